//! Image error metrics of a test image against a reference: RMSE, PSNR, mean SSIM
//! (Wang et al. 2004, in `ssim`) and the largest absolute error with its pixel, as
//! defined in docs/formats/images.md and matched against scikit-image 0.26 in
//! tests/reference/metrics_reference.py. No perceptual colour metrics (no FLIP, no ΔE).

pub mod ssim;

use rayon::prelude::*;
use serde::Serialize;

use crate::image::{Image, exposure_scale};

/// The error of a test image against a reference, after the same exposure on both.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Comparison {
    /// `sqrt(mean over pixels and the 3 channels of (s*test - s*ref)^2)`, `s = 2^stops`,
    /// on linear values, not clamped.
    pub rmse: f64,
    /// `20 log10(1 / rmse)`: peak 1 after exposure. `f64::INFINITY` when `rmse` is 0
    /// (serde_json writes that as `null`).
    pub psnr_db: f64,
    /// Mean SSIM on Rec. 709 luminance scaled by `s` and clamped to [0, 1]: 11x11
    /// Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03, L = 1, population statistics,
    /// averaged over the positions where the window fits inside the image.
    pub mssim: f64,
    /// Largest `|s*test - s*ref|` over pixels and channels (linear, not clamped).
    pub max_abs_error: f64,
    /// `[x, y]` of the first pixel (row-major from the top) holding `max_abs_error`.
    pub max_error_pixel: [u32; 2],
    pub width: u32,
    pub height: u32,
}

/// Why two images cannot be compared.
#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    #[error(
        "the images differ in size: reference {}x{}, test {}x{}",
        reference.0, reference.1, test.0, test.1
    )]
    SizeMismatch {
        reference: (u32, u32),
        test: (u32, u32),
    },
    #[error(
        "the {which} image holds a non-finite value at pixel ({x}, {y}); metrics need finite radiance"
    )]
    NonFinite { which: &'static str, x: u32, y: u32 },
    #[error(
        "the images are {width}x{height}; MSSIM needs at least {min}x{min} pixels (its Gaussian window)",
        min = ssim::WINDOW
    )]
    TooSmall { width: u32, height: u32 },
    #[error("exposure {stops} stops gives no finite, positive scale 2^stops")]
    Exposure { stops: f64 },
    #[error("the squared error overflows at exposure {stops} stops")]
    Overflow { stops: f64 },
}

/// Compares `test` against `reference` after scaling both by `2^exposure_stops`.
///
/// Errors: different sizes (naming both), a non-finite pixel (naming the image and the
/// pixel, reference first, row-major), images smaller than the 11x11 SSIM window, an
/// exposure whose scale is not finite and positive, or an overflowing squared error.
pub fn compare(
    reference: &Image,
    test: &Image,
    exposure_stops: f64,
) -> Result<Comparison, MetricsError> {
    let (width, height) = (reference.width(), reference.height());
    if (width, height) != (test.width(), test.height()) {
        return Err(MetricsError::SizeMismatch {
            reference: (width, height),
            test: (test.width(), test.height()),
        });
    }
    check_finite(reference, "reference")?;
    check_finite(test, "test")?;
    let scale = exposure_scale(exposure_stops);
    if !(scale.is_finite() && scale > 0.0) {
        return Err(MetricsError::Exposure {
            stops: exposure_stops,
        });
    }
    let (w, h) = (width as usize, height as usize);
    if w < ssim::WINDOW || h < ssim::WINDOW {
        return Err(MetricsError::TooSmall { width, height });
    }

    let errors = abs_errors(reference, test, scale);
    if !errors.sum_sq.is_finite() {
        return Err(MetricsError::Overflow {
            stops: exposure_stops,
        });
    }
    let rmse = (errors.sum_sq / (3 * w * h) as f64).sqrt();
    let psnr_db = if rmse == 0.0 {
        f64::INFINITY
    } else {
        20.0 * (1.0 / rmse).log10()
    };

    let luma = |img: &Image| -> Vec<f64> {
        img.pixels()
            .par_iter()
            .map(|&p| clamped_luminance(p, scale))
            .collect()
    };
    let mssim = ssim::mssim(&luma(reference), &luma(test), w, h)
        .expect("size checked against the window above");

    let (index, _) = errors.max_at;
    Ok(Comparison {
        rmse,
        psnr_db,
        mssim,
        max_abs_error: errors.max_at.1,
        max_error_pixel: [(index % w) as u32, (index / w) as u32],
        width,
        height,
    })
}

/// Rec. 709 luminance in f64 after exposure, clamped to SSIM's dynamic range [0, 1].
/// The operation order (weights, then scale, then clamp) is the reference script's.
fn clamped_luminance(p: [f32; 3], scale: f64) -> f64 {
    let [r, g, b] = p.map(f64::from);
    ((0.2126 * r + 0.7152 * g + 0.0722 * b) * scale).clamp(0.0, 1.0)
}

fn check_finite(image: &Image, which: &'static str) -> Result<(), MetricsError> {
    match image
        .pixels()
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        None => Ok(()),
        Some(i) => {
            let w = image.width() as usize;
            Err(MetricsError::NonFinite {
                which,
                x: (i % w) as u32,
                y: (i / w) as u32,
            })
        }
    }
}

/// Sum of squared exposed differences, and the largest absolute one with its pixel index.
struct AbsErrors {
    sum_sq: f64,
    max_at: (usize, f64),
}

/// Per-row partial sums in parallel, combined in row order so the result is deterministic;
/// ties for the maximum keep the first pixel in row-major order.
fn abs_errors(reference: &Image, test: &Image, scale: f64) -> AbsErrors {
    let w = reference.width() as usize;
    let rows: Vec<AbsErrors> = reference
        .pixels()
        .par_chunks(w)
        .zip(test.pixels().par_chunks(w))
        .enumerate()
        .map(|(y, (ref_row, test_row))| {
            let mut acc = AbsErrors {
                sum_sq: 0.0,
                max_at: (y * w, 0.0),
            };
            for (x, (r, t)) in ref_row.iter().zip(test_row).enumerate() {
                for c in 0..3 {
                    let d = (f64::from(t[c]) - f64::from(r[c])) * scale;
                    acc.sum_sq += d * d;
                    if d.abs() > acc.max_at.1 {
                        acc.max_at = (y * w + x, d.abs());
                    }
                }
            }
            acc
        })
        .collect();
    let mut total = AbsErrors {
        sum_sq: 0.0,
        max_at: (0, 0.0),
    };
    for row in rows {
        total.sum_sq += row.sum_sq;
        if row.max_at.1 > total.max_at.1 {
            total.max_at = row.max_at;
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth gradient with a sinusoidal pattern, values in about [0.05, 0.95].
    fn scene(width: u32, height: u32) -> Image {
        let mut img = Image::new(width, height);
        for y in 0..height {
            for x in 0..width {
                let (u, v) = (x as f32 / width as f32, y as f32 / height as f32);
                let s = 0.2 * (0.9 * x as f32).sin() * (0.5 * y as f32).cos();
                img.set(
                    x,
                    y,
                    [0.3 + 0.4 * u + s, 0.5 + 0.3 * v - s, 0.4 + 0.2 * u * v],
                );
            }
        }
        img
    }

    /// `img` plus deterministic uniform noise of half-width `amplitude` per channel.
    fn noisy(img: &Image, amplitude: f32, seed: u64) -> Image {
        let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut out = img.clone();
        for p in out.pixels_mut() {
            for c in p.iter_mut() {
                // xorshift64*: good enough for test noise.
                state ^= state >> 12;
                state ^= state << 25;
                state ^= state >> 27;
                let u =
                    (state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40) as f32 / (1u64 << 24) as f32;
                *c += amplitude * (2.0 * u - 1.0);
            }
        }
        out
    }

    #[test]
    fn identical_images_are_perfect() {
        let a = scene(37, 23);
        for stops in [0.0, -2.0, 3.5] {
            let c = compare(&a, &a, stops).expect("same size");
            assert_eq!(c.rmse, 0.0);
            assert_eq!(c.psnr_db, f64::INFINITY);
            assert_eq!(c.mssim, 1.0);
            assert_eq!(c.max_abs_error, 0.0);
            assert_eq!(c.max_error_pixel, [0, 0]);
            assert_eq!((c.width, c.height), (37, 23));
        }
    }

    #[test]
    fn one_changed_pixel_gives_the_closed_form_errors() {
        let a = scene(32, 24);
        let mut b = a.clone();
        let mut p = b.get(5, 7);
        p[0] += 0.25;
        b.set(5, 7, p);
        let c = compare(&a, &b, 0.0).expect("same size");
        let expected = (0.0625f64 / (32.0 * 24.0 * 3.0)).sqrt();
        assert!((c.rmse - expected).abs() < 1e-7 * expected, "{}", c.rmse);
        assert!((c.psnr_db - 20.0 * (1.0 / expected).log10()).abs() < 1e-6);
        assert!((c.max_abs_error - 0.25).abs() < 1e-6);
        assert_eq!(c.max_error_pixel, [5, 7]);
        assert!(c.mssim < 1.0 && c.mssim > 0.9, "{}", c.mssim);

        // One stop up doubles every linear error and costs 20 log10(2) dB.
        let up = compare(&a, &b, 1.0).expect("same size");
        assert!((up.rmse - 2.0 * c.rmse).abs() < 1e-12);
        assert!((up.max_abs_error - 2.0 * c.max_abs_error).abs() < 1e-12);
        assert!((c.psnr_db - up.psnr_db - 20.0 * 2f64.log10()).abs() < 1e-9);
    }

    #[test]
    fn swapping_reference_and_test_changes_nothing() {
        let a = scene(29, 31);
        let b = noisy(&a, 0.1, 7);
        let (ab, ba) = (
            compare(&a, &b, 0.5).expect("ab"),
            compare(&b, &a, 0.5).expect("ba"),
        );
        assert_eq!(ab.rmse, ba.rmse);
        assert_eq!(ab.max_abs_error, ba.max_abs_error);
        assert_eq!(ab.max_error_pixel, ba.max_error_pixel);
        // SSIM is symmetric in its arguments (eq. 13); the floating-point evaluation is
        // symmetric too up to rounding.
        assert!((ab.mssim - ba.mssim).abs() < 1e-14);
    }

    #[test]
    fn mssim_falls_as_noise_grows() {
        let a = scene(48, 40);
        let mut last = 1.0;
        for amplitude in [0.01, 0.03, 0.1, 0.3] {
            let c = compare(&a, &noisy(&a, amplitude, 3), 0.0).expect("same size");
            assert!(c.mssim < last, "noise {amplitude}: {} !< {last}", c.mssim);
            last = c.mssim;
        }
        assert!(last < 0.5, "heavy noise still scores {last}");
    }

    #[test]
    fn clamping_hides_differences_above_white_from_ssim_only() {
        // Both images are brighter than white everywhere: SSIM sees two white planes,
        // RMSE sees the linear difference.
        let a = Image::from_pixels(12, 12, vec![[2.0; 3]; 144]).expect("144");
        let b = Image::from_pixels(12, 12, vec![[3.0; 3]; 144]).expect("144");
        let c = compare(&a, &b, 0.0).expect("same size");
        assert_eq!(c.mssim, 1.0);
        assert!((c.rmse - 1.0).abs() < 1e-12);
        // Three stops down, luminance 0.25 vs 0.375 is in range and SSIM drops.
        assert!(compare(&a, &b, -3.0).expect("same size").mssim < 0.99);
    }

    #[test]
    fn bad_pairs_are_named_errors() {
        let err = compare(&scene(32, 24), &scene(16, 24), 0.0).expect_err("sizes differ");
        let msg = err.to_string();
        assert!(msg.contains("32x24") && msg.contains("16x24"), "{msg}");

        let mut nan = scene(20, 20);
        nan.set(4, 9, [0.0, f32::NAN, 0.0]);
        let err = compare(&scene(20, 20), &nan, 0.0).expect_err("NaN");
        assert!(
            err.to_string().contains("test") && err.to_string().contains("(4, 9)"),
            "{err}"
        );
        let mut inf = scene(20, 20);
        inf.set(19, 0, [f32::INFINITY, 0.0, 0.0]);
        let err = compare(&inf, &nan, 0.0).expect_err("inf in the reference");
        assert!(
            err.to_string().contains("reference") && err.to_string().contains("(19, 0)"),
            "{err}"
        );

        let err =
            compare(&scene(10, 30), &scene(10, 30), 0.0).expect_err("narrower than the window");
        assert!(
            err.to_string().contains("10x30") && err.to_string().contains("11x11"),
            "{err}"
        );

        for stops in [f64::NAN, 2000.0, -2000.0] {
            assert!(matches!(
                compare(&scene(12, 12), &scene(12, 12), stops),
                Err(MetricsError::Exposure { .. })
            ));
        }
        let huge = Image::from_pixels(12, 12, vec![[f32::MAX; 3]; 144]).expect("144");
        let err = compare(&huge, &Image::new(12, 12), 900.0).expect_err("overflow");
        assert!(matches!(err, MetricsError::Overflow { .. }), "{err}");
    }

    #[test]
    fn comparison_serialises_infinite_psnr_as_null() {
        let a = scene(12, 12);
        let json = serde_json::to_value(compare(&a, &a, 0.0).expect("same")).expect("serialise");
        assert!(json["psnr_db"].is_null());
        assert_eq!(json["max_error_pixel"], serde_json::json!([0, 0]));
    }
}
