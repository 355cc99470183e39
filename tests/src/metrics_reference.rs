//! `meso_materials::metrics::compare` against independent values from scikit-image 0.26 and
//! numpy (tests/reference/metrics_reference.py), on EXR fixtures written by the OpenEXR
//! Python bindings, so this is also an EXR interoperability test (float32, half, Y-only).
//! Needs no Python: the fixtures and metrics_values.json are committed.

use std::path::{Path, PathBuf};

use meso_materials::image::read_exr;
use meso_materials::metrics::compare;
use serde::Deserialize;

/// RMSE and PSNR: both sides compute in f64 from the same stored f32/half samples and
/// differ only in summation order (numpy's pairwise sum against Meso's per-row sums),
/// an effect near 1e-15 relative (measured: 3e-16); 1e-9 leaves six orders of margin yet catches an f32
/// accumulation, a wrong divisor (3 * pixels) or a missing exposure factor.
const RMSE_REL_TOL: f64 = 1e-9;
/// MSSIM: both sides filter in f64 with the same normalised 11-tap Gaussian; the
/// variance terms `E[x^2] - mu^2` cancel, leaving about 1e-15 absolute (measured: 2e-15).
/// 1e-9 still catches an f32 implementation (4e-7 on these cases), and each of sample
/// covariance, sigma 1.4, a 7x7 uniform window, no clamping, the uncropped 'reflect' map
/// and per-channel RGB SSIM moves at least one case by more than 1e-4.
const MSSIM_ABS_TOL: f64 = 1e-9;

#[derive(Deserialize)]
struct Values {
    cases: Vec<Case>,
}

#[derive(Deserialize)]
struct Case {
    name: String,
    reference: PathBuf,
    test: PathBuf,
    exposure_stops: f64,
    rmse: f64,
    psnr_db: Option<f64>,
    mssim: f64,
    max_abs_error: f64,
    max_error_pixel: [u32; 2],
    width: u32,
    height: u32,
}

fn reference_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("reference")
}

fn load() -> Values {
    let path = reference_dir().join("metrics_values.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn assert_rel(name: &str, what: &str, got: f64, want: f64, tol: f64) {
    let err = (got - want).abs();
    assert!(
        err <= tol * want.abs(),
        "{name}: {what} {got:e}, reference {want:e} (relative error {:e} > {tol:e})",
        err / want.abs()
    );
}

#[test]
fn metrics_match_scikit_image_reference_values() {
    let values = load();
    assert!(values.cases.len() >= 8, "the reference file lost cases");
    let mut worst = (0.0f64, 0.0f64);
    for case in &values.cases {
        let name = case.name.as_str();
        let read = |p: &Path| {
            let path = reference_dir().join(p);
            read_exr(&path).unwrap_or_else(|e| panic!("{name}: {e}"))
        };
        let (reference, test) = (read(&case.reference), read(&case.test));
        let c = compare(&reference, &test, case.exposure_stops)
            .unwrap_or_else(|e| panic!("{name}: {e}"));

        assert_eq!(
            (c.width, c.height),
            (case.width, case.height),
            "{name}: size"
        );
        if case.rmse == 0.0 {
            assert_eq!(c.rmse, 0.0, "{name}");
            assert_eq!(c.psnr_db, f64::INFINITY, "{name}");
            assert_eq!(
                case.psnr_db, None,
                "{name}: the reference has a PSNR for rmse 0"
            );
        } else {
            assert_rel(name, "RMSE", c.rmse, case.rmse, RMSE_REL_TOL);
            let psnr = case
                .psnr_db
                .unwrap_or_else(|| panic!("{name}: no reference PSNR"));
            assert_rel(name, "PSNR", c.psnr_db, psnr, RMSE_REL_TOL);
            worst.0 = worst.0.max((c.rmse - case.rmse).abs() / case.rmse);
        }
        // The largest error is one sample difference times a power of two, exact on both
        // sides; serde_json (without its `float_roundtrip` feature) may parse the decimal
        // one ulp away, hence two ulps.
        assert_rel(
            name,
            "max |error|",
            c.max_abs_error,
            case.max_abs_error,
            2.0 * f64::EPSILON,
        );
        assert_eq!(
            c.max_error_pixel, case.max_error_pixel,
            "{name}: pixel of the max error"
        );
        let d = (c.mssim - case.mssim).abs();
        assert!(
            d <= MSSIM_ABS_TOL,
            "{name}: MSSIM {:.15}, reference {:.15} (|difference| {d:e} > {MSSIM_ABS_TOL:e})",
            c.mssim,
            case.mssim
        );
        worst.1 = worst.1.max(d);
    }
    eprintln!(
        "worst RMSE relative error {:e}, worst MSSIM difference {:e}",
        worst.0, worst.1
    );
}

/// The fixtures exercise what the reader must handle: a Y-only half file is grey, and
/// the spike the script planted sits where it said.
#[test]
fn fixtures_read_as_the_script_wrote_them() {
    let dir = reference_dir().join("metrics_fixtures");
    let grey = read_exr(&dir.join("grey_y_half.exr")).expect("Y-only half EXR");
    assert_eq!((grey.width(), grey.height()), (33, 21));
    assert!(grey.pixels().iter().all(|p| p[0] == p[1] && p[1] == p[2]));
    let spiked = read_exr(&dir.join("outlier_spiked.exr")).expect("float EXR");
    let plain = read_exr(&dir.join("outlier.exr")).expect("float EXR");
    assert!(spiked.get(17, 9)[1] - plain.get(17, 9)[1] > 4.9);
}
