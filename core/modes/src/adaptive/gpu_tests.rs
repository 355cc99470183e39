//! The adaptive mode on the GPU against the CPU adaptive mode: the device's bandwidth
//! pass against the CPU's, the device's plan of a frame against `plan_frame` on the
//! same bandwidth pass (the CPU's, uploaded), its up-sampling against `upsample`, and
//! images by the GPU modes' rule (`gpu_test_support`, means against
//! the CPU mode's at equal frames) on the MERL
//! bunny (MERL tables, the environment, an area light) and on the default scene (an
//! SPMM pack and analytic BRDFs under an area light with the ambient term). They need a
//! wgpu adapter (CI: lavapipe, WGPU_BACKEND=vulkan) and fail without one.

use std::path::Path;

use glam::DVec3;
use meso_render::scene::{Scene, load_scene};
use meso_render::{Prepare, RenderMode, SceneEdit, run_frames};

use super::upsample::{self, Guide};
use super::{AdaptiveMode, AdaptiveOptions, GpuAdaptiveMode};
use crate::REFERENCE_SEED_XOR;
use crate::gpu_test_support::{
    MeanOf, agrees, context, merl_bunny_with_point_light_ambient_and_mirror,
};
use crate::trace::SpmmMode;

fn scene(name: &str, size: u32) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/scenes")
        .join(name);
    let mut scene = load_scene(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    scene.render.width = size;
    scene.render.height = size;
    scene
}

fn gpu(scene: Scene, size: u32) -> GpuAdaptiveMode {
    GpuAdaptiveMode::prepare(
        context().clone(),
        scene,
        (size, size),
        AdaptiveOptions::default(),
        Prepare::quietly(),
    )
    .expect("GPU adaptive")
}

fn cpu(scene: Scene, size: u32) -> AdaptiveMode {
    AdaptiveMode::prepare(scene, size, size, Prepare::quietly()).expect("CPU adaptive")
}

/// The spmm mode's image of `scene` at `frames` frames with the reference seed: the
/// integral the adaptive mode converges to.
fn converged(scene: &Scene, size: u32, frames: u32) -> meso_materials::image::Image {
    let mut s = scene.clone();
    s.render.seed ^= REFERENCE_SEED_XOR;
    let mut m = SpmmMode::prepare(s, size, size, Prepare::quietly()).expect("spmm");
    run_frames(&mut m, frames, |_, _| {});
    m.image()
}

/// `g`, made for `scene` or brought to it by an edit, after `frames` more frames
/// against the spmm mode's converged image of `scene` (512 frames) and the CPU adaptive
/// mode's at equal frames, by the GPU modes' rule; no traversal overflows.
fn agrees_with_cpu(what: &str, g: &mut GpuAdaptiveMode, scene: &Scene, size: u32, frames: u32) {
    let reference = converged(scene, size, 512);
    let mut c = cpu(scene.clone(), size);
    agrees(
        what,
        (g, &mut c),
        &reference,
        frames,
        size,
        MeanOf::CpuAtEqualFrames,
    );
    assert_eq!(
        g.device_mode().overflows(),
        (0, 0),
        "{what}: traversal overflows"
    );
}

/// How far the device's pass is from the CPU's at one view: the share of pixels at
/// another level, and of pixels whose deviation or guide differs beyond f32's noise.
struct PassDifference {
    levels: f64,
    sigmas: f64,
    guides: f64,
}

fn pass_difference(what: &str, g: &GpuAdaptiveMode) -> PassDifference {
    let got = g.device_mode().adaptive_pass_pixels().expect("read back");
    let want = g.cpu_mode().bandwidth_pass();
    assert_eq!(got.len(), want.level.len(), "{what}: pixels");
    let n = got.len() as f64;
    let mean_sigma = want.sigma.iter().sum::<f64>() / n;
    let mean_level = want.mean.iter().map(|m| m.abs()).sum::<f64>() / n;
    let (mut levels, mut sigmas, mut guides) = (0, 0, 0);
    let mut rel: Vec<f64> = got
        .iter()
        .zip(&want.sigma)
        .map(|(p, s)| (f64::from(p.sigma) - s).abs() / s.max(1e-3 * mean_sigma))
        .collect();
    rel.sort_by(f64::total_cmp);
    let q = |f: f64| rel[((rel.len() - 1) as f64 * f) as usize];
    eprintln!(
        "{what}: sigma relative error 50% {:.1e}, 90% {:.1e}, 99% {:.1e}, 99.9% {:.1e}, max {:.1e}",
        q(0.5),
        q(0.9),
        q(0.99),
        q(0.999),
        q(1.0)
    );
    for (i, p) in got.iter().enumerate() {
        levels += usize::from(p.level != want.level[i]);
        let sigma = want.sigma[i];
        // The pass's mean, which a pixel's first sample is measured against, with the
        // same tolerance.
        let mean = want.mean[i];
        sigmas += usize::from(
            (f64::from(p.sigma) - sigma).abs() > 1e-2 * sigma.max(1e-3 * mean_sigma)
                || (f64::from(p.mean) - mean).abs() > 1e-2 * mean.abs().max(1e-3 * mean_level),
        );
        let guide = &want.guide;
        let depth = guide.depth[i];
        let depth_ok = if depth.is_finite() {
            (f64::from(p.depth) - depth).abs() <= 1e-4 * depth
        } else {
            p.depth.is_infinite()
        };
        let dir = guide.normal_dir[i];
        let dir_ok = (f64::from(p.normal_dir[0]) - dir.x).abs() <= 1e-3
            && (f64::from(p.normal_dir[1]) - dir.y).abs() <= 1e-3;
        let cos_ok = (f64::from(p.cos_x) - guide.cos_x[i]).abs() <= 1e-4;
        guides += usize::from(!(depth_ok && dir_ok && cos_ok));
    }
    let d = PassDifference {
        levels: levels as f64 / n,
        sigmas: sigmas as f64 / n,
        guides: guides as f64 / n,
    };
    eprintln!(
        "{what}: {:.2}% of pixels at another level, {:.2}% with another deviation, {:.2}% with another guide",
        100.0 * d.levels,
        100.0 * d.sigmas,
        100.0 * d.guides
    );
    d
}

/// The device's bandwidth pass finds the CPU pass's levels, predicted deviations and
/// up-sampling guides, on scenes of every material, light and escape kind: all but a
/// few pixels where f32 puts a value on the other side of an edge (a level's bound,
/// a guard's step).
#[test]
fn the_device_pass_finds_the_cpus_levels_deviations_and_guides() {
    let btf_floor = {
        let mut s = merl_bunny_with_point_light_ambient_and_mirror();
        s.materials[1] = meso_render::scene::test_scenes::tabulated_btf(
            &meso_materials::brdf::AnalyticBrdf::new(
                meso_materials::brdf::BrdfModel::CookTorrance,
                &[("m", 0.5), ("f0", 0.8)],
            )
            .expect("valid"),
            DVec3::new(0.7, 0.4, 0.2),
            glam::DVec2::ONE,
        );
        s
    };
    let cases = [
        ("merl bunny", scene("merl_bunny.toml", 48), 48),
        ("default scene", scene("default.toml", 48), 48),
        ("point light, ambient, mirror, btf floor", btf_floor, 32),
        (
            "forty lights",
            meso_render::scene::test_scenes::many_lights_scene(40),
            24,
        ),
    ];
    for (what, mut s, size) in cases {
        s.render.width = size;
        s.render.height = size;
        let t = std::time::Instant::now();
        let mut g = gpu(s, size);
        eprintln!("{what}: prepared in {:.1} s", t.elapsed().as_secs_f64());
        let t = std::time::Instant::now();
        run_frames(&mut g, 1, |_, _| {});
        eprintln!(
            "{what}: pass and frame in {:.1} s ({})",
            t.elapsed().as_secs_f64(),
            g.diagnostics().summary().unwrap_or_default()
        );
        let d = pass_difference(what, &g);
        assert!(d.levels <= 0.01, "{what}: levels");
        assert!(d.sigmas <= 0.02, "{what}: deviations");
        assert!(d.guides <= 0.001, "{what}: guides");
    }
}

/// The plans of the first frames: the sites (leaf corners of the level pyramid less
/// the levels dropped so far, and pixels without parents at their depth) are the CPU
/// `plan_frame`'s every frame, until the drops have made every pixel a site; the first frame's counts (the sites' deviations, their
/// mean, the dithering) are its counts, pixel by pixel, but for counts one apart where
/// f32 rounding crosses a dithering edge (at most 1% of the pixels). Later counts
/// differ by design: each device's own samples correct its predictions.
#[test]
fn the_device_plans_frames_as_the_cpu_does() {
    let size = 64;
    let mut mode = gpu(scene("merl_bunny.toml", size), size);
    let pass = mode.use_cpu_pass();
    run_frames(&mut mode, 1, |_, _| {});
    let mut leaves = [0usize; 8];
    // Up to the frame whose drops leave every pixel a site (levels reach 7 here).
    for frame in 0..16 {
        if frame > 0 {
            run_frames(&mut mode, 1, |_, _| {});
        }
        let got = mode.device_mode().adaptive_plan().expect("read back");
        let want = mode.cpu_mode().plan_frame(&pass, frame);
        for (i, ((site, _), level)) in got.iter().zip(&want.site_level).enumerate() {
            assert_eq!(*site, level.is_some(), "frame {frame}, pixel {i}: a site?");
            if frame == 0
                && let Some(k) = level
            {
                leaves[(*k as usize).min(7)] += 1;
            }
        }
        if frame > 0 {
            continue;
        }
        let mut off = 0;
        for (i, ((_, got), want)) in got.iter().zip(&want.samples).enumerate() {
            assert!(
                got.abs_diff(*want) <= 1,
                "pixel {i}: {got} samples, the CPU plans {want}"
            );
            off += usize::from(got != want);
        }
        let sites = want.samples.iter().filter(|&&n| n > 0).count();
        eprintln!(
            "frame 0: {sites} sites of {} pixels, leaves by level {leaves:?}, {off} counts one apart",
            got.len()
        );
        assert!(
            leaves[2..].iter().sum::<usize>() > 0,
            "leaves above level 1"
        );
        assert!(off * 100 <= got.len(), "{off} counts one apart");
    }
}

/// The device's image after a frame is its own means where they stand and, elsewhere,
/// the CPU's `upsample` of them (f32 against f64).
#[test]
fn the_device_upsamples_as_the_cpu_does() {
    let size = 40;
    let mut mode = gpu(scene("merl_bunny.toml", size), size);
    let b = mode.use_cpu_pass();
    run_frames(&mut mode, 1, |_, _| {});
    let image = mode.image();
    let own = mode
        .device_mode()
        .adaptive_own_samples()
        .expect("read back");
    let cpu = mode.cpu_mode();
    let guide: &Guide = &b.guide;
    let top = cpu.top_level();
    // After the first frame no site was added by a refinement.
    let has = upsample::trusted(guide, &own, &vec![false; own.len()], top);
    let mut values: Vec<DVec3> = image
        .pixels()
        .iter()
        .zip(&has)
        .map(|(p, &h)| {
            if h {
                DVec3::new(p[0].into(), p[1].into(), p[2].into())
            } else {
                DVec3::splat(-1.0)
            }
        })
        .collect();
    upsample::upsample(guide, &has, &mut values, top);
    let filled = has.iter().filter(|h| !**h).count();
    assert!(filled > 0, "some pixels are up-sampled");
    for (i, (p, v)) in image.pixels().iter().zip(&values).enumerate() {
        for c in 0..3 {
            let (got, want) = (f64::from(p[c]), v[c]);
            assert!(
                (got - want).abs() <= 1e-4 * want.abs().max(1e-2),
                "pixel {i} channel {c}: {got} against the CPU's {want}"
            );
        }
    }
    eprintln!("{filled} of {} pixels up-sampled", has.len());
}

/// The MERL bunny under the environment and an area light: the GPU's image at 8 frames
/// by the rule, against the spmm mode's converged image.
#[test]
fn the_gpu_adaptive_image_is_the_cpus_on_merl_tables() {
    let size = 32;
    let scene = scene("merl_bunny.toml", size);
    let frames = 8;
    let mut g = gpu(scene.clone(), size);
    agrees_with_cpu("merl bunny", &mut g, &scene, size, frames);
}

/// The default scene (an SPMM pack, analytic BRDFs, an area light, the ambient term),
/// then after a material edit, which keeps the pass and restarts the samples.
#[test]
fn the_gpu_adaptive_image_is_the_cpus_on_packs_and_after_an_edit() {
    let size = 32;
    let scene = scene("default.toml", size);
    let frames = 8;
    let mut g = gpu(scene.clone(), size);
    agrees_with_cpu("default scene", &mut g, &scene, size, frames);
    // A material edit: the first material turned into the second.
    let edited = {
        let mut s = scene.clone();
        s.materials[0] = s.materials[1].clone();
        s
    };
    let edit = || SceneEdit::Material {
        index: 0,
        material: edited.materials[0].clone(),
    };
    g.apply(edit()).expect("the edit");
    assert!(g.device_mode().has_adaptive_pass(), "the pass stands");
    agrees_with_cpu("default scene, edited", &mut g, &edited, size, frames);
}

/// What the MERL bunny lacks of the light and material kinds: a point light, the
/// ambient term, a mirror, and a `btf` table on the floor (a rough lobe: under the
/// ambient term the default one, m = 0.3, is so heavy-tailed an estimate that both
/// modes' means at a few frames sit far below the converged one, alike).
#[test]
fn point_lights_ambient_occlusion_a_mirror_and_a_btf_floor_give_the_cpus_image() {
    let size = 32;
    let mut scene = merl_bunny_with_point_light_ambient_and_mirror();
    let rough = meso_materials::brdf::AnalyticBrdf::new(
        meso_materials::brdf::BrdfModel::CookTorrance,
        &[("m", 0.5), ("f0", 0.8)],
    )
    .expect("valid");
    scene.materials[1] = meso_render::scene::test_scenes::tabulated_btf(
        &rough,
        DVec3::new(0.7, 0.4, 0.2),
        glam::DVec2::ONE,
    );
    let frames = 16;
    let mut g = gpu(scene.clone(), size);
    agrees_with_cpu(
        "merl bunny with a point light, ambient, a mirror and a btf floor",
        &mut g,
        &scene,
        size,
        frames,
    );
    let run = run_frames(&mut g, 1, |_, _| {});
    let rays = run.counters.rays;
    assert!(rays.specular > 0 && rays.ambient > 0, "{rays:?}");
}

/// Forty lights: each sample takes every light once, as the CPU adaptive mode's (the
/// spmm modes choose among them above 16).
#[test]
fn forty_lights_give_the_cpus_image() {
    let size = 24;
    let scene = meso_render::scene::test_scenes::many_lights_scene(40);
    let frames = 16;
    let mut g = gpu(scene.clone(), size);
    agrees_with_cpu("forty lights", &mut g, &scene, size, frames);
}

/// A frame asked to stop at once leaves the bandwidth pass in steps of rows (the
/// studio keeps responding during it); once done, the frame is the uninterrupted
/// one's, bit for bit.
#[test]
fn a_stopped_pass_resumes_and_gives_the_uninterrupted_frame() {
    let size = 48;
    let scene = scene("merl_bunny.toml", size);
    let mut whole = gpu(scene.clone(), size);
    run_frames(&mut whole, 1, |_, _| {});
    let mut stepped = gpu(scene, size);
    let mut calls = 0;
    loop {
        calls += 1;
        assert!(calls < 1000, "the pass never ends");
        let stats = stepped
            .render(meso_render::Pass::Frame, Some(&mut || true))
            .expect("a frame's stats");
        if stats.counters.samples > 0 {
            break;
        }
    }
    // 48 rows in steps of 2,048 pixels (42 rows), after the G-buffer's own step.
    assert!(calls >= 3, "{calls} calls");
    assert!(
        whole.image().pixels() == stepped.image().pixels(),
        "the stepped pass's frame differs"
    );
}

/// A camera or size edit takes the pass away (the next frame runs a new one for the
/// new view); an emission edit keeps every sample.
#[test]
fn view_edits_run_a_new_pass_and_emission_edits_keep_the_samples() {
    let size = 24;
    let scene = scene("merl_bunny.toml", size);
    let mut g = gpu(scene.clone(), size);
    run_frames(&mut g, 2, |_, _| {});
    let before = g.device_mode().adaptive_own_samples().expect("read back");
    let mut light = scene.lights[0];
    if let meso_render::scene::Light::Area { radiance, .. } = &mut light {
        *radiance *= 2.0;
    }
    let kept = g
        .apply(SceneEdit::Light { index: 0, light })
        .expect("an emission edit");
    assert_eq!(kept, meso_render::Invalidation::Nothing);
    assert!(g.device_mode().has_adaptive_pass());
    let after = g.device_mode().adaptive_own_samples().expect("read back");
    assert_eq!(before, after, "an emission edit keeps every sample");
    let mut camera = scene.camera;
    camera.position.x += 0.2;
    g.apply(SceneEdit::Camera(camera)).expect("a camera edit");
    assert!(
        !g.device_mode().has_adaptive_pass(),
        "a new view needs a pass"
    );
    run_frames(&mut g, 1, |_, _| {});
    assert!(g.device_mode().has_adaptive_pass());
    g.apply(SceneEdit::Resize {
        width: 16,
        height: 12,
    })
    .expect("a resize");
    assert!(
        !g.device_mode().has_adaptive_pass(),
        "a new size needs a pass"
    );
    run_frames(&mut g, 2, |_, _| {});
    let image = g.image();
    assert_eq!((image.width(), image.height()), (16, 12));
    assert!(image.pixels().iter().flatten().all(|v| v.is_finite()));
    let own = g.device_mode().adaptive_own_samples().expect("read back");
    assert_eq!(own.len(), 16 * 12);
    assert!(own.iter().sum::<u32>() > 0, "the new size renders");
}

/// A device lost during the bandwidth pass (destroyed on purpose, as a driver reset
/// would) is the mode's failure, reported as in a frame: no panic, no samples, and no
/// pass asked for ever.
#[test]
fn a_device_lost_during_the_pass_is_the_modes_failure() {
    // A device of its own: the other tests share `context()`.
    let ctx = meso_gpu::GpuContext::new().expect("an adapter");
    let size = 16;
    let scene = scene("merl_bunny.toml", size);
    let mut g = GpuAdaptiveMode::prepare(
        ctx.clone(),
        scene.clone(),
        (size, size),
        AdaptiveOptions::default(),
        Prepare::quietly(),
    )
    .expect("prepares");
    run_frames(&mut g, 1, |_, _| {});
    assert!(g.failure().is_none());
    let mut camera = scene.camera;
    camera.position.x += 0.1;
    g.apply(SceneEdit::Camera(camera)).expect("a camera edit");
    ctx.device.destroy();
    let stats = g
        .render(meso_render::Pass::Frame, None)
        .expect("a frame's stats");
    assert_eq!(stats.counters.samples, 0);
    assert!(
        matches!(g.failure(), Some(meso_render::ModeError::DeviceFailed(_))),
        "{:?}",
        g.failure()
    );
}

/// Before the first frame after a restart, a preview (the CPU mode's, one sample at
/// each previewed pixel) stands for the image, on the host; the first frame replaces
/// it with the device's.
#[test]
fn a_preview_stands_for_the_image_until_the_first_frame() {
    let size = 32;
    let scene = scene("merl_bunny.toml", size);
    let mut g = gpu(scene.clone(), size);
    let stats = g
        .render(meso_render::Pass::Preview { stride: 4 }, None)
        .expect("a preview");
    assert_eq!(stats.counters.samples, 64, "one sample per 4 x 4 block");
    assert!(g.image_on_device().is_none(), "the preview is on the host");
    assert!(g.image().pixels().iter().flatten().any(|&v| v > 0.0));
    // A second preview of the same restart changes nothing.
    assert!(
        g.render(meso_render::Pass::Preview { stride: 4 }, None)
            .is_none()
    );
    run_frames(&mut g, 1, |_, _| {});
    assert!(g.image_on_device().is_some(), "the device's frame");
    assert!(
        g.render(meso_render::Pass::Preview { stride: 4 }, None)
            .is_none(),
        "no preview once a frame is shown"
    );
    let mut camera = scene.camera;
    camera.position.y += 0.1;
    g.apply(SceneEdit::Camera(camera)).expect("a camera edit");
    assert!(
        g.render(meso_render::Pass::Preview { stride: 4 }, None)
            .is_some(),
        "a restart previews again"
    );
}
