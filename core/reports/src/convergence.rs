//! The speed-against-error report of a render mode (every fast path
//! reports its speed against its error): a converged reference, then the error of the
//! progressive image after 1, 2, 4, ... frames with the render time spent, for the
//! scene as written and for its variants (independent random numbers instead of the
//! scene's Sobol points; one light sample per frame where the scene asks for more; AO off; environment light without MIS; the
//! SPMM residual skipped; N_PCA limited, `npca_4` being the image while the camera moves). A variant that changes what is computed
//! (AO off) is measured against its own reference; other estimators of the same image
//! (independent numbers, one light sample, no MIS) and approximations of it (residual off, fewer PCA
//! terms) against the full one, so their noise or bias shows. The viewport denoiser's
//! rows (`full_denoised`, up to 16 frames) show what it does to the first frames'
//! error. Any mode can be reported; its reference is the spmm mode's.

use std::time::Instant;

use serde::Serialize;

use std::sync::Arc;

use crate::biscale as report;
use meso_materials::image::Image;
use meso_materials::metrics::{Comparison, MetricsError, compare};
use meso_materials::rng::Sampler;
use meso_modes::biscale::cpca::Cpca;
use meso_modes::biscale::cubemap::CubeLayout;
use meso_modes::biscale::hemisphere::HemisphereGrid;
use meso_modes::biscale::sh::ShTransfer;
use meso_modes::biscale::{BiscaleMode, TransferSource};
use meso_render::scene::{Material, Scene};
use meso_render::{Device, ModeError, ModeKind, Pass, Prepare, RenderMode, run_frames};

/// What the report renders.
#[derive(Clone, Debug)]
pub struct ConvergenceRequest {
    pub width: u32,
    pub height: u32,
    /// Frames of each converged reference.
    pub reference_frames: u32,
    /// The last checkpoint (rounded up to a power of two).
    pub max_frames: u32,
    pub mode: ModeKind,
    pub device: Device,
}

/// One scene variant.
#[derive(Clone, Debug, Serialize)]
pub struct Variant {
    pub name: String,
    /// The reference it is measured against: "full" or "no_ao".
    pub reference: String,
}

/// The error after `frames` frames.
#[derive(Clone, Debug, Serialize)]
pub struct Checkpoint {
    pub variant: String,
    pub reference: String,
    pub frames: u32,
    /// Render time of those frames (frames only, no setup).
    pub seconds: f64,
    pub rmse: f64,
    pub psnr_db: f64,
    pub mssim: f64,
}

/// Per variant: time per frame, and when MSSIM first reached 0.98.
#[derive(Clone, Debug, Serialize)]
pub struct VariantSummary {
    pub variant: String,
    pub reference: String,
    pub ms_per_frame: f64,
    pub frames_to_mssim_098: Option<u32>,
    pub seconds_to_mssim_098: Option<f64>,
    pub final_rmse: f64,
    pub final_mssim: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct ConvergenceReport {
    /// The mode measured; references are always the converged spmm mode on the CPU.
    pub mode: ModeKind,
    pub device: Device,
    pub width: u32,
    pub height: u32,
    pub reference_frames: u32,
    pub reference_seconds: f64,
    pub checkpoints: Vec<Checkpoint>,
    pub summaries: Vec<VariantSummary>,
    /// Why residual / N_PCA variants are absent, when they are.
    pub notes: Vec<String>,
    /// Biscale: milliseconds of one light change (new lighting vector and L*).
    pub light_change_ms: Option<f64>,
    /// The converged image of the scene as written.
    #[serde(skip)]
    pub reference: Image,
}

#[derive(Debug, thiserror::Error)]
pub enum ConvergenceError {
    #[error(transparent)]
    Mode(#[from] ModeError),
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    #[error("{0}")]
    Edit(String),
    #[error("--max-frames and --reference-frames must be at least 1 and max <= reference")]
    Frames,
}

/// The largest N_PCA in use by the scene's SPMM materials with a residual.
fn residual_terms(scene: &Scene) -> Option<usize> {
    scene
        .materials
        .iter()
        .filter_map(|m| match m {
            Material::Spmm {
                material,
                residual: true,
                npca,
                ..
            } => material.residual().map(|r| r.npca.min(*npca)),
            _ => None,
        })
        .max()
}

fn with_spmm(scene: &Scene, f: impl Fn(&mut bool, &mut usize)) -> Scene {
    let mut s = scene.clone();
    for m in &mut s.materials {
        if let Material::Spmm { residual, npca, .. } = m {
            f(residual, npca);
        }
    }
    s
}

/// The scene's variants: (variant, its scene).
fn variants(scene: &Scene, notes: &mut Vec<String>) -> Vec<(Variant, Scene)> {
    let v = |name: &str, reference: &str| Variant {
        name: name.into(),
        reference: reference.into(),
    };
    let mut out = vec![(v("full", "full"), scene.clone())];
    if scene.render.sampler != Sampler::Independent {
        // The same image from independent random numbers: what the sampler gains.
        let mut s = scene.clone();
        s.render.sampler = Sampler::Independent;
        out.push((v("independent", "full"), s));
    }
    if scene.render.light_samples > 1 && !scene.lights.is_empty() {
        // The same image from one light sample per frame: what the extra samples gain
        // per frame, and what they cost per second.
        let mut s = scene.clone();
        s.render.light_samples = 1;
        out.push((v("one_light_sample", "full"), s));
    }
    if scene.ambient.is_some() {
        let mut s = scene.clone();
        s.ambient = None;
        out.push((v("no_ao", "no_ao"), s));
    } else {
        notes.push("the scene has no ambient term: no AO-off variant".into());
    }
    match &scene.environment {
        Some(env) if env.mis => {
            // The same image by map sampling alone: what MIS gains at equal frames.
            let mut s = scene.clone();
            if let Some(e) = &mut s.environment {
                e.mis = false;
            }
            out.push((v("no_mis", "full"), s));
        }
        Some(_) => {
            notes.push("the environment samples the map alone (mis = false): no MIS variant".into())
        }
        None => {}
    }
    match residual_terms(scene) {
        Some(k) => {
            out.push((
                v("residual_off", "full"),
                with_spmm(scene, |r, _| *r = false),
            ));
            for n in [0, 1, 2, 4, 8].into_iter().filter(|&n| n < k) {
                out.push((
                    v(&format!("npca_{n}"), "full"),
                    with_spmm(scene, |_, npca| *npca = (*npca).min(n)),
                ));
            }
        }
        None => notes
            .push("no SPMM material with a residual in use: no residual or N_PCA variants".into()),
    }
    out
}

pub use meso_modes::REFERENCE_SEED_XOR;

fn converged(scene: &Scene, r: &ConvergenceRequest) -> Result<(Image, f64), ConvergenceError> {
    // The reference is the spmm mode on the CPU, whichever mode is being measured.
    let mut scene = scene.clone();
    scene.render.seed ^= REFERENCE_SEED_XOR;
    let mut mode = meso_modes::create(
        ModeKind::Spmm,
        Device::Cpu,
        scene,
        r.width,
        r.height,
        Prepare::quietly(),
    )?;
    let run = run_frames(mode.as_mut(), r.reference_frames, |_, _| {});
    Ok((mode.image(), run.seconds))
}

/// The rows of the viewport denoiser (`render::denoise`) applied to the scene's
/// progressive image; measured against the full reference, never part of it.
pub const DENOISED: &str = "full_denoised";
/// Its checkpoints stop here: it is for the first frames.
pub const DENOISED_FRAMES: u32 = 16;

/// The mode's image through the denoiser and the filter's time; `None` where the
/// mode gives no guides.
fn denoise(mode: &dyn RenderMode, image: &Image) -> Option<(Image, f64)> {
    let start = Instant::now();
    let guides = mode.guides(Pass::Frame)?;
    let samples = mode.progress().min_samples;
    let img = meso_render::Denoiser::for_samples(samples).apply(image, &guides)?;
    Some((img, start.elapsed().as_secs_f64()))
}

/// The summary of a variant's checkpoints (in order of frames).
fn summary_of(rows: &[Checkpoint]) -> VariantSummary {
    let last = rows.last().expect("at least one checkpoint");
    let reached = rows.iter().find(|c| c.mssim >= 0.98);
    VariantSummary {
        variant: last.variant.clone(),
        reference: last.reference.clone(),
        ms_per_frame: last.seconds * 1e3 / f64::from(last.frames),
        frames_to_mssim_098: reached.map(|c| c.frames),
        seconds_to_mssim_098: reached.map(|c| c.seconds),
        final_rmse: last.rmse,
        final_mssim: last.mssim,
    }
}

/// The frame count of the checkpoint after `frames`: every count up to 8, then four
/// per doubling (16, 20, 24, 28, 32, 40, ...), so a goal such as "MSSIM 0.98 by 20
/// frames" reads off the report, while the powers of two stay checkpoints.
fn next_checkpoint(frames: u32) -> u32 {
    if frames < 8 {
        return frames + 1;
    }
    let power = 1u32 << (31 - frames.leading_zeros());
    frames.saturating_add(power / 4)
}

/// The error of `mode` against `reference` after the checkpoints' frame counts
/// (`next_checkpoint`; the last is `max_frames`); for the scene
/// as written (`full`) also the denoiser's rows up to `DENOISED_FRAMES`.
fn measure(
    mode: &mut dyn RenderMode,
    v: &Variant,
    reference: &Image,
    request: &ConvergenceRequest,
    checkpoints: &mut Vec<Checkpoint>,
    summaries: &mut Vec<VariantSummary>,
) -> Result<(), ConvergenceError> {
    let (mut frames, mut seconds, mut next) = (0u32, 0.0, 1u32);
    let mut reached = None;
    let mut last: Option<Comparison> = None;
    let mut denoised = (v.name == "full").then(Vec::new);
    while frames < request.max_frames {
        let start = Instant::now();
        run_frames(mode, next - frames, |_, _| {});
        seconds += start.elapsed().as_secs_f64();
        frames = next;
        let image = mode.image();
        if let Some(rows) = &mut denoised
            && frames <= DENOISED_FRAMES
            && let Some((img, secs)) = denoise(mode, &image)
        {
            let c = compare(reference, &img, 0.0)?;
            rows.push(Checkpoint {
                variant: DENOISED.into(),
                reference: v.reference.clone(),
                frames,
                seconds: seconds + secs,
                rmse: c.rmse,
                psnr_db: c.psnr_db,
                mssim: c.mssim,
            });
        }
        let c = compare(reference, &image, 0.0)?;
        if reached.is_none() && c.mssim >= 0.98 {
            reached = Some((frames, seconds));
        }
        checkpoints.push(Checkpoint {
            variant: v.name.clone(),
            reference: v.reference.clone(),
            frames,
            seconds,
            rmse: c.rmse,
            psnr_db: c.psnr_db,
            mssim: c.mssim,
        });
        last = Some(c);
        next = next_checkpoint(frames).min(request.max_frames);
    }
    let last = last.expect("at least one checkpoint");
    summaries.push(VariantSummary {
        variant: v.name.clone(),
        reference: v.reference.clone(),
        ms_per_frame: seconds * 1e3 / frames as f64,
        frames_to_mssim_098: reached.map(|r| r.0),
        seconds_to_mssim_098: reached.map(|r| r.1),
        final_rmse: last.rmse,
        final_mssim: last.mssim,
    });
    if let Some(rows) = denoised.filter(|r| !r.is_empty()) {
        summaries.push(summary_of(&rows));
        checkpoints.extend(rows);
    }
    Ok(())
}

/// Runs the report; `progress(message)` is called as each part starts.
pub fn convergence_report(
    scene: &Scene,
    request: &ConvergenceRequest,
    mut progress: impl FnMut(&str),
) -> Result<ConvergenceReport, ConvergenceError> {
    if request.max_frames == 0 || request.max_frames > request.reference_frames {
        return Err(ConvergenceError::Frames);
    }
    let mut notes = Vec::new();
    let variants = variants(scene, &mut notes);
    let mut references: Vec<(String, Image)> = Vec::new();
    let mut reference_seconds = 0.0;
    for (v, s) in &variants {
        if v.name == v.reference {
            progress(&format!(
                "reference `{}`: {} frames",
                v.name, request.reference_frames
            ));
            let (img, secs) = converged(s, request)?;
            reference_seconds += secs;
            references.push((v.name.clone(), img));
        }
    }
    let mut checkpoints = Vec::new();
    let mut summaries = Vec::new();
    let mut light_change_ms = None;
    for (v, s) in &variants {
        progress(&format!("variant `{}`", v.name));
        let reference = &references
            .iter()
            .find(|(n, _)| *n == v.reference)
            .expect("every variant's reference was rendered above")
            .1;
        let mut mode = meso_modes::create(
            request.mode,
            request.device,
            s.clone(),
            request.width,
            request.height,
            Prepare::quietly(),
        )?;
        measure(
            mode.as_mut(),
            v,
            reference,
            request,
            &mut checkpoints,
            &mut summaries,
        )?;
    }
    if request.mode == ModeKind::Biscale {
        // The other representations of the same transfer, on the same precomputation:
        // the dense matrix (the exact product), Sloan et al.'s SH and CPCA.
        let reference = &references[0].1;
        let mut mode = BiscaleMode::new(
            scene.clone(),
            request.width,
            request.height,
            Prepare::quietly(),
        )?;
        if let Some(env) = scene.environment.clone() {
            // A light change: turn the map and back; the second turn is timed.
            let mut turned = env.clone();
            turned.rotate_y_deg += 45.0;
            for e in [turned, env] {
                mode.apply(meso_render::SceneEdit::Environment(Some(e)))
                    .map_err(|e| ConvergenceError::Edit(e.to_string()))?;
            }
            light_change_ms = Some(mode.light_change_ms());
        }
        let pre = mode.precomputed().clone();
        let s = mode.settings().clone();
        let cube = CubeLayout::new(s.cube_n);
        let local = HemisphereGrid::new(s.local_res);
        progress("transfer variants: dense, sh, cpca");
        let sources = [
            ("dense", TransferSource::Dense),
            (
                "sh",
                TransferSource::Sh(Arc::new(ShTransfer::build(
                    &pre.transfer,
                    &pre.frames,
                    cube,
                    local,
                    report::SH_ORDER,
                ))),
            ),
            (
                "cpca",
                TransferSource::Cpca(Arc::new(Cpca::build(
                    &pre.transfer,
                    report::CPCA_CLUSTERS,
                    report::CPCA_COMPONENTS,
                    s.seed,
                ))),
            ),
        ];
        for (name, source) in sources {
            mode.set_transfer_source(source);
            let v = Variant {
                name: name.into(),
                reference: "full".into(),
            };
            measure(
                &mut mode,
                &v,
                reference,
                request,
                &mut checkpoints,
                &mut summaries,
            )?;
        }
        // Frames while the camera is dragged: the nearest tabulated view, no residual.
        mode.set_transfer_source(TransferSource::Biclustered);
        mode.apply(meso_render::SceneEdit::Moving(true))
            .map_err(|e| ConvergenceError::Edit(e.to_string()))?;
        let v = Variant {
            name: "moving".into(),
            reference: "full".into(),
        };
        measure(
            &mut mode,
            &v,
            reference,
            request,
            &mut checkpoints,
            &mut summaries,
        )?;
    }
    let reference = references.swap_remove(0).1;
    Ok(ConvergenceReport {
        mode: request.mode,
        device: request.device,
        reference,
        width: request.width,
        height: request.height,
        reference_frames: request.reference_frames,
        reference_seconds,
        checkpoints,
        summaries,
        notes,
        light_change_ms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_render::scene::test_scenes::edit_test_scene;

    #[test]
    fn a_scene_with_several_light_samples_is_also_measured_with_one() {
        let mut scene = edit_test_scene();
        scene.render.light_samples = 2;
        let names = |scene: &Scene| -> Vec<(String, u32)> {
            variants(scene, &mut Vec::new())
                .into_iter()
                .map(|(v, s)| (v.name, s.render.light_samples))
                .collect()
        };
        let two = names(&scene);
        assert_eq!(two[0], ("full".into(), 2));
        assert!(two.contains(&("one_light_sample".into(), 1)), "{two:?}");
        scene.render.light_samples = 1;
        assert!(!names(&scene).iter().any(|(n, _)| n == "one_light_sample"));
    }

    #[test]
    fn error_falls_with_frames_and_the_residual_variants_show_their_bias() {
        let scene = edit_test_scene();
        let request = ConvergenceRequest {
            width: 24,
            height: 24,
            reference_frames: 256,
            max_frames: 64,
            mode: ModeKind::Spmm,
            device: Device::Cpu,
        };
        let report = convergence_report(&scene, &request, |_| {}).expect("report");
        let names: Vec<&str> = report
            .summaries
            .iter()
            .map(|s| s.variant.as_str())
            .collect();
        assert_eq!(
            names,
            [
                "full",
                "full_denoised",
                "independent",
                "no_ao",
                "residual_off",
                "npca_0",
                "npca_1",
                "npca_2",
                "npca_4"
            ]
        );
        let full: Vec<&Checkpoint> = report
            .checkpoints
            .iter()
            .filter(|c| c.variant == "full")
            .collect();
        assert_eq!(
            full.iter().map(|c| c.frames).collect::<Vec<_>>(),
            [
                1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64
            ]
        );
        // Monte Carlo error falls roughly as 1 / sqrt(frames): 64x the frames should
        // cut it well below half (it is 1/8 for independent references).
        let last = full.last().expect("checkpoints");
        assert!(last.rmse < 0.5 * full[0].rmse, "{full:?}");
        assert!(full.windows(2).all(|w| w[1].seconds > w[0].seconds));
        // The denoiser's rows stop at 16 frames and cut the first frame's error (its
        // bias is smaller than one frame's noise; measured 0.76x on this 24x24 scene,
        // 0.40x on the default scene at 256x256), never replacing the estimate's rows.
        let denoised: Vec<&Checkpoint> = report
            .checkpoints
            .iter()
            .filter(|c| c.variant == DENOISED)
            .collect();
        assert_eq!(
            denoised.iter().map(|c| c.frames).collect::<Vec<_>>(),
            [1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 14, 16]
        );
        assert!(
            denoised[0].rmse < 0.85 * full[0].rmse,
            "{denoised:?} vs {full:?}"
        );
        // Skipping the residual is biased: it stops improving above the full image's
        // error at the same frame count.
        let at64 = |v: &str| {
            report
                .checkpoints
                .iter()
                .find(|c| c.variant == v && c.frames == 64)
                .expect("checkpoint")
                .rmse
        };
        assert!(at64("residual_off") > at64("full"), "{report:#?}");
    }

    #[test]
    fn the_reference_is_independent_of_the_progressive_images() {
        // With reference_frames == max_frames == K the last checkpoint compares two
        // K-frame renders of the same scene. Independent seeds make its error that of
        // two independent K-frame renders (measured below with two other seeds); a
        // reference sharing the progressive image's seed would make it exactly 0.
        let scene = edit_test_scene();
        let k = 4;
        let request = ConvergenceRequest {
            width: 24,
            height: 24,
            reference_frames: k,
            max_frames: k,
            mode: ModeKind::Spmm,
            device: Device::Cpu,
        };
        let report = convergence_report(&scene, &request, |_| {}).expect("report");
        let reported = report
            .checkpoints
            .iter()
            .find(|c| c.variant == "full" && c.frames == k)
            .expect("last checkpoint")
            .rmse;
        let render = |seed: u64| {
            let mut s = scene.clone();
            s.render.seed = seed;
            let mut mode =
                meso_modes::create(ModeKind::Spmm, Device::Cpu, s, 24, 24, Prepare::quietly())
                    .expect("mode");
            run_frames(mode.as_mut(), k, |_, _| {});
            mode.image()
        };
        let seed = scene.render.seed;
        let independent = compare(&render(seed ^ 1), &render(seed ^ 2), 0.0)
            .expect("same size")
            .rmse;
        let ratio = reported / independent;
        eprintln!("reported {reported:e}, independent {independent:e}, ratio {ratio}");
        // Both are RMSEs over 576 pixels of the same noise; measured ratio 0.955 (the
        // margin covers the sampling spread of two such estimates).
        assert!((0.8..1.25).contains(&ratio), "ratio {ratio}");
    }
}
