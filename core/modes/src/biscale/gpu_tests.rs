//! The biscale mode on the GPU against the CPU biscale mode: the same preparation
//! (shared through a precomputation cache), images compared by the GPU spmm tests'
//! rule (RMSE against the CPU's converged image at most 1.25x the CPU's own at equal
//! frames plus 0.2% of the mean; means within 2% plus four standard errors), the
//! environment layer on its own, and edits. They need a wgpu adapter (CI: lavapipe,
//! WGPU_BACKEND=vulkan) and fail without one, naming the cause.

use std::path::Path;

use glam::DVec3;
use meso_render::scene::{Environment, Material, Scene, load_scene};
use meso_render::{Invalidation, Prepare, RenderMode, SceneEdit, run_frames};

use super::{BiscaleMode, BiscaleSettings, GpuBiscaleMode};
use crate::REFERENCE_SEED_XOR;
use crate::gpu_test_support::{
    MeanOf, agrees as agrees_with, context, mean, merl_bunny,
    merl_bunny_with_point_light_ambient_and_mirror,
};

/// Small resolutions so lavapipe and a debug build take seconds; one cache for every
/// mode of a test, so the CPU and the GPU use the very same precomputation.
fn settings(cache: &Path) -> BiscaleSettings {
    BiscaleSettings {
        cube_n: 8,
        local_res: 8,
        view_res: 8,
        rays_per_side: 1,
        refine_vertices: 256,
        cache_dir: Some(cache.to_path_buf()),
        ..BiscaleSettings::default()
    }
}

fn cpu(scene: Scene, size: u32, s: &BiscaleSettings) -> BiscaleMode {
    BiscaleMode::prepare(scene, size, size, s.clone(), Prepare::quietly()).expect("CPU biscale")
}

fn gpu(scene: Scene, size: u32, s: &BiscaleSettings) -> GpuBiscaleMode {
    GpuBiscaleMode::prepare(
        context().clone(),
        scene,
        (size, size),
        s.clone(),
        Prepare::quietly(),
    )
    .expect("GPU biscale")
}

/// `gpu` after `frames` more frames against the CPU biscale mode of `scene` (converged:
/// 16x the frames, another seed; and at equal frames), by the rule in the header.
/// Returns the GPU's mean and the reference's.
fn agrees(
    what: &str,
    scene: &Scene,
    gpu: &mut GpuBiscaleMode,
    size: u32,
    frames: u32,
    s: &BiscaleSettings,
) -> (f64, f64) {
    let mut ref_scene = scene.clone();
    ref_scene.render.seed ^= REFERENCE_SEED_XOR;
    let mut reference = cpu(ref_scene, size, s);
    run_frames(&mut reference, 16 * frames, |_, _| {});
    let reference = reference.image();
    let mut same = cpu(scene.clone(), size, s);
    let agreed = agrees_with(
        what,
        (gpu, &mut same),
        &reference,
        frames,
        size,
        MeanOf::Converged,
    );
    assert_eq!(
        gpu.device_mode().overflows(),
        (0, 0),
        "{what}: traversal overflows"
    );
    agreed
}

#[test]
fn the_gpu_biscale_image_is_the_cpus() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = merl_bunny();
    let mut mode = gpu(scene.clone(), 48, &s);
    assert_eq!(
        (mode.kind(), mode.device()),
        (meso_render::ModeKind::Biscale, meso_render::Device::Gpu)
    );
    agrees("merl_bunny", &scene, &mut mode, 48, 16, &s);
    let diagnostics = mode.diagnostics();
    let summary = diagnostics.summary().expect("a summary");
    assert!(summary.contains("biclusters"), "{summary}");
    let memory = diagnostics
        .0
        .iter()
        .find_map(|d| match d {
            meso_render::Diagnostic::DeviceMemory(m) => Some(m.clone()),
            _ => None,
        })
        .expect("device memory");
    eprintln!("{summary}\n{memory:?}");
    // L* is vertices x 3 x M f32, all of it on the device.
    let lstar = memory
        .iter()
        .find(|(n, _)| *n == "biscale_lstar")
        .expect("L*")
        .1;
    let m = u64::from(s.local_res * s.local_res);
    assert_eq!(lstar, mode.precomputed().frames.len() as u64 * 3 * m * 4);
}

/// The environment layer alone (no light, no ambient term): the precomputed part and
/// the traced peaks, which the lights' layers cannot hide.
#[test]
fn the_gpu_environment_layer_is_the_cpus() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let mut scene = merl_bunny();
    scene.lights.clear();
    scene.ambient = None;
    let mut mode = gpu(scene.clone(), 32, &s);
    let (m_gpu, m_ref) = agrees(
        "merl_bunny, environment only",
        &scene,
        &mut mode,
        32,
        48,
        &s,
    );
    assert!(
        m_ref > 0.0 && (m_gpu / m_ref - 1.0).abs() < 0.02,
        "{m_gpu} against {m_ref}"
    );
}

/// A light's strength re-weights its layer only: the image moves by exactly the
/// light's layer (linear in the strength), no sample is dropped, and the environment
/// layer keeps its samples.
#[test]
fn a_light_edit_changes_only_the_lights_layer() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = merl_bunny();
    let mut mode = gpu(scene.clone(), 32, &s);
    run_frames(&mut mode, 4, |_, _| {});
    let before = mode.image();
    let progress = mode.progress();
    let light = scene.lights[0];
    let emission = light.emission();
    let set = |k: f64, mode: &mut GpuBiscaleMode| {
        let edit = SceneEdit::Light {
            index: 0,
            light: light.with_emission(emission * k),
        };
        let inv = mode.apply(edit).expect("a light edit");
        assert_eq!(
            inv,
            Invalidation::Nothing,
            "a strength edit keeps every sample"
        );
        mode.image()
    };
    let twice = set(2.0, &mut mode);
    let thrice = set(3.0, &mut mode);
    assert_eq!(mode.progress().min_samples, progress.min_samples);
    let (mut moved, mut off) = (0.0f64, 0.0f64);
    for ((a, b), c) in before
        .pixels()
        .iter()
        .zip(twice.pixels())
        .zip(thrice.pixels())
    {
        for ch in 0..3 {
            let (d1, d2) = (f64::from(b[ch] - a[ch]), f64::from(c[ch] - a[ch]));
            moved = moved.max(d1.abs());
            off = off.max((d2 - 2.0 * d1).abs());
        }
    }
    assert!(moved > 1e-3, "the light lights the scene");
    assert!(
        off <= 1e-4 * moved.max(1.0) + 1e-5,
        "not linear in the light: {off} of {moved}"
    );
    // Off altogether: the environment's and ambient layers' samples remain.
    let dark = set(0.0, &mut mode);
    assert!(mean(&dark) > 0.0 && mean(&dark) < mean(&before));
}

/// A camera edit and an environment turn (a light change: a new split's lighting and
/// a new L* uploaded) give the CPU's image of the edited scene.
#[test]
fn camera_and_environment_edits_give_the_cpus_image() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = merl_bunny();
    let mut mode = gpu(scene.clone(), 32, &s);
    run_frames(&mut mode, 2, |_, _| {});
    let mut edited = scene.clone();
    edited.camera.position += DVec3::new(0.6, 0.2, 0.0);
    let env = edited.environment.as_mut().expect("an environment");
    env.rotate_y_deg += 120.0;
    let turned: Environment = env.clone();
    assert_eq!(
        mode.apply(SceneEdit::Camera(edited.camera))
            .expect("camera"),
        Invalidation::All
    );
    mode.apply(SceneEdit::Environment(Some(turned)))
        .expect("a turn");
    agrees(
        "merl_bunny, moved and turned",
        &edited,
        &mut mode,
        32,
        8,
        &s,
    );
}

/// A material edit to an analytic BRDF (a gray table on the device) gives the CPU's
/// image, and so does an SPMM pack put on the bunny (it was refused by name before
/// the device read packs' biscale tables).
#[test]
fn material_edits_are_uploaded() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = merl_bunny();
    let mut mode = gpu(scene.clone(), 32, &s);
    let plastic = Material::Brdf {
        brdf: meso_materials::brdf::AnalyticBrdf::with_defaults(
            meso_materials::brdf::BrdfModel::CookTorrance,
        ),
        albedo: DVec3::new(0.2, 0.5, 0.8),
    };
    let mut edited = scene.clone();
    edited.materials[1] = plastic.clone();
    mode.apply(SceneEdit::Material {
        index: 1,
        material: plastic,
    })
    .expect("a BRDF on the device");
    agrees("merl_bunny, BRDF floor", &edited, &mut mode, 32, 8, &s);
    let pack = meso_render::scene::test_scenes::tilted_spmm();
    let bunny = scene.meshes[0].material;
    mode.apply(SceneEdit::Material {
        index: bunny,
        material: pack.clone(),
    })
    .expect("a pack on the device");
    edited.materials[bunny] = pack;
    GpuBiscaleMode::supports(&edited).expect("packs are rendered");
    agrees("merl_bunny, tilted pack", &edited, &mut mode, 32, 8, &s);
}

/// The default scene (the leather pack on the bunny, a Lambertian floor, an area
/// light, the ambient term) under the studio map, so the pack's biscale tables light
/// the bunny: its image is the CPU's.
fn leather_merl_bunny() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/scenes/default.toml");
    let mut scene = load_scene(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    scene.environment = merl_bunny().environment;
    let bunny = scene.meshes[0].material;
    assert!(
        matches!(scene.materials[bunny], Material::Spmm { .. }),
        "the default scene's bunny wears a pack"
    );
    scene
}

/// Bytes of the biscale tables on the device.
fn table_bytes(mode: &GpuBiscaleMode) -> u64 {
    mode.device_mode().biscale_bytes().tables
}

#[test]
fn an_spmm_pack_gives_the_cpus_image() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = leather_merl_bunny();
    let mut mode = gpu(scene.clone(), 48, &s);
    // The leather's basis rows are on the device (views x cells per basis).
    let row = u64::from(s.view_res * s.view_res * s.local_res * s.local_res) * 4;
    assert!(table_bytes(&mode) > row, "{} bytes", table_bytes(&mode));
    eprintln!("default scene: biscale_tables {} bytes", table_bytes(&mode));
    agrees("default scene under the map", &scene, &mut mode, 48, 16, &s);
}

/// The leather's precomputed part alone (no peaks, lights or ambient term), the floor
/// in leather too with texels several pixels wide, so each pixel shows one texel's
/// cluster and weights rather than the grain's average (which a wrong cluster index
/// keeps within the noise on the bunny, whose texels are far below a pixel).
#[test]
fn the_precomputed_part_of_a_pack_is_the_cpus() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = BiscaleSettings {
        traced_share: 0.0,
        ..settings(cache.path())
    };
    let mut scene = leather_merl_bunny();
    scene.lights.clear();
    scene.ambient = None;
    let (bunny, floor) = (scene.meshes[0].material, scene.meshes[1].material);
    let Material::Spmm { material, .. } = &scene.materials[bunny] else {
        panic!("a pack");
    };
    scene.materials[floor] = Material::Spmm {
        material: material.clone(),
        uv_scale: glam::DVec2::splat(0.125),
        residual: true,
        npca: 0,
    };
    let mut mode = gpu(scene.clone(), 32, &s);
    agrees("leather, precomputed part", &scene, &mut mode, 32, 32, &s);
}

/// A pack with a residual (the woven cloth of tests/scenes/biscale.toml, its mean and
/// six components) on the floor, texels several pixels wide, in the precomputed part
/// alone where the only noise is the jitter and the view pick: the residual's rows
/// times each texel's own coefficients, as on the CPU (on the bunny, where a pixel
/// averages many texels, coefficients read one term off stay within the noise).
#[test]
fn an_spmm_residual_in_the_precomputed_part_is_the_cpus() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = BiscaleSettings {
        traced_share: 0.0,
        ..settings(cache.path())
    };
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/scenes/biscale.toml");
    let cloth = load_scene(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let Material::Spmm {
        material, residual, ..
    } = &cloth.materials[cloth.meshes[0].material]
    else {
        panic!("biscale.toml's bunny wears a pack");
    };
    assert!(*residual && material.npca() > 6, "a residual in use");
    let mut scene = leather_merl_bunny();
    scene.lights.clear();
    scene.ambient = None;
    let floor = scene.meshes[1].material;
    scene.materials[floor] = Material::Spmm {
        material: material.clone(),
        uv_scale: glam::DVec2::splat(0.125),
        residual: true,
        npca: 6,
    };
    let mut mode = gpu(scene.clone(), 32, &s);
    agrees("woven cloth floor, residual", &scene, &mut mode, 32, 32, &s);
}

/// Edits of the pack: its weights scaled (the same bases, new texel weights on the
/// device), then the floor made a pack too; each gives the CPU's image of the
/// edited scene.
#[test]
fn spmm_pack_edits_give_the_cpus_image() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = leather_merl_bunny();
    let (bunny, floor_index) = (scene.meshes[0].material, scene.meshes[1].material);
    let mut mode = gpu(scene.clone(), 32, &s);
    run_frames(&mut mode, 2, |_, _| {});
    let mut edited = scene.clone();
    let Material::Spmm { material, .. } = &mut edited.materials[bunny] else {
        panic!("a pack");
    };
    let scaled = material
        .with_weight_scale(
            &meso_materials::spmm::WeightTarget::cluster(0),
            [2.0, 0.5, 1.0],
        )
        .expect("a weight edit");
    *material = std::sync::Arc::new(scaled);
    let before = mean(&mode.image());
    let inv = mode
        .apply(SceneEdit::Material {
            index: bunny,
            material: edited.materials[bunny].clone(),
        })
        .expect("a weight edit on the device");
    // The pixels whose samples shaded the edited texels restart (their texture boxes
    // are the device's marks): some, not none.
    assert!(
        matches!(inv, Invalidation::Pixels(n) if n > 0) || inv == Invalidation::All,
        "the bunny's pixels restart: {inv:?}"
    );
    let (m_gpu, _) = agrees("leather, cluster 0 scaled", &edited, &mut mode, 32, 8, &s);
    assert!((m_gpu / before - 1.0).abs() > 1e-3, "the edit shows");
    let floor = match &edited.materials[bunny] {
        Material::Spmm { material, .. } => Material::Spmm {
            material: material.clone(),
            uv_scale: glam::DVec2::splat(3.0),
            residual: true,
            npca: 0,
        },
        _ => unreachable!("a pack"),
    };
    edited.materials[floor_index] = floor.clone();
    mode.apply(SceneEdit::Material {
        index: floor_index,
        material: floor,
    })
    .expect("a pack on the floor");
    agrees("leather on the floor too", &edited, &mut mode, 32, 8, &s);
}

/// New meshes (the bunny moved along the floor) run the precomputation again: the
/// device's image is the CPU's of the moved scene, its shadow moved with it.
#[test]
fn a_mesh_edit_precomputes_again_and_gives_the_cpus_image() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = merl_bunny();
    let mut mode = gpu(scene.clone(), 24, &s);
    run_frames(&mut mode, 1, |_, _| {});
    let mut edited = scene.clone();
    for p in &mut edited.meshes[0].positions {
        *p += DVec3::new(0.3, 0.0, -0.2);
    }
    let key_before = mode.precomputed().key;
    let inv = mode
        .apply(SceneEdit::Meshes(edited.meshes.clone()))
        .expect("new meshes");
    assert_eq!(inv, Invalidation::All);
    assert_ne!(mode.precomputed().key, key_before, "precomputed again");
    agrees("merl_bunny, moved bunny", &edited, &mut mode, 24, 8, &s);
}

/// The precomputed part alone (nothing traced: no peaks, no light, no ambient term),
/// where the only noise is the pixel jitter and the view pick, so the rule is tight
/// enough to see how L* is interpolated and the rows are read (a nearest-vertex L*
/// passes the image tests above, whose noise is the peaks', and fails this one).
#[test]
fn the_precomputed_part_is_the_cpus() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = BiscaleSettings {
        traced_share: 0.0,
        ..settings(cache.path())
    };
    let mut scene = merl_bunny();
    scene.lights.clear();
    scene.ambient = None;
    let mut mode = gpu(scene.clone(), 32, &s);
    agrees(
        "merl_bunny, precomputed part",
        &scene,
        &mut mode,
        32,
        48,
        &s,
    );
}

/// A `btf` material has no table: the device evaluates each cell's response at one
/// jittered direction with its own `btf` code, as the CPU does with its shading core.
#[test]
fn a_btf_floor_is_evaluated_per_cell_as_on_the_cpu() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let mut scene = merl_bunny();
    scene.materials[1] = meso_render::scene::test_scenes::tabulated_btf(
        &meso_materials::brdf::AnalyticBrdf::with_defaults(
            meso_materials::brdf::BrdfModel::CookTorrance,
        ),
        DVec3::new(0.7, 0.4, 0.2),
        glam::DVec2::ONE,
    );
    let mut mode = gpu(scene.clone(), 32, &s);
    agrees("merl_bunny, btf floor", &scene, &mut mode, 32, 16, &s);
}

/// The viewport denoiser runs on the device in this mode too: the first frame's
/// picture is the reference filter of its own image and guides (the guides' agreement
/// with the CPU's is the device half's test, meso-gpu's `the_device_guides_are_the_cpu_modes`).
#[test]
fn the_first_frames_are_denoised_on_the_device() {
    let cache = tempfile::tempdir().expect("temp dir");
    let s = settings(cache.path());
    let size = 24;
    let mut g = gpu(merl_bunny(), size, &s);
    run_frames(&mut g, 1, |_, _| {});
    let denoiser = meso_render::Denoiser::for_samples(1);
    let estimate = g.image_on_device().expect("on the device");
    let picture = g
        .denoised_on_device(estimate.as_ref(), &denoiser, 1.0)
        .expect("filtered on the device")
        .read()
        .expect("read back");
    let image = estimate.read().expect("read back");
    let guides = g.guides(meso_render::Pass::Frame).expect("guides");
    let expected = denoiser.apply_reference(&image, &guides).expect("guides");
    let worst = picture
        .pixels()
        .iter()
        .zip(expected.pixels())
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs() / q[c].abs().max(1.0)))
        .fold(0.0f32, f32::max);
    assert!(worst <= 1e-4, "largest relative difference {worst}");
    // Guides of a scene: the floor and the bunny hit, finite; nothing else.
    assert!(guides.depth.iter().any(|d| d.is_finite()));
    assert!(guides.albedo.iter().flatten().all(|v| v.is_finite()));
}

/// A point light, the ambient term and a mirror on top of the MERL bunny's area light
/// and map: the lights the device traces with the GPU spmm mode's estimators, and the
/// mirror's bounce into the precomputed part.
#[test]
fn point_lights_ambient_occlusion_and_a_mirror_give_the_cpus_image() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = merl_bunny_with_point_light_ambient_and_mirror();
    let mut mode = gpu(scene.clone(), 32, &s);
    agrees(
        "merl_bunny with a point light, ambient occlusion and a mirror",
        &scene,
        &mut mode,
        32,
        16,
        &s,
    );
    let run = run_frames(&mut mode, 1, |_, _| {});
    let rays = run.counters.rays;
    assert!(rays.specular > 0 && rays.ambient > 0, "{rays:?}");
}

/// Forty lights: the device selects among them stochastically (as the GPU and CPU spmm
/// modes do above 16), the CPU biscale mode samples every one.
#[test]
fn forty_lights_give_the_cpus_image() {
    let cache = tempfile::tempdir().expect("a temporary folder");
    let s = settings(cache.path());
    let scene = meso_render::scene::test_scenes::many_lights_scene(40);
    let mut mode = gpu(scene.clone(), 32, &s);
    agrees("forty lights", &scene, &mut mode, 32, 64, &s);
}
