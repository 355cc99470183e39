//! Local bandwidth of a 2D signal by a Haar wavelet pyramid (Bagher et al. 2013,
//! section 2.3, eq. 7 and Fig. 6): per level the largest coefficient, the finest level
//! that is still significant (eq. 7, epsilon = 0.01), and per pixel the level holding
//! the 95th percentile of its wavelet energy, turned into a Nyquist sampling rate in
//! samples per pixel of the analysed image. The caller converts pixels to radians or
//! metres. Coefficients are L1-normalised (differences of block means), so a step of
//! height h gives coefficients of the same size at every level, as in the paper's
//! `1/2^i psi((x - 2^i j) / 2^i)`. The floor below which a coefficient is noise is
//! epsilon times the signal's peak (eq. 7 writes epsilon times the largest
//! coefficient, which for a constant signal would promote its rounding noise).

/// Eq. 7's epsilon: finer levels whose summed largest coefficients stay below this
/// fraction of the largest one are noise.
pub const EPSILON: f64 = 0.01;
/// Share of a pixel's wavelet energy below its bandwidth (section 2.3).
pub const PERCENTILE: f64 = 0.95;

/// The detail coefficients of one level: per block of `2^(k+1)` pixels, the three
/// orientations' coefficients (horizontal, vertical, diagonal).
#[derive(Clone, Debug)]
struct Level {
    width: usize,
    height: usize,
    details: Vec<[f64; 3]>,
}

/// The Haar pyramid of an image: level 0 is the finest (2 x 2 pixel blocks).
#[derive(Clone, Debug)]
pub struct Pyramid {
    width: usize,
    height: usize,
    levels: Vec<Level>,
    /// max |pixel|: coefficients below epsilon times this are noise.
    peak: f64,
}

impl Pyramid {
    /// Analyses a `width` x `height` image (row-major). Odd sizes replicate their last
    /// row or column, so an edge adds no detail; the pyramid stops when a side is 1.
    pub fn new(width: usize, height: usize, pixels: &[f64]) -> Self {
        assert_eq!(pixels.len(), width * height, "one value per pixel");
        let mut levels = Vec::new();
        let (mut w, mut h) = (width, height);
        let mut approx = pixels.to_vec();
        while w > 1 && h > 1 {
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            let at = |x: usize, y: usize| approx[y.min(h - 1) * w + x.min(w - 1)];
            let mut next = vec![0.0; nw * nh];
            let mut details = vec![[0.0; 3]; nw * nh];
            for y in 0..nh {
                for x in 0..nw {
                    let (a, b) = (at(2 * x, 2 * y), at(2 * x + 1, 2 * y));
                    let (c, d) = (at(2 * x, 2 * y + 1), at(2 * x + 1, 2 * y + 1));
                    next[y * nw + x] = (a + b + c + d) / 4.0;
                    details[y * nw + x] = [
                        (a - b + c - d) / 4.0,
                        (a + b - c - d) / 4.0,
                        (a - b - c + d) / 4.0,
                    ];
                }
            }
            levels.push(Level {
                width: nw,
                height: nh,
                details,
            });
            approx = next;
            (w, h) = (nw, nh);
        }
        Self {
            width,
            height,
            levels,
            peak: pixels.iter().fold(0.0, |m, p| m.max(p.abs())),
        }
    }

    fn floor(&self) -> f64 {
        EPSILON * self.peak
    }

    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// Eq. 7's lambda_k^max: the largest |coefficient| of each level, finest first,
    /// 0 where it is below the noise floor.
    pub fn level_maxima(&self) -> Vec<f64> {
        let floor = self.floor();
        self.levels
            .iter()
            .map(|l| {
                let m = l
                    .details
                    .iter()
                    .flat_map(|d| d.iter().map(|c| c.abs()))
                    .fold(0.0, f64::max);
                if m > floor { m } else { 0.0 }
            })
            .collect()
    }

    /// Eq. 7: the finest level whose finer levels together stay below epsilon times
    /// the largest coefficient; `None` when every coefficient is 0 (a constant signal).
    pub fn significant_level(&self) -> Option<usize> {
        significant_level(&self.level_maxima())
    }

    /// Per pixel, the Nyquist rate in samples per pixel of the level holding the 95th
    /// percentile of the pixel's wavelet energy (coarse to fine), counting only
    /// coefficients above the noise floor (eq. 7's epsilon, header): a
    /// level-k band has period 2^(k+1) pixels, so rate 2^-k. 0 where nothing is
    /// significant.
    pub fn rate_map(&self) -> Vec<f64> {
        let global = self.level_maxima().into_iter().fold(0.0, f64::max);
        let floor = self.floor();
        let mut out = vec![0.0; self.width * self.height];
        if global == 0.0 {
            return out;
        }
        let mut energy = vec![0.0; self.levels.len()];
        for y in 0..self.height {
            for x in 0..self.width {
                for (k, l) in self.levels.iter().enumerate() {
                    let (bx, by) = (
                        (x >> (k + 1)).min(l.width - 1),
                        (y >> (k + 1)).min(l.height - 1),
                    );
                    let d = l.details[by * l.width + bx];
                    energy[k] = d.iter().filter(|c| c.abs() > floor).map(|c| c * c).sum();
                }
                out[y * self.width + x] = percentile_rate(&energy);
            }
        }
        out
    }
}

/// Eq. 7 on given level maxima (finest first): the finest level `i` with
/// `sum_{k < i} lambda_k < epsilon max_k lambda_k`.
pub fn significant_level(maxima: &[f64]) -> Option<usize> {
    let max = maxima.iter().copied().fold(0.0, f64::max);
    if max <= 0.0 {
        return None;
    }
    let mut finer = 0.0;
    for (i, &m) in maxima.iter().enumerate() {
        if finer + m >= EPSILON * max {
            return Some(i);
        }
        finer += m;
    }
    Some(maxima.len() - 1)
}

/// The rate 2^-k of the level at the 95th percentile of `energy` (finest first),
/// accumulated from the coarsest level; 0 for no energy.
fn percentile_rate(energy: &[f64]) -> f64 {
    let total: f64 = energy.iter().sum();
    if total <= 0.0 {
        return 0.0;
    }
    let mut acc = 0.0;
    for k in (0..energy.len()).rev() {
        acc += energy[k];
        if acc >= PERCENTILE * total {
            return 0.5f64.powi(k as i32);
        }
    }
    1.0
}

/// The rate map of an image reduced to `out_w` x `out_h` blocks by their maximum (a
/// conservative down-scale, as the paper's 16 x 16 lobe images).
pub fn max_blocks(
    rates: &[f64],
    width: usize,
    height: usize,
    out_w: usize,
    out_h: usize,
) -> Vec<f64> {
    let mut out = vec![0.0f64; out_w * out_h];
    for y in 0..height {
        for x in 0..width {
            let (bx, by) = (x * out_w / width, y * out_h / height);
            let o = &mut out[by * out_w + bx];
            *o = o.max(rates[y * width + x]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(n: usize, f: impl Fn(usize, usize) -> f64) -> Vec<f64> {
        (0..n * n).map(|i| f(i % n, i / n)).collect()
    }

    #[test]
    fn a_constant_image_has_no_bandwidth() {
        let p = Pyramid::new(32, 32, &vec![3.5; 32 * 32]);
        assert_eq!(p.significant_level(), None);
        assert!(p.rate_map().iter().all(|&r| r == 0.0));
    }

    #[test]
    fn a_checkerboard_of_period_two_is_at_the_finest_level() {
        let p = Pyramid::new(16, 16, &image(16, |x, y| ((x + y) % 2) as f64));
        assert_eq!(p.significant_level(), Some(0));
        assert!(p.rate_map().iter().all(|&r| r == 1.0));
    }

    #[test]
    fn stripes_of_period_2_to_the_k_plus_1_give_rate_2_to_the_minus_k() {
        // Square waves of period 2^(k+1) pixels: all their Haar energy is at level k.
        for k in 0..4 {
            let period = 1usize << (k + 1);
            let img = image(64, |x, _| if x % period < period / 2 { 1.0 } else { 0.0 });
            let p = Pyramid::new(64, 64, &img);
            assert_eq!(p.significant_level(), Some(k), "period {period}");
            let rates = p.rate_map();
            assert!(
                rates.iter().all(|&r| r == 0.5f64.powi(k as i32)),
                "period {period}: {:?}",
                &rates[..4]
            );
        }
    }

    #[test]
    fn a_smooth_bump_is_coarser_than_a_narrow_one_and_flat_far_away_is_zero() {
        let bump = |sigma: f64| {
            image(64, move |x, y| {
                let (dx, dy) = (x as f64 - 31.5, y as f64 - 31.5);
                (-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp()
            })
        };
        let wide = Pyramid::new(64, 64, &bump(8.0)).rate_map();
        let narrow = Pyramid::new(64, 64, &bump(1.5)).rate_map();
        let centre = 32 * 64 + 32;
        assert!(
            narrow[centre] > wide[centre],
            "{} {}",
            narrow[centre],
            wide[centre]
        );
        // The narrow bump's corner is flat (below epsilon): no bandwidth there.
        assert_eq!(narrow[0], 0.0);
    }

    #[test]
    fn eq7_ignores_finer_levels_below_epsilon() {
        // Level 0 holds 0.5% of the maximum: negligible; level 1 is the answer.
        assert_eq!(significant_level(&[0.005, 1.0, 0.3]), Some(1));
        // Two finer levels that together reach 1% are not.
        assert_eq!(significant_level(&[0.006, 0.006, 1.0]), Some(1));
        assert_eq!(significant_level(&[0.02, 1.0]), Some(0));
        assert_eq!(significant_level(&[0.0, 0.0]), None);
    }

    #[test]
    fn max_blocks_keeps_the_largest_rate_per_block() {
        let mut r = vec![0.0; 16];
        r[5] = 0.5;
        r[15] = 0.25;
        assert_eq!(max_blocks(&r, 4, 4, 2, 2), vec![0.5, 0.0, 0.0, 0.25]);
    }
}
