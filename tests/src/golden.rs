//! Image regressions: renders of the test scenes compared with committed golden EXRs
//! using the tolerances (and their reasons) in tests/golden/tolerances.toml, one entry
//! per golden. Each is rendered on 1 thread and on the machine's threads, which must
//! agree exactly. `MESO_UPDATE_GOLDEN=1 cargo test -p meso-tests golden` rewrites them.

use std::collections::BTreeMap;
use std::path::PathBuf;

use meso_core::image::{Image, read_exr, write_exr};
use meso_core::metrics::compare;
use meso_core::modes;
use meso_core::render::{Prepare, run_frames};
use meso_core::scene::load_scene;

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
    max_rmse: f64,
    min_mssim: f64,
}

fn render(g: &Golden, threads: usize) -> Image {
    let scene = load_scene(&root().join("scenes").join(&g.scene)).expect("test scene loads");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    pool.install(|| {
        let (kind, device) = (scene.render.mode, scene.render.device);
        let mut mode = modes::create(kind, device, scene, g.width, g.height, Prepare::quietly())
            .expect("the scene's mode renders it");
        let run = run_frames(mode.as_mut(), g.frames, |_, _| {});
        assert_eq!(run.dropped, 0, "{}: no non-finite sample", g.scene);
        mode.image()
    })
}

#[test]
fn test_scenes_match_their_golden_images_on_any_thread_count() {
    let goldens: BTreeMap<String, Golden> = toml::from_str(
        &std::fs::read_to_string(root().join("golden/tolerances.toml")).expect("tolerances file"),
    )
    .expect("valid tolerances");
    assert!(goldens.len() >= 3, "default, Cornell box and cloth scenes");
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
        let c = compare(&reference, &image, 0.0).expect("same size");
        eprintln!("{name}: rmse {:e} mssim {}", c.rmse, c.mssim);
        if !(c.rmse <= g.max_rmse && c.mssim >= g.min_mssim) {
            failures.push(format!("{name}: {c:?}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
