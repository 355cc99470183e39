//! How the adaptive mode spreads its samples (Bagher et al. 2013, section 2.4, made to
//! pay under importance sampling):
//! - the per-sample variance of the estimator the frames run, estimated from the
//!   bandwidth pass's n_b directions drawn with the estimator's own pdfs
//!   (sigma^2 = E[(chi cos / p)^2] - E[chi cos / p]^2, eq. 9's sigma_p^2 with the
//!   importance-sampling pdf in place of the uniform bound), plus the variance the
//!   pixel footprint adds where the image changes within a pixel (edges);
//! - samples per pixel in proportion to the predicted standard deviation (Neyman
//!   allocation): for a fixed total it minimises the summed variance of the pixels,
//!   which is what PSNR measures. Eq. 9's own rule, N_p in proportion to the variance,
//!   equalises the pixels' variances and is never better than uniform sampling for
//!   the image's mean squared error (`gain` shows it);
//! - fractional rates per frame by per-pixel dithering, so a quiet pixel gets a sample
//!   every few frames instead of one every frame, and every pixel keeps a floor rate
//!   (the image converges everywhere).

/// Running sums of one pixel's sampled values.
#[derive(Clone, Copy, Debug, Default)]
pub struct Moments {
    sum: f64,
    sum2: f64,
    n: u32,
}

impl Moments {
    pub fn add(&mut self, v: f64) {
        self.sum += v;
        self.sum2 += v * v;
        self.n += 1;
    }

    /// Adds a zero: a draw that contributed nothing (a direction below the horizon).
    pub fn add_zero(&mut self) {
        self.n += 1;
    }

    pub fn mean(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.sum / f64::from(self.n)
        }
    }

    pub fn count(&self) -> u32 {
        self.n
    }

    /// Adds another set of draws' sums (a frame's, to a pixel's).
    pub fn merge(&mut self, other: &Moments) {
        self.sum += other.sum;
        self.sum2 += other.sum2;
        self.n += other.n;
    }

    /// The unbiased sample variance (0 below two draws).
    pub fn variance(&self) -> f64 {
        if self.n < 2 {
            return 0.0;
        }
        let n = f64::from(self.n);
        ((self.sum2 - self.sum * self.sum / n) / (n - 1.0)).max(0.0)
    }
}

/// How many of a pixel's own samples the bandwidth pass's prediction counts as: its
/// n_b = 16 strata.
pub const PREDICTION_WEIGHT: f64 = 16.0;

/// A pixel's standard deviation per sample from the pass's prediction and the variance
/// its own samples show, pooled with the prediction counted as `PREDICTION_WEIGHT`
/// samples: the prediction leads while a pixel has few samples, its measurement once
/// it has many (the prediction misses what the pass does not model, e.g. shadows, and
/// a lobe that 16 directions barely sample). A single sample measures its squared
/// distance from the pass's mean (`predicted_mean`) on one degree of freedom: a first
/// sample far from what the pass expects (a highlight's rare hit) draws samples in the
/// next frame instead of standing alone until the dithering gives the pixel another.
pub fn corrected_sigma(predicted: f64, predicted_mean: f64, own: &Moments) -> f64 {
    let (dof, variance) = match own.n {
        0 => return predicted,
        1 => (1.0, (own.mean() - predicted_mean).powi(2)),
        n => (f64::from(n - 1), own.variance()),
    };
    ((PREDICTION_WEIGHT * predicted * predicted + dof * variance) / (PREDICTION_WEIGHT + dof))
        .sqrt()
}

/// The variance a pixel's footprint adds (the camera ray's jitter over a pixel whose
/// radiance changes inside it): a linear change of g per pixel along an axis has
/// variance g^2 / 12 over the pixel; g is the larger one-sided difference to a
/// neighbour, so a step at an edge counts on both sides.
pub fn footprint_variance(mean: &[f64], w: u32, h: u32) -> Vec<f64> {
    let at = |x: u32, y: u32| mean[(y * w + x) as usize];
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let v = at(x, y);
            let step = |a: Option<f64>, b: Option<f64>| {
                a.map_or(0.0, |a| (a - v).abs())
                    .max(b.map_or(0.0, |b| (b - v).abs()))
            };
            let gx = step(
                (x > 0).then(|| at(x - 1, y)),
                (x + 1 < w).then(|| at(x + 1, y)),
            );
            let gy = step(
                (y > 0).then(|| at(x, y - 1)),
                (y + 1 < h).then(|| at(x, y + 1)),
            );
            (gx * gx + gy * gy) / 12.0
        })
        .collect()
}

/// Samples a pixel takes in frame `frame` at `rate` samples per frame (any positive
/// real): floor((frame + 1) rate + phase) - floor(frame rate + phase), so over F frames
/// it takes F rate samples within one, and a rate below one spreads its samples over
/// frames. `phase` in [0, 1) staggers pixels of equal rate.
pub fn dithered(rate: f64, frame: u32, phase: f64) -> u32 {
    let f = f64::from(frame);
    let n = ((f + 1.0) * rate + phase).floor() - (f * rate + phase).floor();
    n.max(0.0) as u32
}

/// A pixel's fixed phase for `dithered` (the golden-ratio sequence: neighbours differ).
pub fn phase(pixel: usize) -> f64 {
    (pixel as f64 * 0.618_033_988_749_894_9).fract()
}

/// The factor by which the summed variance of an image falls when a fixed total of
/// samples is spread in proportion to `weight` rather than uniformly, for pixels of
/// per-sample variance `variance` (each pixel's weight raised to `floor` times the mean
/// weight first, as the mode does): n sum(s^2) / (sum(N) sum(s^2 / N)). Weights equal
/// to the standard deviations give the largest factor; weights equal to the variances
/// give exactly 1.
pub fn gain(variance: &[f64], weight: &[f64], floor: f64) -> f64 {
    let mean = weight.iter().sum::<f64>() / weight.len().max(1) as f64;
    let n: Vec<f64> = weight
        .iter()
        .map(|w| w.max(floor * mean).max(f64::MIN_POSITIVE))
        .collect();
    let total_var: f64 = variance.iter().sum();
    let spent: f64 = n.iter().sum();
    let with: f64 = variance.iter().zip(&n).map(|(v, n)| v / n).sum();
    if with > 0.0 {
        variance.len() as f64 * total_var / (spent * with)
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moments_give_the_unbiased_variance() {
        let mut m = Moments::default();
        for v in [1.0, 2.0, 3.0, 6.0] {
            m.add(v);
        }
        // Mean 3, squared deviations 4 + 1 + 0 + 9 = 14, over n - 1 = 3.
        assert!((m.mean() - 3.0).abs() < 1e-12);
        assert!((m.variance() - 14.0 / 3.0).abs() < 1e-12);
        m.add_zero();
        // Five values 1, 2, 3, 6, 0: mean 2.4, squared deviations 1.96 + 0.16 + 0.36
        // + 12.96 + 5.76 = 21.2, over 4.
        assert!((m.variance() - 5.3).abs() < 1e-12, "{}", m.variance());
    }

    #[test]
    fn merged_moments_equal_the_moments_of_all_draws() {
        let (mut a, mut b, mut all) = (Moments::default(), Moments::default(), Moments::default());
        for (i, v) in [0.5, 4.0, 1.5, 2.0, 9.0].into_iter().enumerate() {
            if i < 2 {
                a.add(v)
            } else {
                b.add(v)
            }
            all.add(v);
        }
        a.merge(&b);
        assert!((a.mean() - all.mean()).abs() < 1e-12);
        assert!((a.variance() - all.variance()).abs() < 1e-12);
    }

    #[test]
    fn the_corrected_deviation_pools_the_prediction_with_the_measured_variance() {
        let predicted = 0.5;
        // No sample: the prediction alone. One sample: its squared distance from the
        // predicted mean 1 on one degree of freedom, (16 * 0.25 + 1 * 4) / 17.
        let mut m = Moments::default();
        assert_eq!(corrected_sigma(predicted, 1.0, &m), predicted);
        m.add(3.0);
        let s = corrected_sigma(predicted, 1.0, &m);
        assert!((s * s - 8.0 / 17.0).abs() < 1e-12, "{s}");
        // A first sample where the pass expects it keeps the deviation below the
        // prediction's: (16 * 0.25 + 0) / 17.
        let s = corrected_sigma(predicted, 3.0, &m);
        assert!((s * s - 4.0 / 17.0).abs() < 1e-12, "{s}");
        // Draws 3, 1, 5, 7: variance 20 / 3 on 3 degrees of freedom, pooled with the
        // prediction's 0.25 on 16: (16 * 0.25 + 3 * 20 / 3) / 19 = 24 / 19.
        for v in [1.0, 5.0, 7.0] {
            m.add(v);
        }
        let s = corrected_sigma(predicted, 1.0, &m);
        assert!((s * s - 24.0 / 19.0).abs() < 1e-12, "{s}");
        // Many draws: the measurement leads. 4000 alternating 0 and 2 have variance
        // about 1; the pooled deviation is within 0.2% of 1.
        let mut many = Moments::default();
        for k in 0..4000 {
            many.add(if k % 2 == 0 { 0.0 } else { 2.0 });
        }
        let s = corrected_sigma(predicted, 1.0, &many);
        assert!((s - 1.0).abs() < 2e-3, "{s}");
        // A predicted zero does not keep a pixel whose draws vary at zero.
        assert!(corrected_sigma(0.0, 1.0, &many) > 0.99);
    }

    #[test]
    fn a_ramp_has_its_slope_and_a_step_counts_on_both_sides() {
        // A horizontal ramp of slope 2 on a 4 x 2 image: g_x = 2, g_y = 0.
        let ramp = [0.0, 2.0, 4.0, 6.0, 0.0, 2.0, 4.0, 6.0];
        for v in footprint_variance(&ramp, 4, 2) {
            assert!((v - 4.0 / 12.0).abs() < 1e-12, "{v}");
        }
        // A step of 6 between columns 1 and 2: both columns see 36 / 12, the outer
        // ones nothing.
        let step = [0.0, 0.0, 6.0, 6.0];
        assert_eq!(footprint_variance(&step, 4, 1), vec![0.0, 3.0, 3.0, 0.0]);
    }

    #[test]
    fn dithering_takes_the_rate_over_frames_to_within_one() {
        for (rate, phase) in [(0.25, 0.0), (0.3, 0.7), (2.5, 0.1), (4.0, 0.5)] {
            let mut total = 0u32;
            for f in 0..40 {
                total += dithered(rate, f, phase);
                let expected = f64::from(f + 1) * rate;
                assert!(
                    (f64::from(total) - expected).abs() <= 1.0,
                    "rate {rate}, frame {f}: {total}"
                );
            }
        }
        // A quarter sample per frame: one sample every four frames.
        let n: Vec<u32> = (0..8).map(|f| dithered(0.25, f, 0.0)).collect();
        assert_eq!(n, [0, 0, 0, 1, 0, 0, 0, 1]);
    }

    #[test]
    fn neyman_allocation_beats_uniform_and_variance_proportional_does_not() {
        // Two pixels of variance 1 and 100 (standard deviations 1 and 10). Uniform:
        // 101 / 1 each per unit budget. N ~ sigma: shares 2/11 and 20/11 of 2 samples,
        // sum s^2 / N = 1 / (2/11) + 100 / (20/11) = 5.5 + 55 = 60.5; gain = 2 * 101 /
        // (2 * 60.5) = 101 / 60.5.
        let var = [1.0, 100.0];
        let g = gain(&var, &[1.0, 10.0], 0.0);
        assert!((g - 101.0 / 60.5).abs() < 1e-12, "{g}");
        // N ~ variance equalises the pixels' variances: no gain at all.
        assert!((gain(&var, &var, 0.0) - 1.0).abs() < 1e-12);
        // Uniform weights: 1.
        assert!((gain(&var, &[3.0, 3.0], 0.0) - 1.0).abs() < 1e-12);
        // A weight of zero for a noisy pixel is caught by the floor instead of
        // sending the image's variance to infinity.
        assert!(gain(&var, &[1.0, 0.0], 0.25) > 0.0);
    }
}
