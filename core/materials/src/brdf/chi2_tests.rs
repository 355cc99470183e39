//! Chi-square goodness-of-fit tests of every model's `sample` against its `pdf`, in
//! the manner of pbrt-v4 and Mitsuba: histogram many samples over bins of the sphere,
//! integrate the pdf over the same bins, and reject when the chi^2 statistic is
//! improbable. Bins live in a frame around the lobe axis with polar edges crowded
//! near it, so sharp lobes (n = 1e4, roughness 0.02) still spread over many bins.
//! `histogram`, `p_value` and `Binning` are shared with the MERL, environment and
//! SPMM texel samplers' tests.

use std::f64::consts::PI;

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::*;
use crate::rng::SampleStream;

pub const THETA_BINS: usize = 40;
pub const PHI_BINS: usize = 48;
pub const SAMPLES: u64 = 1_000_000;
const MIN_EXPECTED: f64 = 5.0;
/// Overall false-alarm rate of the whole suite (Sidak-corrected per test).
pub const SIGNIFICANCE: f64 = 0.01;

pub struct Binning {
    frame: Frame,
    theta_edges: Vec<f64>,
}

impl Binning {
    /// Polar edges theta_k = pi (k/K)^power around `axis`.
    pub fn new(axis: DVec3, power: f64) -> Self {
        let (x, y) = warp::orthonormal_basis(axis);
        let theta_edges = (0..=THETA_BINS)
            .map(|k| PI * (k as f64 / THETA_BINS as f64).powf(power))
            .collect();
        Self {
            frame: Frame { x, y, z: axis },
            theta_edges,
        }
    }

    pub fn index(&self, w: DVec3) -> usize {
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
    /// cells: a cell is split in four while the split changes its estimate, so bins
    /// that a lobe's edge cuts are refined along the cut. The horizon, where every pdf
    /// drops to 0, is handled exactly (see `gauss_cell`), so a sliver of a bin above the
    /// horizon is integrated as accurately as a whole bin.
    pub fn integrate(&self, pdf: impl Fn(DVec3) -> f64 + Sync) -> Vec<f64> {
        let f = |theta: f64, phi: f64| pdf(self.direction(theta, phi)) * theta.sin();
        (0..THETA_BINS * PHI_BINS)
            .into_par_iter()
            .map(|bin| {
                let (t, p) = (bin / PHI_BINS, bin % PHI_BINS);
                let (t0, t1) = (self.theta_edges[t], self.theta_edges[t + 1]);
                let dp = 2.0 * PI / PHI_BINS as f64;
                let cell = [t0, t1, dp * p as f64, dp * (p + 1) as f64];
                self.adaptive_cell(&f, cell, self.gauss_cell(&f, cell), 0)
            })
            .collect()
    }

    /// World z of the direction (theta, phi) of the binning frame is
    /// A cos(theta) + sin(theta) B(phi), with A = axis.z and B(phi) = cos(phi) x.z +
    /// sin(phi) y.z; returns (A, B(phi), dB/dphi).
    fn horizon_terms(&self, phi: f64) -> (f64, f64, f64) {
        let (s, c) = phi.sin_cos();
        let (xz, yz) = (self.frame.x.z, self.frame.y.z);
        (self.frame.z.z, c * xz + s * yz, c * yz - s * xz)
    }

    /// The parts of [t0, t1] above the horizon at azimuth `phi`: z = R cos(theta - c)
    /// is positive on the open arc |theta - c| < pi/2 (mod 2 pi).
    fn theta_above(&self, t0: f64, t1: f64, phi: f64) -> impl Iterator<Item = (f64, f64)> {
        let (a, b, _) = self.horizon_terms(phi);
        let c = b.atan2(a);
        arc_pieces(t0, t1, c, 0.5 * PI)
    }

    /// The parts of [p0, p1] above the horizon at polar angle `theta`:
    /// z = A cos(theta) + sin(theta) R cos(phi - psi) > 0 where cos(phi - psi) > q.
    fn phi_above(&self, p0: f64, p1: f64, theta: f64) -> impl Iterator<Item = (f64, f64)> {
        let (xz, yz) = (self.frame.x.z, self.frame.y.z);
        let r = (xz * xz + yz * yz).sqrt() * theta.sin();
        let a = self.frame.z.z * theta.cos();
        // a + r cos(phi - psi) > 0: everywhere, nowhere, or on an arc about psi.
        let half_width = if a >= r {
            PI
        } else if a <= -r {
            0.0
        } else {
            (-a / r).acos()
        };
        arc_pieces(p0, p1, yz.atan2(xz), half_width)
    }

    /// 4x4 Gauss-Legendre over a cell, restricted to the upper hemisphere exactly: the
    /// inner integral runs over the clipped range of whichever variable the horizon
    /// cuts more steeply in this cell, so the outer integrand stays continuous.
    fn gauss_cell(&self, f: &impl Fn(f64, f64) -> f64, [t0, t1, p0, p1]: [f64; 4]) -> f64 {
        let (tc, pc) = (0.5 * (t0 + t1), 0.5 * (p0 + p1));
        let (a, b, db) = self.horizon_terms(pc);
        let dz_dtheta = (-a * tc.sin() + b * tc.cos()).abs() * (t1 - t0);
        let dz_dphi = (tc.sin() * db).abs() * (p1 - p0);
        let gauss = |lo: f64, hi: f64, g: &mut dyn FnMut(f64) -> f64| {
            let (mid, half) = (0.5 * (lo + hi), 0.5 * (hi - lo));
            GAUSS_X
                .iter()
                .zip(GAUSS_W)
                .map(|(x, w)| w * g(mid + half * x))
                .sum::<f64>()
                * half
        };
        if dz_dtheta >= dz_dphi {
            gauss(p0, p1, &mut |phi| {
                self.theta_above(t0, t1, phi)
                    .map(|(lo, hi)| gauss(lo, hi, &mut |theta| f(theta, phi)))
                    .sum()
            })
        } else {
            gauss(t0, t1, &mut |theta| {
                self.phi_above(p0, p1, theta)
                    .map(|(lo, hi)| gauss(lo, hi, &mut |phi| f(theta, phi)))
                    .sum()
            })
        }
    }

    fn adaptive_cell(
        &self,
        f: &impl Fn(f64, f64) -> f64,
        cell: [f64; 4],
        whole: f64,
        depth: u32,
    ) -> f64 {
        let [t0, t1, p0, p1] = cell;
        let (tm, pm) = (0.5 * (t0 + t1), 0.5 * (p0 + p1));
        let quads = [
            [t0, tm, p0, pm],
            [t0, tm, pm, p1],
            [tm, t1, p0, pm],
            [tm, t1, pm, p1],
        ];
        let parts = quads.map(|q| self.gauss_cell(f, q));
        let split: f64 = parts.iter().sum();
        if depth >= MAX_DEPTH || (split - whole).abs() <= CELL_TOLERANCE {
            return split;
        }
        quads
            .iter()
            .zip(parts)
            .map(|(q, w)| self.adaptive_cell(f, *q, w, depth + 1))
            .sum()
    }
}

/// The parts of [lo, hi] inside the open arc (centre - half_width, centre + half_width)
/// taken modulo 2 pi (at most two, when the arc's complement lies inside [lo, hi]).
fn arc_pieces(lo: f64, hi: f64, centre: f64, half_width: f64) -> impl Iterator<Item = (f64, f64)> {
    [-2.0 * PI, 0.0, 2.0 * PI, 4.0 * PI]
        .into_iter()
        .filter_map(move |k| {
            let (a, b) = (
                lo.max(centre + k - half_width),
                hi.min(centre + k + half_width),
            );
            (a < b).then_some((a, b))
        })
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

/// Runs one chi^2 test; returns the p-value, or an error naming the failure.
#[cfg(test)]
fn chi2_p_value(
    brdf: &AnalyticBrdf,
    wo: DVec3,
    binning: &Binning,
    seed: u64,
) -> Result<f64, String> {
    let (observed, accepted) = histogram(
        |u| brdf.sample(wo, u).map(|s| s.wi),
        |wi| binning.index(wi),
        THETA_BINS * PHI_BINS,
        seed,
    );
    let expected = binning.integrate(|wi| brdf.pdf(wo, wi));
    // The quadrature's own error: cells converge to 1e-8; the worst total measured is 6e-9.
    p_value(&observed, &expected, accepted, 1e-6)
}

/// Counts of `SAMPLES` draws of `sample` (uniform numbers keyed by `seed` and the
/// sample index) over `bins` bins, and how many draws returned a direction.
pub fn histogram(
    sample: impl Fn(DVec2) -> Option<DVec3>,
    bin_of: impl Fn(DVec3) -> usize,
    bins: usize,
    seed: u64,
) -> (Vec<f64>, u64) {
    let mut observed = vec![0.0f64; bins];
    let mut accepted = 0u64;
    for k in 0..SAMPLES {
        let u = SampleStream::new(&[seed, k]).next_2d();
        if let Some(wi) = sample(u) {
            observed[bin_of(wi)] += 1.0;
            accepted += 1;
        }
    }
    (observed, accepted)
}

/// The chi^2 p-value of `observed` counts (from `histogram`) against `expected_prob`,
/// the pdf's integral over each bin, whose total may differ from the returned share of
/// samples by 5 binomial sigma plus `integration_error`.
pub fn p_value(
    observed: &[f64],
    expected_prob: &[f64],
    accepted: u64,
    integration_error: f64,
) -> Result<f64, String> {
    let expected: Vec<f64> = expected_prob.iter().map(|e| e * SAMPLES as f64).collect();
    // The pdf integrates to the probability that `sample` returns a direction.
    let total_expected: f64 = expected.iter().sum();
    let accept_rate = accepted as f64 / SAMPLES as f64;
    let se = (accept_rate * (1.0 - accept_rate) / SAMPLES as f64).sqrt();
    if (total_expected / SAMPLES as f64 - accept_rate).abs() > 5.0 * se + integration_error {
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

#[cfg(test)]
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
        (case(BlinnPhong, &[("n", 1e5)]), 4.0),
        (case(Ward, &[("ax", 0.5), ("ay", 0.5)]), 2.0),
        (case(Ward, &[("ax", 0.3), ("ay", 0.05)]), 3.0),
        (case(Ward, &[("ax", 0.02), ("ay", 0.02)]), 3.0),
        (case(Ward, &[("ax", 1.0), ("ay", 0.02)]), 3.0),
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
        // Weights far from unit length: the axis is normalised, the exponent is not.
        (
            case(
                Lafortune,
                &[("cx", -300.0), ("cy", 200.0), ("cz", 50.0), ("n", 8.0)],
            ),
            2.0,
        ),
        // cz = 0: at normal view the axis vanishes and the cosine fallback is used;
        // elsewhere the axis is horizontal and half the lobe falls below the horizon.
        (
            case(
                Lafortune,
                &[("cx", -1.0), ("cy", -1.0), ("cz", 0.0), ("n", 5.0)],
            ),
            1.0,
        ),
    ];
    // Normal, oblique, anisotropic azimuth and two grazing views.
    let views = [
        warp::spherical(1.0, 0.0),
        warp::spherical(0.6, 0.9),
        warp::spherical(0.05, 2.5),
        warp::spherical(0.005, 4.0),
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
    // The same `histogram` and `p_value` every sampler test uses, so a harness that
    // cannot fail fails here.
    let (observed, accepted) = histogram(
        |u| sampled.sample(wo, u).map(|s| s.wi),
        |wi| binning.index(wi),
        THETA_BINS * PHI_BINS,
        7,
    );
    let expected = binning.integrate(|wi| claimed.pdf(wo, wi));
    // The wrong pdf integrates to less than the share of samples returned (0.951 vs
    // 0.967): the total check notices that first.
    let total = p_value(&observed, &expected, accepted, 1e-6);
    assert!(total.is_err(), "the wrong total went unnoticed: {total:?}");
    // Scaled to the right total, only its shape is wrong: the chi^2 must notice.
    let sum: f64 = expected.iter().sum();
    let share = accepted as f64 / SAMPLES as f64;
    let reshaped: Vec<f64> = expected.iter().map(|e| e * share / sum).collect();
    let p = p_value(&observed, &reshaped, accepted, 1e-6).expect("the totals agree");
    assert!(p < 1e-6, "a 10% roughness error went unnoticed: p = {p}");
}
