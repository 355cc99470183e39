//! `meso compare`: image metrics between two files.

use std::path::Path;

use crate::*;

fn write_exr(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> [f32; 3]) {
    let mut img = meso_materials::image::Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            img.set(x, y, f(x, y));
        }
    }
    meso_materials::image::write_exr(path, &img).expect("write test EXR");
}

#[test]
fn compare_reports_metrics_and_rejects_bad_pairs() {
    let dir = tempfile::tempdir().expect("temp dir");
    let a = dir.path().join("a.exr");
    let b = dir.path().join("b.exr");
    let small = dir.path().join("small.exr");
    write_exr(&a, 32, 24, |x, y| [x as f32 / 32.0, y as f32 / 24.0, 0.5]);
    // B differs from A by exactly 0.1 in the red channel of one pixel.
    write_exr(&b, 32, 24, |x, y| {
        let r = x as f32 / 32.0 + if (x, y) == (5, 7) { 0.1 } else { 0.0 };
        [r, y as f32 / 24.0, 0.5]
    });
    write_exr(&small, 16, 24, |_, _| [0.0; 3]);
    let (a_s, b_s) = (a.to_str().expect("utf-8"), b.to_str().expect("utf-8"));

    let same = meso(&["compare", a_s, a_s, "--json"], "");
    assert_ok(&same);
    let v: serde_json::Value = serde_json::from_str(&stdout(&same)).expect("JSON");
    assert_eq!(v["rmse"], 0.0);
    assert_eq!(v["mssim"], 1.0);
    assert!(v["psnr_db"].is_null());

    let diff = meso(&["compare", a_s, b_s, "--json"], "");
    assert_ok(&diff);
    let v: serde_json::Value = serde_json::from_str(&stdout(&diff)).expect("JSON");
    // RMSE over 32*24 pixels x 3 channels with one entry off by 0.1.
    let expected_rmse = (0.01f64 / (32.0 * 24.0 * 3.0)).sqrt();
    let rmse = v["rmse"].as_f64().expect("rmse");
    assert!(
        (rmse - expected_rmse).abs() < 1e-6 * expected_rmse + 1e-9,
        "{rmse}"
    );
    assert!((v["max_abs_error"].as_f64().expect("max") - 0.1).abs() < 1e-6);
    assert_eq!(v["max_error_pixel"], serde_json::json!([5, 7]));
    assert!(v["mssim"].as_f64().expect("mssim") < 1.0);

    let human = meso(&["compare", a_s, b_s], "");
    assert_ok(&human);
    assert!(stdout(&human).contains("MSSIM"));

    let small_s = small.to_str().expect("utf-8");
    assert_bad_input(&meso(&["compare", a_s, small_s], ""), &["32x24", "16x24"]);
    let missing = dir.path().join("missing.exr");
    assert_bad_input(
        &meso(&["compare", a_s, missing.to_str().expect("utf-8")], ""),
        &["missing.exr"],
    );
    let garbage = dir.path().join("garbage.exr");
    std::fs::write(&garbage, b"not an exr at all").expect("write");
    assert_bad_input(
        &meso(&["compare", garbage.to_str().expect("utf-8"), a_s], ""),
        &["garbage.exr"],
    );
}
