//! Mean SSIM (Wang, Bovik, Sheikh, Simoncelli 2004, IEEE TIP 13(4), eq. 13 with the
//! Gaussian-weighted statistics of eqs. 14-16 and the mean of eq. 17) on one grey plane.
//! The statistics are separable Gaussian filters evaluated only where the 11x11 window
//! fits inside the image ("valid"); no border padding, no downsampling, no colour.

use rayon::prelude::*;

/// Gaussian standard deviation of the window, in pixels (paper, section III-C).
pub const SIGMA: f64 = 1.5;
/// Window radius: 11 taps, as in the paper and in scikit-image (`int(3.5 * 1.5 + 0.5)`).
pub const RADIUS: usize = 5;
/// Window side length.
pub const WINDOW: usize = 2 * RADIUS + 1;
/// Stabilising constants (paper, eq. 6-7 and section III-C) with dynamic range L = 1.
const C1: f64 = (0.01 * 1.0) * (0.01 * 1.0);
const C2: f64 = (0.03 * 1.0) * (0.03 * 1.0);

/// Output rows per parallel task: large enough that the `2 * RADIUS` extra input rows a
/// band must filter horizontally stay a small overhead, small enough to balance work.
const BAND_ROWS: usize = 32;

/// The sampled Gaussian `exp(-k^2 / (2 sigma^2))` for `k` in `-radius..=radius`,
/// normalised to sum 1 (as the paper's MATLAB `fspecial` and SciPy's `gaussian_filter`).
pub fn gaussian_kernel(sigma: f64, radius: usize) -> Vec<f64> {
    let r = radius as f64;
    let raw: Vec<f64> = (0..2 * radius + 1)
        .map(|i| {
            let k = i as f64 - r;
            (-0.5 * k * k / (sigma * sigma)).exp()
        })
        .collect();
    let total: f64 = raw.iter().sum();
    raw.iter().map(|w| w / total).collect()
}

/// Number of statistics filtered per pixel: x, y, x^2, y^2, x*y.
const STATS: usize = 5;

/// Mean SSIM of two `width` x `height` grey planes (row-major, values meant in [0, 1]).
/// The mean runs over the `(width - 10) x (height - 10)` positions where the window fits
/// fully inside the image. Returns `None` when the image is smaller than the window.
///
/// Cost: O(width * height * WINDOW) for the separable filters, parallel over row bands;
/// the band sums are added in band order, so the result does not depend on scheduling.
pub fn mssim(x: &[f64], y: &[f64], width: usize, height: usize) -> Option<f64> {
    assert_eq!(x.len(), width * height, "plane x is not width * height");
    assert_eq!(y.len(), width * height, "plane y is not width * height");
    if width < WINDOW || height < WINDOW {
        return None;
    }
    let kernel = gaussian_kernel(SIGMA, RADIUS);
    let (out_w, out_h) = (width - 2 * RADIUS, height - 2 * RADIUS);
    let bands: Vec<f64> = (0..out_h.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|band| {
            let y0 = band * BAND_ROWS;
            let rows = BAND_ROWS.min(out_h - y0);
            band_ssim_sum(x, y, width, out_w, y0, rows, &kernel)
        })
        .collect();
    let total: f64 = bands.iter().sum();
    Some(total / (out_w * out_h) as f64)
}

/// Sum of the SSIM map over output rows `y0..y0 + rows` (output row `j` is centred on
/// input row `j + RADIUS`). First filters the band's `rows + 2 * RADIUS` input rows
/// horizontally, then vertically, then evaluates eq. 13 per position.
fn band_ssim_sum(
    x: &[f64],
    y: &[f64],
    width: usize,
    out_w: usize,
    y0: usize,
    rows: usize,
    kernel: &[f64],
) -> f64 {
    let in_rows = rows + 2 * RADIUS;
    // horizontal[s][r * out_w + i]: statistic s filtered along input row y0 + r at column i + RADIUS.
    let mut horizontal = vec![vec![0.0f64; in_rows * out_w]; STATS];
    for r in 0..in_rows {
        let row = (y0 + r) * width;
        let (xr, yr) = (&x[row..row + width], &y[row..row + width]);
        for i in 0..out_w {
            let mut acc = [0.0f64; STATS];
            for (k, &w) in kernel.iter().enumerate() {
                let (a, b) = (xr[i + k], yr[i + k]);
                acc[0] += w * a;
                acc[1] += w * b;
                acc[2] += w * (a * a);
                acc[3] += w * (b * b);
                acc[4] += w * (a * b);
            }
            for (s, v) in acc.into_iter().enumerate() {
                horizontal[s][r * out_w + i] = v;
            }
        }
    }
    let mut sum = 0.0;
    for j in 0..rows {
        for i in 0..out_w {
            let mut m = [0.0f64; STATS];
            for (k, &w) in kernel.iter().enumerate() {
                let at = (j + k) * out_w + i;
                for (s, acc) in m.iter_mut().enumerate() {
                    *acc += w * horizontal[s][at];
                }
            }
            sum += ssim_at(m);
        }
    }
    sum
}

/// Eq. 13 from the Gaussian-weighted moments `[mu_x, mu_y, E[x^2], E[y^2], E[xy]]`, with
/// the population (biased) variances of eqs. 15-16. For identical inputs every factor of
/// the numerator equals its denominator counterpart bit for bit, so the result is exactly 1.
fn ssim_at(m: [f64; STATS]) -> f64 {
    let [mx, my, exx, eyy, exy] = m;
    let vx = exx - mx * mx;
    let vy = eyy - my * my;
    let cov = exy - mx * my;
    let numerator = (2.0 * mx * my + C1) * (2.0 * cov + C2);
    let denominator = (mx * mx + my * my + C1) * (vx + vy + C2);
    numerator / denominator
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_is_normalised_symmetric_and_gaussian() {
        let k = gaussian_kernel(SIGMA, RADIUS);
        assert_eq!(k.len(), 11);
        assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        for i in 0..5 {
            assert_eq!(k[i], k[10 - i]);
        }
        // Ratio of neighbouring taps: exp(-(2k+1) / (2 sigma^2)).
        assert!((k[6] / k[5] - (-1.0 / 4.5f64).exp()).abs() < 1e-15);
    }

    /// The brute-force definition: a 2-D weighted window at every valid position.
    fn mssim_direct(x: &[f64], y: &[f64], width: usize, height: usize) -> f64 {
        let k = gaussian_kernel(SIGMA, RADIUS);
        let mut total = 0.0;
        for cy in RADIUS..height - RADIUS {
            for cx in RADIUS..width - RADIUS {
                let mut m = [0.0; STATS];
                for dy in 0..WINDOW {
                    for dx in 0..WINDOW {
                        let w = k[dy] * k[dx];
                        let idx = (cy + dy - RADIUS) * width + cx + dx - RADIUS;
                        let (a, b) = (x[idx], y[idx]);
                        m[0] += w * a;
                        m[1] += w * b;
                        m[2] += w * a * a;
                        m[3] += w * b * b;
                        m[4] += w * a * b;
                    }
                }
                total += ssim_at(m);
            }
        }
        total / ((width - 2 * RADIUS) * (height - 2 * RADIUS)) as f64
    }

    fn pattern(width: usize, height: usize, phase: f64) -> Vec<f64> {
        (0..width * height)
            .map(|i| {
                let (px, py) = ((i % width) as f64, (i / width) as f64);
                0.5 + 0.4 * (0.7 * px + phase).sin() * (0.3 * py).cos()
            })
            .collect()
    }

    #[test]
    fn separable_banded_filter_matches_the_direct_window() {
        // 75 rows make three bands, the last one partial.
        for (w, h) in [(11, 11), (12, 75), (40, 17)] {
            let (a, b) = (pattern(w, h, 0.0), pattern(w, h, 0.4));
            let fast = mssim(&a, &b, w, h).expect("big enough");
            let slow = mssim_direct(&a, &b, w, h);
            assert!((fast - slow).abs() < 1e-13, "{w}x{h}: {fast} vs {slow}");
        }
    }

    #[test]
    fn identical_is_exactly_one_and_small_is_none() {
        let a = pattern(30, 20, 0.1);
        assert_eq!(mssim(&a, &a, 30, 20), Some(1.0));
        assert_eq!(mssim(&a[..10 * 20], &a[..10 * 20], 10, 20), None);
    }

    #[test]
    fn constant_planes_follow_the_luminance_term() {
        // Zero variance: SSIM reduces to (2 mx my + C1) / (mx^2 + my^2 + C1).
        let (w, h) = (13, 12);
        let (a, b) = (vec![0.2; w * h], vec![0.6; w * h]);
        let expected = (2.0 * 0.2 * 0.6 + C1) / (0.04 + 0.36 + C1);
        let got = mssim(&a, &b, w, h).expect("big enough");
        assert!((got - expected).abs() < 1e-12, "{got} vs {expected}");
    }
}
