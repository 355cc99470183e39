//! Directional albedo rho(wo) = integral of f(wi, wo) cos_i dwi over the hemisphere,
//! estimated by importance sampling with the model's own `sample`. Replayable: sample
//! k uses the random numbers of key (seed, k), summed in a fixed order, so the result
//! does not depend on the thread count.

use glam::DVec3;
use rayon::prelude::*;

use super::AnalyticBrdf;
use crate::rng::SampleStream;

/// A Monte Carlo estimate with its standard error (sample std. dev. / sqrt(N)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlbedoEstimate {
    pub mean: f64,
    pub std_error: f64,
    pub samples: u32,
}

/// Samples per parallel chunk; the chunks' partial sums are added in index order.
const CHUNK: u32 = 1 << 14;

/// Albedo for the fixed direction `wo` (unit, local frame) from `samples` samples.
pub fn directional_albedo(
    brdf: &AnalyticBrdf,
    wo: DVec3,
    samples: u32,
    seed: u64,
) -> AlbedoEstimate {
    let samples = samples.max(1);
    let chunks = samples.div_ceil(CHUNK);
    let partial: Vec<(f64, f64)> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let (mut sum, mut sum2) = (0.0, 0.0);
            for k in c * CHUNK..((c + 1) * CHUNK).min(samples) {
                let u = SampleStream::new(&[seed, u64::from(k)]).next_2d();
                let v = match brdf.sample(wo, u) {
                    Some(s) => brdf.eval(s.wi, wo) * s.wi.z / s.pdf,
                    None => 0.0,
                };
                sum += v;
                sum2 += v * v;
            }
            (sum, sum2)
        })
        .collect();
    let (sum, sum2) = partial
        .iter()
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let n = f64::from(samples);
    let mean = sum / n;
    let var = if samples > 1 {
        ((sum2 - n * mean * mean) / (n - 1.0)).max(0.0)
    } else {
        0.0
    };
    AlbedoEstimate {
        mean,
        std_error: (var / n).sqrt(),
        samples,
    }
}
