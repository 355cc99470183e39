//! Image regressions: renders of the test scenes compared with committed golden EXRs
//! using the tolerances (and their reasons) in tests/golden/tolerances.toml, one entry
//! per golden. Each is rendered on 1 thread and on the machine's threads, which must
//! agree exactly. `MESO_UPDATE_GOLDEN=1 cargo test -p meso-tests golden` rewrites them.

use std::collections::BTreeMap;
use std::path::PathBuf;

use meso_materials::image::{Image, read_exr, write_exr};
use meso_materials::metrics::{Comparison, compare};
use meso_render::scene::load_scene;
use meso_render::{Prepare, run_frames};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Golden {
    scene: String,
    image: String,
    width: u32,
    height: u32,
    frames: u32,
    /// RMSE over the golden's mean (over pixels and channels): a bound on the error
    /// relative to the image's own brightness, so a dim scene is held as tightly as
    /// a bright one. A uniformly dimmed image `(1 - d) x golden` has relative RMSE
    /// `d x rms/mean >= d`, so any bound below 0.1 catches 10% dimmer.
    max_relative_rmse: f64,
    min_mssim: f64,
}

/// Mean over pixels and channels.
fn mean(image: &Image) -> f64 {
    let sum: f64 = image
        .pixels()
        .iter()
        .flat_map(|p| p.iter().map(|&c| c as f64))
        .sum();
    sum / (3 * image.pixels().len()) as f64
}

/// How `image` compares with the golden `reference` and whether `g`'s bounds hold.
fn judge(g: &Golden, reference: &Image, image: &Image) -> (Comparison, f64, bool) {
    let c = compare(reference, image, 0.0).expect("same size");
    let relative = c.rmse / mean(reference);
    (
        c,
        relative,
        relative <= g.max_relative_rmse && c.mssim >= g.min_mssim,
    )
}

fn goldens() -> BTreeMap<String, Golden> {
    let goldens: BTreeMap<String, Golden> = toml::from_str(
        &std::fs::read_to_string(root().join("golden/tolerances.toml")).expect("tolerances file"),
    )
    .expect("valid tolerances");
    assert_eq!(
        goldens.keys().collect::<Vec<_>>(),
        [
            "cloth_64",
            "cornell_64",
            "default_scene_64",
            "env_64",
            "fitted_64"
        ],
        "one entry per golden image"
    );
    goldens
}

fn render(g: &Golden, threads: usize) -> Image {
    let scene = load_scene(&root().join("scenes").join(&g.scene)).expect("test scene loads");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    pool.install(|| {
        let (kind, device) = (scene.render.mode, scene.render.device);
        let mut mode =
            meso_modes::create(kind, device, scene, g.width, g.height, Prepare::quietly())
                .expect("the scene's mode renders it");
        let run = run_frames(mode.as_mut(), g.frames, |_, _| {});
        assert_eq!(run.dropped, 0, "{}: no non-finite sample", g.scene);
        mode.image()
    })
}

#[test]
fn test_scenes_match_their_golden_images_on_any_thread_count() {
    let goldens = goldens();
    let update = std::env::var_os("MESO_UPDATE_GOLDEN").is_some();
    let mut failures = Vec::new();
    for (name, g) in &goldens {
        let image = render(g, 2);
        assert_eq!(image, render(g, 1), "{name}: 1 and 2 threads differ");
        let path = root().join("golden").join(&g.image);
        if update {
            write_exr(&path, &image).expect("write golden");
        }
        let reference = read_exr(&path).expect("golden image (MESO_UPDATE_GOLDEN=1 makes it)");
        let (c, relative, pass) = judge(g, &reference, &image);
        eprintln!("{name}: relative rmse {relative:e} mssim {}", c.mssim);
        if !pass {
            failures.push(format!("{name}: relative rmse {relative:e}, {c:?}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The tolerances see a dim light on every scene: each golden scaled by 0.9 (the whole
/// scene's lighting 10% dimmer) fails its own bounds. (The exact re-render passing
/// them is the test above.)
#[test]
fn every_golden_tolerance_rejects_a_ten_percent_dimmer_image() {
    let mut passed = Vec::new();
    for (name, g) in &goldens() {
        let reference = read_exr(&root().join("golden").join(&g.image)).expect("golden image");
        let mut dim = reference.clone();
        for p in dim.pixels_mut() {
            *p = p.map(|c| 0.9 * c);
        }
        let (c, relative, pass) = judge(g, &reference, &dim);
        eprintln!(
            "{name}: mean {:.4}, 0.9 x golden: rmse {:.4} relative {relative:.4} mssim {:.4}",
            mean(&reference),
            c.rmse,
            c.mssim
        );
        if pass {
            passed.push(name.clone());
        }
    }
    assert!(passed.is_empty(), "a 10% dimmer image passes {passed:?}");
}
