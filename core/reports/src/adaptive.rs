//! The adaptive mode's speed-up report (issue 14, "Measure and report"): the spmm
//! mode's brute force and the adaptive mode's variants (n_b = 16, n_b = 256,
//! pre-convolved) rendered side by side on one scene and the same cores, each measured
//! at frames 1, 2, 4, ... against a converged spmm reference with an independent seed;
//! the speed-up at equal PSNR is the time the brute force needs to reach the PSNR an
//! adaptive checkpoint has (log-linear interpolation between the brute force's
//! checkpoints), divided by the adaptive checkpoint's time.

use std::time::Instant;

use serde::Serialize;

use crate::convergence::REFERENCE_SEED_XOR;
use meso_materials::image::Image;
use meso_materials::metrics::compare;
use meso_modes::adaptive::{AdaptiveMode, AdaptiveOptions};
use meso_modes::trace::SpmmMode;
use meso_render::scene::Scene;
use meso_render::{ModeError, Prepare, RenderMode, run_frames};

#[derive(Clone, Debug)]
pub struct SpeedupRequest {
    pub width: u32,
    pub height: u32,
    pub reference_frames: u32,
    /// Last checkpoint of the brute force.
    pub spmm_frames: u32,
    /// Last checkpoint of the adaptive variants.
    pub adaptive_frames: u32,
    /// The knobs every variant starts from (each variant changes n_b or pre-convolution).
    pub options: AdaptiveOptions,
    /// Runs of each curve (at least 1); a checkpoint keeps the shortest time of its
    /// runs (its image is the same in every run): on a shared machine the fastest run
    /// is the one least disturbed.
    pub repeats: u32,
}

#[derive(Clone, Debug, Serialize)]
pub struct Checkpoint {
    pub frames: u32,
    /// Render time of those frames (the adaptive mode's includes its bandwidth pass).
    pub seconds: f64,
    pub samples: u64,
    pub psnr_db: f64,
    pub rmse: f64,
    /// Time the brute force needs for this PSNR over this checkpoint's time; `None`
    /// for the brute force itself and where it never reached this PSNR.
    pub speedup: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Curve {
    pub name: String,
    pub checkpoints: Vec<Checkpoint>,
    /// Seconds of the bandwidth pass (adaptive variants).
    pub bandwidth_pass_seconds: Option<f64>,
    /// Of which the G-buffer.
    pub gbuffer_seconds: Option<f64>,
    /// Pixels shaded in the first frame, of all.
    pub first_frame_shaded: Option<f64>,
}

/// How well each rule spreads samples, against the per-pixel variance of the frames'
/// estimator measured by brute force (`allocation::gain`: the factor by which the
/// image's summed variance falls at equal samples against uniform sampling, the floor
/// of `AdaptiveOptions::min_share` applied to every rule).
#[derive(Clone, Debug, Serialize)]
pub struct AllocationStudy {
    /// Samples per pixel the variance was measured with (independent numbers).
    pub samples_per_pixel: u32,
    /// N_p in proportion to the measured standard deviation, scored on the same
    /// measurement: optimistic where `samples_per_pixel` samples leave the deviations
    /// noisy (a pixel whose sample happened to be high both draws the samples and
    /// counts their gain).
    pub oracle: f64,
    /// N_p in proportion to the measured standard deviation, scored on an independent
    /// second measurement of as many samples: what knowing each pixel's deviation to
    /// that precision gains, without the self-scoring's optimism.
    pub oracle_held_out: f64,
    /// The paper's rule: N_p in proportion to eq. 9's bound.
    pub eq9_bound: f64,
    /// N_p in proportion to the square root of eq. 9's bound.
    pub eq9_sqrt: f64,
    /// The mode's rule: in proportion to the predicted standard deviation.
    pub predicted: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct SpeedupReport {
    pub width: u32,
    pub height: u32,
    pub reference_frames: u32,
    pub reference_seconds: f64,
    pub threads: usize,
    pub curves: Vec<Curve>,
    pub allocation: AllocationStudy,
    #[serde(skip)]
    pub reference: Image,
}

/// The brute force's time to reach `psnr`, interpolated linearly in log time between
/// its checkpoints; `None` past its last one.
fn time_to(curve: &[Checkpoint], psnr: f64) -> Option<f64> {
    let first = curve.first()?;
    if psnr <= first.psnr_db {
        // Reached by the first frame: at most its time.
        return Some(first.seconds);
    }
    curve.windows(2).find_map(|w| {
        let (a, b) = (&w[0], &w[1]);
        (psnr > a.psnr_db && psnr <= b.psnr_db).then(|| {
            let t = (psnr - a.psnr_db) / (b.psnr_db - a.psnr_db);
            (a.seconds.ln() + t * (b.seconds.ln() - a.seconds.ln())).exp()
        })
    })
}

fn measure(
    mode: &mut dyn RenderMode,
    reference: &Image,
    max_frames: u32,
) -> Result<Vec<Checkpoint>, ModeError> {
    let (mut frames, mut seconds, mut samples, mut next) = (0u32, 0.0, 0u64, 1u32);
    let mut out = Vec::new();
    while frames < max_frames {
        let start = Instant::now();
        let run = run_frames(mode, next - frames, |_, _| {});
        seconds += start.elapsed().as_secs_f64();
        samples += run.counters.samples;
        frames = next;
        let c = compare(reference, &mode.image(), 0.0).expect("same size, finite");
        out.push(Checkpoint {
            frames,
            seconds,
            samples,
            psnr_db: c.psnr_db,
            rmse: c.rmse,
            speedup: None,
        });
        next = (next * 2).min(max_frames);
    }
    Ok(out)
}

/// `measure` of `repeats` modes made by `make`, each checkpoint with its shortest time
/// (the images, and so the PSNR, are the same in every run); also the last mode.
fn measure_fastest<M: RenderMode>(
    mut make: impl FnMut() -> Result<M, ModeError>,
    reference: &Image,
    max_frames: u32,
    repeats: u32,
) -> Result<(Vec<Checkpoint>, M), ModeError> {
    let mut mode = make()?;
    let mut best = measure(&mut mode, reference, max_frames)?;
    for _ in 1..repeats {
        mode = make()?;
        let run = measure(&mut mode, reference, max_frames)?;
        for (b, r) in best.iter_mut().zip(run) {
            debug_assert_eq!(
                b.psnr_db, r.psnr_db,
                "a repeated run renders the same image"
            );
            b.seconds = b.seconds.min(r.seconds);
        }
    }
    Ok((best, mode))
}

/// Runs the report; `progress(message)` as each part starts.
pub fn speedup_report(
    scene: &Scene,
    r: &SpeedupRequest,
    mut progress: impl FnMut(&str),
) -> Result<SpeedupReport, ModeError> {
    progress(&format!("reference: spmm, {} frames", r.reference_frames));
    let mut ref_scene = scene.clone();
    ref_scene.render.seed ^= REFERENCE_SEED_XOR;
    let start = Instant::now();
    let mut reference_mode = SpmmMode::prepare(ref_scene, r.width, r.height, Prepare::quietly())?;
    run_frames(&mut reference_mode, r.reference_frames, |_, _| {});
    let reference = reference_mode.image();
    let reference_seconds = start.elapsed().as_secs_f64();
    drop(reference_mode);
    progress("brute force: spmm");
    let (brute, spmm) = measure_fastest(
        || SpmmMode::prepare(scene.clone(), r.width, r.height, Prepare::quietly()),
        &reference,
        r.spmm_frames,
        r.repeats,
    )?;
    drop(spmm);
    let mut curves = vec![Curve {
        name: "spmm".into(),
        checkpoints: brute.clone(),
        bandwidth_pass_seconds: None,
        gbuffer_seconds: None,
        first_frame_shaded: None,
    }];
    let base = AdaptiveOptions {
        n_b: 16,
        preconvolved: false,
        ..r.options
    };
    let mut variants = vec![
        ("adaptive_nb16", base),
        ("adaptive_nb256", AdaptiveOptions { n_b: 256, ..base }),
        (
            "preconvolved",
            AdaptiveOptions {
                preconvolved: true,
                ..base
            },
        ),
    ];
    // What the split environment estimator adds: the same mode drawing the whole map
    // with one sampler, as the brute force does.
    if base.split_environment {
        let whole = AdaptiveOptions {
            split_environment: false,
            ..base
        };
        variants.insert(1, ("adaptive_whole_map", whole));
    }
    for (name, options) in variants {
        progress(&format!("adaptive: {name}"));
        let (mut checkpoints, mode) = measure_fastest(
            || {
                AdaptiveMode::prepare_with(
                    scene.clone(),
                    r.width,
                    r.height,
                    Prepare::quietly(),
                    options,
                )
            },
            &reference,
            r.adaptive_frames,
            r.repeats,
        )?;
        let mut shaded = None;
        let pass = mode.buffers().map(|b| b.seconds);
        if let Some(b) = mode.buffers() {
            // The first frame's plan, recomputed (the mode keeps the last one).
            let first = mode.plan_frame(b, 0);
            let n = first.site_level.iter().filter(|s| s.is_some()).count();
            shaded = Some(n as f64 / first.site_level.len() as f64);
        }
        for c in &mut checkpoints {
            c.speedup = time_to(&brute, c.psnr_db).map(|t| t / c.seconds);
        }
        curves.push(Curve {
            name: name.into(),
            checkpoints,
            bandwidth_pass_seconds: pass,
            gbuffer_seconds: mode.buffers().map(|b| b.gbuffer_seconds),
            first_frame_shaded: shaded,
        });
    }
    progress("allocation study");
    let allocation = allocation_study(scene, r, STUDY_SPP)?;
    Ok(SpeedupReport {
        allocation,
        width: r.width,
        height: r.height,
        reference_frames: r.reference_frames,
        reference_seconds,
        threads: rayon::current_num_threads(),
        curves,
        reference,
    })
}

/// Samples per pixel of the allocation study.
const STUDY_SPP: u32 = 64;

/// Measures each pixel's per-sample variance (RGB summed, as the PSNR sums it) with
/// `spp` independent samples of the frames' estimator and scores the allocation rules.
pub fn allocation_study(
    scene: &Scene,
    r: &SpeedupRequest,
    spp: u32,
) -> Result<AllocationStudy, ModeError> {
    use rayon::prelude::*;
    let mut scene = scene.clone();
    scene.render.sampler = meso_materials::rng::Sampler::Independent;
    let options = AdaptiveOptions {
        n_b: 16,
        preconvolved: false,
        ..r.options
    };
    let mode = AdaptiveMode::prepare_with(scene, r.width, r.height, Prepare::quietly(), options)?;
    let w = r.width;
    let spp = spp.max(2);
    // Per-sample variances from samples `first..first + spp` of every pixel.
    let measure = |first: u32| -> Vec<f64> {
        (0..w * r.height)
            .into_par_iter()
            .map(|i| {
                let mut m = [meso_modes::adaptive::allocation::Moments::default(); 3];
                for k in first..first + spp {
                    let v = mode.sample_value(i % w, i / w, u64::from(k));
                    for (c, value) in m.iter_mut().zip(v.to_array()) {
                        c.add(value);
                    }
                }
                m.iter().map(|c| c.variance()).sum()
            })
            .collect()
    };
    let measured = measure(0);
    let held_out = measure(spp);
    let b = mode.bandwidth_pass();
    let floor = options.min_share;
    let gain = |weight: &[f64]| meso_modes::adaptive::allocation::gain(&measured, weight, floor);
    let sqrt = |v: &[f64]| v.iter().map(|x| x.sqrt()).collect::<Vec<_>>();
    Ok(AllocationStudy {
        samples_per_pixel: spp,
        oracle: gain(&sqrt(&measured)),
        oracle_held_out: meso_modes::adaptive::allocation::gain(&held_out, &sqrt(&measured), floor),
        eq9_bound: gain(&b.variance),
        eq9_sqrt: gain(&sqrt(&b.variance)),
        predicted: gain(&b.sigma),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cp(seconds: f64, psnr_db: f64) -> Checkpoint {
        Checkpoint {
            frames: 0,
            seconds,
            samples: 0,
            psnr_db,
            rmse: 0.0,
            speedup: None,
        }
    }

    #[test]
    fn time_to_a_psnr_interpolates_in_log_time() {
        let curve = [cp(1.0, 20.0), cp(4.0, 26.0), cp(16.0, 32.0)];
        assert_eq!(time_to(&curve, 18.0), Some(1.0));
        let t = time_to(&curve, 23.0).expect("reached");
        assert!((t - 2.0).abs() < 1e-12, "{t}");
        assert!((time_to(&curve, 32.0).expect("reached") - 16.0).abs() < 1e-9);
        assert_eq!(time_to(&curve, 33.0), None);
    }
}

#[cfg(test)]
mod allocation_tests {
    use super::*;

    /// Samples spread by the pass's predicted deviation recover most of what the measured
    /// deviations would give (the allocation study of the report, at 64 samples per pixel):
    /// a pass whose prediction were blurred, shifted or blind to the footprint's edges
    /// (as one shared per 2 x 2 block was) falls well below.
    #[test]
    fn the_predicted_deviation_recovers_most_of_the_oracle_allocation_gain() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/scenes/merl_dragon.toml");
        let scene = meso_render::scene::load_scene(&path).expect("the shipped dragon scene");
        let request = SpeedupRequest {
            width: 128,
            height: 128,
            reference_frames: 0,
            spmm_frames: 0,
            adaptive_frames: 0,
            options: AdaptiveOptions::default(),
            repeats: 1,
        };
        let study = allocation_study(&scene, &request, 64).expect("study");
        eprintln!(
            "oracle {:.2} (held out {:.2}), predicted {:.2}, eq. 9 {:.2}",
            study.oracle, study.oracle_held_out, study.predicted, study.eq9_bound
        );
        assert!(study.oracle > 1.5, "{study:?}");
        assert!(study.predicted >= 0.55 * study.oracle, "{study:?}");
        // Scored on samples it did not allocate with, the oracle loses its
        // self-scoring optimism (measured 4.89x against 5.16x); one that equalled
        // the self-scored figure would be scored on the same samples.
        assert!(
            study.oracle_held_out < study.oracle && study.oracle_held_out > study.predicted,
            "{study:?}"
        );
    }
}
