//! Image regressions: renders of the test scenes compared with committed golden EXRs
//! using the tolerances (and their reasons) in tests/golden/tolerances.toml.
//! `MESO_UPDATE_GOLDEN=1 cargo test -p meso-tests golden` rewrites the goldens.

use std::path::PathBuf;

use meso_core::image::{read_exr, write_exr};
use meso_core::metrics::compare;
use meso_core::scene::load_scene;
use meso_core::trace::{Film, Renderer};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Tolerance {
    image: String,
    max_rmse: f64,
    min_mssim: f64,
}

#[test]
fn default_scene_matches_its_golden_image() {
    let tolerances: std::collections::BTreeMap<String, Tolerance> = toml::from_str(
        &std::fs::read_to_string(root().join("golden/tolerances.toml")).expect("tolerances file"),
    )
    .expect("valid tolerances");
    let tol = &tolerances["default_scene_32"];
    let scene = load_scene(&root().join("scenes/default.toml")).expect("default scene");
    let (w, h, frames) = (32, 32, 16);
    let renderer = Renderer::new(&scene, w, h);
    let mut film = Film::new(w, h);
    for f in 0..frames {
        film.add_frame(&renderer.render_frame(f).0);
    }
    let image = film.mean();
    let golden = root().join("golden").join(&tol.image);
    if std::env::var_os("MESO_UPDATE_GOLDEN").is_some() {
        write_exr(&golden, &image).expect("write golden");
    }
    let reference = read_exr(&golden).expect("golden image (MESO_UPDATE_GOLDEN=1 makes it)");
    let c = compare(&reference, &image, 0.0).expect("same size");
    assert!(
        c.rmse <= tol.max_rmse && c.mssim >= tol.min_mssim,
        "{}: {c:?}",
        tol.image
    );
}
