//! What the GPU modes' tests share: the device, scenes, and the image rule by which a
//! GPU mode's image is judged against its CPU mode (the GPU spmm tests' rule: RMSE
//! against the CPU's converged image at most 1.25x the CPU's own at equal frames plus
//! 0.2% of the mean; means within 2% plus four standard errors, of the converged image
//! or, where a mode's early frames are not an unbiased estimate of it, of the CPU
//! mode's at equal frames).

use std::path::Path;
use std::sync::OnceLock;

use glam::DVec3;
use meso_gpu::GpuContext;
use meso_materials::image::Image;
use meso_render::scene::{Ambient, Light, Material, Scene, load_scene, mesh};
use meso_render::{RenderMode, run_frames};

pub fn context() -> &'static GpuContext {
    static CONTEXT: OnceLock<GpuContext> = OnceLock::new();
    CONTEXT.get_or_init(|| {
        GpuContext::new().unwrap_or_else(|e| {
            panic!("the GPU tests need a wgpu adapter (CI: lavapipe, WGPU_BACKEND=vulkan): {e}")
        })
    })
}

pub fn rmse(a: &Image, b: &Image) -> f64 {
    let n = a.pixels().len() as f64 * 3.0;
    let sum: f64 = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..3).map(move |c| (f64::from(p[c]) - f64::from(q[c])).powi(2)))
        .sum();
    (sum / n).sqrt()
}

pub fn mean(a: &Image) -> f64 {
    a.pixels()
        .iter()
        .flatten()
        .map(|&v| f64::from(v))
        .sum::<f64>()
        / (a.pixels().len() * 3) as f64
}

/// Which mean a GPU mode's image is held to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeanOf {
    /// The converged image's.
    Converged,
    /// The CPU mode's at equal frames (the adaptive mode: its up-sampled pixels and its
    /// allocation's skew bias the early frames' mean, alike on both devices).
    CpuAtEqualFrames,
}

/// `gpu` after `frames` more frames against `reference` (converged: run by the caller)
/// and `same` (the CPU mode, run here for `frames` frames), by the rule in the header,
/// for a `size` x `size` image. Returns the GPU's mean and the reference's.
pub fn agrees(
    what: &str,
    (gpu, same): (&mut dyn RenderMode, &mut dyn RenderMode),
    reference: &Image,
    frames: u32,
    size: u32,
    mean_of: MeanOf,
) -> (f64, f64) {
    run_frames(same, frames, |_, _| {});
    let run = run_frames(gpu, frames, |_, _| {});
    let image = gpu.image();
    assert!(
        image.pixels().iter().flatten().all(|v| v.is_finite()),
        "{what}: non-finite pixels"
    );
    assert_eq!(run.dropped, 0, "{what}: non-finite samples");
    let (e_gpu, e_cpu) = (rmse(&image, reference), rmse(&same.image(), reference));
    let (m_gpu, m_ref) = (mean(&image), mean(reference));
    eprintln!(
        "{what}: {size}x{size}, {frames} frames: RMSE gpu {e_gpu:.5}, cpu {e_cpu:.5} (ratio {:.3}); mean gpu {m_gpu:.5}, cpu {:.5}, reference {m_ref:.5} ({:+.2}%)",
        e_gpu / e_cpu,
        mean(&same.image()),
        100.0 * (m_gpu / m_ref - 1.0)
    );
    assert!(
        e_gpu <= 1.25 * e_cpu + 0.002 * m_ref,
        "{what}: GPU RMSE {e_gpu} against the CPU's {e_cpu}"
    );
    let standard_error = e_cpu / f64::from(size);
    let target = match mean_of {
        MeanOf::Converged => m_ref,
        MeanOf::CpuAtEqualFrames => mean(&same.image()),
    };
    assert!(
        (m_gpu - target).abs() <= 0.02 * target + 4.0 * standard_error,
        "{what}: mean {m_gpu} against {target} ({mean_of:?}; standard error {standard_error})"
    );
    (m_gpu, m_ref)
}

/// The MERL bunny on its MERL floor under the studio map and one area light
/// (`tests/scenes/merl_bunny.toml`).
pub fn merl_bunny() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/scenes/merl_bunny.toml");
    load_scene(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `merl_bunny` with what it lacks of the light and material kinds: a point light, the
/// ambient term, and a mirror upright behind the bunny, facing the camera.
pub fn merl_bunny_with_point_light_ambient_and_mirror() -> Scene {
    let mut scene = merl_bunny();
    scene.lights.push(Light::Point {
        position: DVec3::new(0.8, 1.4, 1.0),
        intensity: DVec3::new(1.5, 1.2, 1.0),
    });
    scene.ambient = Some(Ambient {
        radiance: DVec3::splat(0.3),
        radius: 0.5,
    });
    scene.materials.push(Material::Mirror {
        reflectance: DVec3::new(0.9, 0.85, 0.8),
    });
    scene.material_names.push("chrome".into());
    let mirror = scene.materials.len() - 1;
    scene.meshes.push(mesh::quad(
        DVec3::new(-1.0, 0.0, -0.6),
        DVec3::new(2.0, 0.0, 0.0),
        DVec3::new(0.0, 1.2, 0.0),
        mirror,
    ));
    scene
}
