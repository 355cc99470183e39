//! The GPU path against the CPU reference: BRDFs, basis functions and SPMM texels in
//! WGSL against core's f64 evaluation, closest hits against the CPU's traversal, and
//! the mode's images against the CPU mode's. They need a wgpu adapter (CI: Mesa's
//! lavapipe with WGPU_BACKEND=vulkan) and fail without one, naming the cause.
//!
//! Split by concept under `tests/`; this file holds what they share: the device
//! context, the test scenes, the GPU mode and the image rule (a GPU image against the
//! CPU's converged one).

mod brdfs;
mod btf;
mod denoise;
mod device;
mod environment;
mod images;
mod kernel_cases;
mod lights;
mod memory;
mod merl;
mod packs;
mod sampler;
mod traversal;

use std::sync::OnceLock;

use super::GpuContext;

/// The device the tests share, made once (tests that need a device of their own make
/// one).
pub(super) fn context() -> &'static GpuContext {
    static CONTEXT: OnceLock<GpuContext> = OnceLock::new();
    CONTEXT.get_or_init(|| {
        GpuContext::new().unwrap_or_else(|e| {
            panic!("the GPU tests need a wgpu adapter (CI: lavapipe, WGPU_BACKEND=vulkan): {e}")
        })
    })
}

/// A scene file of `tests/scenes`, loaded as the CLI loads it.
pub(super) fn test_scene(name: &str) -> meso_render::scene::Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/scenes")
        .join(name);
    meso_render::scene::load_scene(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The GPU mode of `scene` at `size` x `size` on the shared device.
fn gpu_mode(scene: meso_render::scene::Scene, size: u32) -> super::GpuSpmmMode {
    super::GpuSpmmMode::prepare(
        context().clone(),
        scene,
        size,
        size,
        meso_render::Prepare::quietly(),
    )
    .expect("the GPU mode renders the scene")
}

/// The root-mean-square difference of two images over every channel.
fn rmse(a: &meso_materials::image::Image, b: &meso_materials::image::Image) -> f64 {
    let n = a.pixels().len() as f64 * 3.0;
    let sum: f64 = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum();
    (sum / n).sqrt()
}

/// The mean of every channel of every pixel.
fn mean(a: &meso_materials::image::Image) -> f64 {
    a.pixels().iter().flatten().map(|&v| v as f64).sum::<f64>() / (a.pixels().len() * 3) as f64
}

/// The GPU image after `frames` frames against the CPU's converged one: an error no
/// larger than the CPU's own after as many frames (both drawing the default sampler,
/// Owen-scrambled Sobol points in the same dimension layout; packs sampled from their
/// bases on both) times 1.25 plus a floor of 0.2% of the image's mean, the same mean within
/// 2% plus four standard errors of an image mean after `frames` frames (the CPU's own
/// RMSE over the square root of the pixel count: sharp MERL lobes make rare, large
/// samples, whose noise in the mean is far above 2% at 16 frames), no non-finite pixel
/// and no traversal past its bounds.
fn image_agrees_with_the_cpu(scene_file: &str, size: u32, frames: u32) {
    image_of_scene_agrees_with_the_cpu(scene_file, test_scene(scene_file), size, frames);
}

/// The image rule for a scene built in code; `scene_file` names it in messages.
fn image_of_scene_agrees_with_the_cpu(
    scene_file: &str,
    scene: meso_render::scene::Scene,
    size: u32,
    frames: u32,
) {
    mode_agrees_with_the_cpu(scene_file, scene, size, frames, None);
}

/// The rule above for `gpu` (a fresh mode of `scene` if `None`) after `frames` more
/// frames: a mode with a history (edits that kept some layers' samples) has at least
/// as many samples per layer as a fresh one.
fn mode_agrees_with_the_cpu(
    scene_file: &str,
    scene: meso_render::scene::Scene,
    size: u32,
    frames: u32,
    gpu: Option<super::GpuSpmmMode>,
) {
    let m = measure_against_the_cpu(scene_file, scene, size, frames, gpu);
    assert_within_the_rule(scene_file, size, &[m]);
}

/// The rule pooled over `seeds` (squared errors and means averaged): for scenes whose
/// RMSE at a few frames swings with the seed.
fn scene_agrees_with_the_cpu_over_seeds(scene_file: &str, size: u32, frames: u32, seeds: &[u64]) {
    let runs: Vec<Measured> = seeds
        .iter()
        .map(|&seed| {
            let mut scene = test_scene(scene_file);
            scene.render.seed = seed;
            measure_against_the_cpu(scene_file, scene, size, frames, None)
        })
        .collect();
    assert_within_the_rule(scene_file, size, &runs);
}

/// One scene's errors after a few frames against the CPU's converged image.
struct Measured {
    e_gpu: f64,
    e_cpu: f64,
    m_gpu: f64,
    m_ref: f64,
}

fn measure_against_the_cpu(
    scene_file: &str,
    mut scene: meso_render::scene::Scene,
    size: u32,
    frames: u32,
    gpu: Option<super::GpuSpmmMode>,
) -> Measured {
    use meso_render::{RenderMode, run_frames};
    scene.render.sampler = meso_materials::rng::Sampler::Sobol;
    let seed = scene.render.seed;
    let mut reference =
        meso_modes::trace::SpmmMode::new(scene.clone(), size, size).expect("CPU mode");
    run_frames(&mut reference, 16 * frames, |_, _| {});
    let reference = reference.image();
    // Another seed than the reference's, so the two are independent.
    let mut other = scene.clone();
    other.render.seed += 1;
    let mut cpu = meso_modes::trace::SpmmMode::new(other, size, size).expect("CPU mode");
    run_frames(&mut cpu, frames, |_, _| {});
    let mut gpu = gpu.unwrap_or_else(|| gpu_mode(scene, size));
    let run = run_frames(&mut gpu, frames, |_, _| {});
    let image = gpu.image();
    assert!(
        image.pixels().iter().flatten().all(|v| v.is_finite()),
        "{scene_file}: non-finite pixels"
    );
    assert_eq!(run.dropped, 0, "{scene_file}: non-finite samples");
    assert_eq!(gpu.overflows(), (0, 0), "{scene_file}: traversal overflows");
    assert!(run.counters.rays.shadow + run.counters.rays.environment > 0);
    let (e_gpu, e_cpu) = (rmse(&image, &reference), rmse(&cpu.image(), &reference));
    let (m_gpu, m_ref) = (mean(&image), mean(&reference));
    eprintln!(
        "{scene_file} {size}x{size}, {frames} frames, seed {}: RMSE gpu {e_gpu:.5}, cpu {e_cpu:.5}; mean gpu {m_gpu:.5}, cpu {:.5}, reference {m_ref:.5}",
        seed,
        mean(&cpu.image())
    );
    Measured {
        e_gpu,
        e_cpu,
        m_gpu,
        m_ref,
    }
}

/// The image rule over one or more measurements, pooled.
fn assert_within_the_rule(scene_file: &str, size: u32, runs: &[Measured]) {
    let n = runs.len() as f64;
    let pooled =
        |f: fn(&Measured) -> f64| (runs.iter().map(|m| f(m).powi(2)).sum::<f64>() / n).sqrt();
    let average = |f: fn(&Measured) -> f64| runs.iter().map(f).sum::<f64>() / n;
    let (e_gpu, e_cpu) = (pooled(|m| m.e_gpu), pooled(|m| m.e_cpu));
    let (m_gpu, m_ref) = (average(|m| m.m_gpu), average(|m| m.m_ref));
    assert!(
        e_gpu <= 1.25 * e_cpu + 0.002 * m_ref,
        "{scene_file}: GPU RMSE {e_gpu} against the CPU's {e_cpu}"
    );
    // The standard error of the averaged mean.
    let standard_error = e_cpu / f64::from(size) / n.sqrt();
    assert!(
        (m_gpu - m_ref).abs() <= 0.02 * m_ref + 4.0 * standard_error,
        "{scene_file}: mean {m_gpu} against {m_ref} (standard error {standard_error})"
    );
}
