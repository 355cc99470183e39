//! The biscale mode against the spmm mode's converged image (the reference renderer)
//! on the environment-only bunny scene (tests/scenes/biscale.toml), with the tolerances
//! and their derivation in tests/golden/biscale_tolerances.toml; and the biclustering's
//! losslessness on the bunny's transfer matrix.

use std::collections::BTreeMap;
use std::collections::btree_map::Entry;
use std::path::PathBuf;

use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::image::Image;
use meso_materials::metrics::compare;
use meso_materials::rng::SampleStream;
use meso_modes::biscale::{BiscaleMode, BiscaleSettings};
use meso_render::scene::{Background, Material, Scene, load_scene};
use meso_render::{Device, ModeKind, Prepare, RenderMode, SceneEdit, run_frames};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Tolerance {
    /// `spmm` (the scene's own material) or `lambertian` (albedo 0.6 instead).
    material: String,
    width: u32,
    height: u32,
    reference_frames: u32,
    frames: u32,
    cube_n: u32,
    local_res: u32,
    /// RMSE over the reference's mean, as for the goldens.
    max_relative_rmse: f64,
    min_mssim: f64,
    /// |mean(biscale) / mean(reference) - 1|: a uniformly dimmer image fails it.
    max_mean_deviation: f64,
}

fn mean(image: &Image) -> f64 {
    let s: f64 = image
        .pixels()
        .iter()
        .flat_map(|p| p.iter().map(|&c| c as f64))
        .sum();
    s / (3 * image.pixels().len()) as f64
}

fn with_material(scene: &Scene, name: &str) -> Material {
    match name {
        "spmm" => scene.materials[0].clone(),
        "lambertian" => Material::Brdf {
            brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
            albedo: glam::DVec3::splat(0.6),
        },
        other => panic!("unknown material `{other}` in the tolerances"),
    }
}

fn reference(scene: &Scene, t: &Tolerance) -> Image {
    let mut scene = scene.clone();
    scene.render.seed ^= 0x5245_4645;
    let mut mode = meso_modes::create(
        ModeKind::Spmm,
        Device::Cpu,
        scene,
        t.width,
        t.height,
        Prepare::quietly(),
    )
    .expect("spmm renders the scene");
    run_frames(mode.as_mut(), t.reference_frames, |_, _| {});
    mode.image()
}

#[test]
fn biscale_agrees_with_the_converged_spmm_image_and_is_lossless_on_the_bunny() {
    let tolerances: BTreeMap<String, Tolerance> = toml::from_str(
        &std::fs::read_to_string(root().join("golden/biscale_tolerances.toml"))
            .expect("tolerances file"),
    )
    .expect("valid tolerances");
    let mut scene = load_scene(&root().join("scenes/biscale.toml")).expect("scene");
    // A black background: the comparison is of the object's shading, not of the map
    // seen directly (identical in both modes up to anti-aliasing noise).
    scene.background = Background::Color(glam::DVec3::ZERO);
    let mut modes_by_res: BTreeMap<(u32, u32), BiscaleMode> = BTreeMap::new();
    let mut failures = Vec::new();
    let mut references: BTreeMap<(String, u32, u32, u32), Image> = BTreeMap::new();
    for (name, t) in &tolerances {
        let material = with_material(&scene, &t.material);
        let mut s = scene.clone();
        s.materials[0] = material.clone();
        let key = (t.cube_n, t.local_res);
        if let Entry::Vacant(slot) = modes_by_res.entry(key) {
            // The scene's own vertices: the tolerances (and the bias they state, docs/
            // rendering.md "Limits") are those of per-vertex transfer on the bunny; the
            // refinement has its own test (`refinement_puts_a_receivers_shadow...`).
            let settings = BiscaleSettings {
                cube_n: t.cube_n,
                local_res: t.local_res,
                cache_dir: None,
                refine_vertices: 0,
                ..BiscaleSettings::default()
            };
            let mode =
                BiscaleMode::prepare(s.clone(), t.width, t.height, settings, Prepare::quietly())
                    .expect("biscale renders the scene");
            // Lossless: the biclustered product is the dense one for random lighting.
            let pre = mode.precomputed();
            let rng = SampleStream::new(&[t.cube_n as u64]);
            let light: Vec<[f32; 3]> = (0..pre.transfer.cols as u64)
                .map(|k| {
                    [
                        rng.at(3 * k) as f32,
                        rng.at(3 * k + 1) as f32,
                        rng.at(3 * k + 2) as f32,
                    ]
                })
                .collect();
            let dense = pre.transfer.apply_f64(&light);
            let got = pre.biclusters.apply(&light);
            let largest = dense.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
            let err = dense
                .iter()
                .zip(&got)
                .flat_map(|(d, g)| (0..3).map(move |c| (d[c] - g[c] as f64).abs()))
                .fold(0.0, f64::max);
            eprintln!(
                "n {} M {}: {} vertices, {} biclusters, FLOP ratio {:.3}, error {:e} of {:e}",
                t.cube_n,
                t.local_res * t.local_res,
                pre.frames.len(),
                pre.biclusters.len(),
                pre.flop_ratio(),
                err,
                largest
            );
            assert!(err <= 1e-6 * largest, "not lossless: {err} of {largest}");
            assert!(pre.flop_ratio() < 0.5, "FLOP ratio {}", pre.flop_ratio());
            slot.insert(mode);
        }
        let mode = modes_by_res.get_mut(&key).expect("made above");
        mode.apply(SceneEdit::Material { index: 0, material })
            .expect("a material the mode renders");
        mode.apply(SceneEdit::Resize {
            width: t.width,
            height: t.height,
        })
        .expect("size");
        run_frames(mode, t.frames, |_, _| {});
        let image = mode.image();
        let reference = references
            .entry((t.material.clone(), t.width, t.height, t.reference_frames))
            .or_insert_with(|| reference(&s, t))
            .clone();
        let c = compare(&reference, &image, 0.0).expect("same size");
        let relative = c.rmse / mean(&reference);
        let brightness = mean(&image) / mean(&reference);
        eprintln!(
            "{name}: relative rmse {relative:.4}, mssim {:.4}, mean ratio {brightness:.4}",
            c.mssim
        );
        if relative > t.max_relative_rmse
            || c.mssim < t.min_mssim
            || (brightness - 1.0).abs() > t.max_mean_deviation
        {
            failures.push(format!(
                "{name}: relative rmse {relative}, mssim {}",
                c.mssim
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
