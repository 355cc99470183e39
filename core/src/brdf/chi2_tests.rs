//! Chi-square goodness-of-fit tests of every model's `sample` against its `pdf`, in
//! the manner of pbrt-v4 and Mitsuba: histogram many samples over bins of the sphere,
//! integrate the pdf over the same bins, and reject when the chi^2 statistic is
//! improbable. Bins live in a frame around the lobe axis with polar edges crowded
//! near it, so sharp lobes (n = 1e4, roughness 0.02) still spread over many bins.

use std::f64::consts::PI;

use glam::DVec3;
use rayon::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::*;
use crate::rng::SampleStream;

const THETA_BINS: usize = 40;
const PHI_BINS: usize = 48;
const SAMPLES: u64 = 400_000;
const MIN_EXPECTED: f64 = 5.0;
/// Overall false-alarm rate of the whole suite (Sidak-corrected per test).
const SIGNIFICANCE: f64 = 0.01;

struct Binning {
    frame: Frame,
    theta_edges: Vec<f64>,
}

impl Binning {
    /// Polar edges theta_k = pi (k/K)^power around `axis`.
    fn new(axis: DVec3, power: f64) -> Self {
        let (x, y) = warp::orthonormal_basis(axis);
        let theta_edges = (0..=THETA_BINS)
            .map(|k| PI * (k as f64 / THETA_BINS as f64).powf(power))
            .collect();
        Self {
            frame: Frame { x, y, z: axis },
            theta_edges,
        }
    }

    fn index(&self, w: DVec3) -> usize {
        let l = self.frame.to_local(w);
        let theta = l.z.clamp(-1.0, 1.0).acos();
        let phi = l.y.atan2(l.x).rem_euclid(2.0 * PI);
        let t = self
            .theta_edges
            .partition_point(|&e| e <= theta)
            .clamp(1, THETA_BINS)
            - 1;
        let p = ((phi / (2.0 * PI) * PHI_BINS as f64) as usize).min(PHI_BINS - 1);
        t * PHI_BINS + p
    }

    fn direction(&self, theta: f64, phi: f64) -> DVec3 {
        self.frame.to_world(warp::spherical(theta.cos(), phi))
    }

    /// Integral of `pdf` sin(theta) over every bin, by adaptive 4x4 Gauss-Legendre
    /// cells: a cell is split in four while the split changes its estimate, so bins that
    /// the horizon or a lobe's edge cuts are refined along the cut. Gauss nodes never
    /// sit on a cell edge, where a discontinuity would be counted on the wrong side.
    fn integrate(&self, pdf: impl Fn(DVec3) -> f64 + Sync) -> Vec<f64> {
        let f = |theta: f64, phi: f64| pdf(self.direction(theta, phi)) * theta.sin();
        (0..THETA_BINS * PHI_BINS)
            .into_par_iter()
            .map(|bin| {
                let (t, p) = (bin / PHI_BINS, bin % PHI_BINS);
                let (t0, t1) = (self.theta_edges[t], self.theta_edges[t + 1]);
                let dp = 2.0 * PI / PHI_BINS as f64;
                let (p0, p1) = (dp * p as f64, dp * (p + 1) as f64);
                adaptive_cell(&f, [t0, t1, p0, p1], gauss_cell(&f, [t0, t1, p0, p1]), 0)
            })
            .collect()
    }
}

/// Nodes and weights of 4-point Gauss-Legendre on [-1, 1].
const GAUSS_X: [f64; 4] = [
    -0.861_136_311_594_052_6,
    -0.339_981_043_584_856_3,
    0.339_981_043_584_856_3,
    0.861_136_311_594_052_6,
];
const GAUSS_W: [f64; 4] = [
    0.347_854_845_137_453_9,
    0.652_145_154_862_546_1,
    0.652_145_154_862_546_1,
    0.347_854_845_137_453_9,
];
/// Absolute tolerance per cell, in probability (times SAMPLES: 0.004 expected samples).
const CELL_TOLERANCE: f64 = 1e-8;
const MAX_DEPTH: u32 = 6;

fn gauss_cell(f: &impl Fn(f64, f64) -> f64, [t0, t1, p0, p1]: [f64; 4]) -> f64 {
    let (tc, th, pc, ph) = (
        0.5 * (t0 + t1),
        0.5 * (t1 - t0),
        0.5 * (p0 + p1),
        0.5 * (p1 - p0),
    );
    let mut sum = 0.0;
    for (xi, wi) in GAUSS_X.iter().zip(GAUSS_W) {
        for (xj, wj) in GAUSS_X.iter().zip(GAUSS_W) {
            sum += wi * wj * f(tc + th * xi, pc + ph * xj);
        }
    }
    sum * th * ph
}

fn adaptive_cell(f: &impl Fn(f64, f64) -> f64, cell: [f64; 4], whole: f64, depth: u32) -> f64 {
    let [t0, t1, p0, p1] = cell;
    let (tm, pm) = (0.5 * (t0 + t1), 0.5 * (p0 + p1));
    let quads = [
        [t0, tm, p0, pm],
        [t0, tm, pm, p1],
        [tm, t1, p0, pm],
        [tm, t1, pm, p1],
    ];
    let parts = quads.map(|q| gauss_cell(f, q));
    let split: f64 = parts.iter().sum();
    if depth >= MAX_DEPTH || (split - whole).abs() <= CELL_TOLERANCE {
        return split;
    }
    quads
        .iter()
        .zip(parts)
        .map(|(q, w)| adaptive_cell(f, *q, w, depth + 1))
        .sum()
}

/// Runs one chi^2 test; returns the p-value, or an error naming the failure.
fn chi2_p_value(
    brdf: &AnalyticBrdf,
    wo: DVec3,
    binning: &Binning,
    seed: u64,
) -> Result<f64, String> {
    let mut observed = vec![0.0f64; THETA_BINS * PHI_BINS];
    let mut accepted = 0u64;
    for k in 0..SAMPLES {
        let u = SampleStream::new(&[seed, k]).next_2d();
        if let Some(s) = brdf.sample(wo, u) {
            observed[binning.index(s.wi)] += 1.0;
            accepted += 1;
        }
    }
    let expected: Vec<f64> = binning
        .integrate(|wi| brdf.pdf(wo, wi))
        .into_iter()
        .map(|e| e * SAMPLES as f64)
        .collect();
    // The pdf integrates to the probability that `sample` returns a direction.
    let total_expected: f64 = expected.iter().sum();
    let accept_rate = accepted as f64 / SAMPLES as f64;
    let se = (accept_rate * (1.0 - accept_rate) / SAMPLES as f64).sqrt();
    if (total_expected / SAMPLES as f64 - accept_rate).abs() > 5.0 * se + 2e-3 {
        return Err(format!(
            "pdf integrates to {} but {} of samples were returned",
            total_expected / SAMPLES as f64,
            accept_rate
        ));
    }
    let (mut chi2, mut dof) = (0.0, 0usize);
    let (mut pooled_obs, mut pooled_exp) = (0.0, 0.0);
    for (o, e) in observed.iter().zip(&expected) {
        // A bin whose expected count is 0 but holds a sample is a sliver above the
        // horizon that the quadrature missed: `sample` only returns directions where
        // `pdf` > 0, so such bins join the pooled low-expectation bin.
        if *e < MIN_EXPECTED {
            pooled_obs += o;
            pooled_exp += e;
        } else {
            chi2 += (o - e) * (o - e) / e;
            dof += 1;
        }
    }
    if pooled_exp >= MIN_EXPECTED {
        chi2 += (pooled_obs - pooled_exp) * (pooled_obs - pooled_exp) / pooled_exp;
        dof += 1;
    }
    if dof < 2 {
        return Err(format!("only {dof} usable bins"));
    }
    let dist = ChiSquared::new((dof - 1) as f64).map_err(|e| e.to_string())?;
    Ok(1.0 - dist.cdf(chi2))
}

fn case(model: BrdfModel, params: &[(&str, f64)]) -> AnalyticBrdf {
    AnalyticBrdf::new(model, params).expect("test parameters lie in range")
}

#[test]
fn every_sampler_matches_its_pdf() {
    use BrdfModel::*;
    let cases: Vec<(AnalyticBrdf, f64)> = vec![
        (case(Lambertian, &[]), 1.0),
        (case(OrenNayar, &[("sigma", 1.0)]), 1.0),
        (case(BlinnPhong, &[("n", 0.0)]), 1.0),
        (case(BlinnPhong, &[("n", 20.0)]), 2.0),
        (case(BlinnPhong, &[("n", 1e3)]), 3.0),
        (case(BlinnPhong, &[("n", 1e4)]), 3.0),
        (case(Ward, &[("ax", 0.5), ("ay", 0.5)]), 2.0),
        (case(Ward, &[("ax", 0.3), ("ay", 0.05)]), 3.0),
        (case(Ward, &[("ax", 0.02), ("ay", 0.02)]), 3.0),
        (case(CookTorrance, &[("m", 0.8), ("f0", 0.5)]), 2.0),
        (case(CookTorrance, &[("m", 0.2), ("f0", 0.04)]), 2.0),
        (case(CookTorrance, &[("m", 0.02), ("f0", 0.9)]), 3.0),
        (
            case(AshikhminShirley, &[("nu", 10.0), ("nv", 10.0), ("rs", 0.5)]),
            2.0,
        ),
        (
            case(AshikhminShirley, &[("nu", 1e3), ("nv", 10.0), ("rs", 0.5)]),
            3.0,
        ),
        (
            case(AshikhminShirley, &[("nu", 1.0), ("nv", 1e4), ("rs", 0.5)]),
            3.0,
        ),
        (
            case(
                Lafortune,
                &[("cx", -1.0), ("cy", -1.0), ("cz", 1.0), ("n", 0.0)],
            ),
            1.0,
        ),
        (
            case(
                Lafortune,
                &[("cx", -1.0), ("cy", -0.5), ("cz", 0.8), ("n", 30.0)],
            ),
            2.0,
        ),
        (
            case(
                Lafortune,
                &[("cx", 0.0), ("cy", 0.0), ("cz", 1.0), ("n", 1e3)],
            ),
            3.0,
        ),
    ];
    // Normal, oblique, anisotropic azimuth and grazing views.
    let views = [
        warp::spherical(1.0, 0.0),
        warp::spherical(0.6, 0.9),
        warp::spherical(0.05, 2.5),
    ];
    let tests = cases.len() * views.len();
    let threshold = 1.0 - (1.0 - SIGNIFICANCE).powf(1.0 / tests as f64);
    let failures: Vec<String> = cases
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, (brdf, power))| {
            views.iter().enumerate().filter_map(move |(v, &wo)| {
                let axis = match brdf {
                    AnalyticBrdf::Lambertian(_) | AnalyticBrdf::OrenNayar(_) => DVec3::Z,
                    AnalyticBrdf::Lafortune(l) => (DVec3::new(l.cx(), l.cy(), l.cz()) * wo)
                        .try_normalize()
                        .unwrap_or(DVec3::Z),
                    _ => DVec3::new(-wo.x, -wo.y, wo.z),
                };
                let binning = Binning::new(axis, *power);
                match chi2_p_value(brdf, wo, &binning, 1000 + (i * 10 + v) as u64) {
                    Ok(p) if p >= threshold => None,
                    Ok(p) => Some(format!(
                        "{brdf:?} wo {wo}: p-value {p:.3e} < {threshold:.3e}"
                    )),
                    Err(e) => Some(format!("{brdf:?} wo {wo}: {e}")),
                }
            })
        })
        .collect();
    assert!(
        failures.is_empty(),
        "chi-square failures:\n{}",
        failures.join("\n")
    );
}

#[test]
fn chi2_test_detects_a_wrong_pdf() {
    // The harness itself must be able to fail: Beckmann sampling with m = 0.3 judged
    // against the pdf of m = 0.33 is a 10% error in roughness.
    let sampled = case(BrdfModel::CookTorrance, &[("m", 0.3), ("f0", 0.5)]);
    let claimed = case(BrdfModel::CookTorrance, &[("m", 0.33), ("f0", 0.5)]);
    let wo = warp::spherical(0.7, 0.3);
    let binning = Binning::new(DVec3::new(-wo.x, -wo.y, wo.z), 2.0);
    let mut observed = vec![0.0f64; THETA_BINS * PHI_BINS];
    for k in 0..SAMPLES {
        if let Some(s) = sampled.sample(wo, SampleStream::new(&[7, k]).next_2d()) {
            observed[binning.index(s.wi)] += 1.0;
        }
    }
    let expected = binning.integrate(|wi| claimed.pdf(wo, wi));
    let chi2: f64 = expected
        .iter()
        .map(|e| e * SAMPLES as f64)
        .zip(&observed)
        .filter(|(e, _)| *e >= MIN_EXPECTED)
        .map(|(e, o)| (o - e) * (o - e) / e)
        .sum();
    let dof = expected
        .iter()
        .filter(|e| **e * SAMPLES as f64 >= MIN_EXPECTED)
        .count();
    let p = 1.0
        - ChiSquared::new((dof - 1) as f64)
            .expect("dof > 1")
            .cdf(chi2);
    assert!(p < 1e-6, "a 10% roughness error went unnoticed: p = {p}");
}
