//! Many-light selection for the spmm mode: an alias table (Walker 1977, Vose 1991) over
//! the lights' power, from which each shading point draws `CANDIDATES` lights (a point
//! on an area light with them) and keeps one by resampled importance sampling (Talbot et
//! al. 2005) towards their unshadowed contribution. No light tree: selection is O(1) per
//! candidate, but blind to distance until the candidates are weighed.

use std::f64::consts::PI;

use glam::DVec3;

use meso_materials::rng::SampleStream;

use crate::geometry::SceneBvh;
use crate::layers::{LightTarget, MANY_LIGHTS, light_power};
use crate::scene::Light;
use crate::shading::{ShadedMaterial, Shading};

/// Light selections (shadow rays) per shading point on the stochastic path, times the
/// scene's `light_samples`.
pub const LIGHT_SAMPLES: usize = 1;
/// Candidates drawn from the alias table for each light sample.
pub const CANDIDATES: usize = 8;
/// A light's selection power never falls below this fraction of the mean power, so
/// every light with a layer of its own keeps a positive pdf even at zero emission (its
/// layer may be re-weighted later) and the estimator stays unbiased for it.
const POWER_FLOOR: f64 = 1e-3;

/// How the spmm mode samples lights.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightSampling {
    /// One shadow ray to every light up to `MANY_LIGHTS` lights, stochastic above.
    #[default]
    Auto,
    /// One shadow ray to every light whatever their number (the reference).
    Exact,
    /// Stochastic selection whatever the number of lights.
    Stochastic,
}

impl LightSampling {
    /// True if `lights` lights are sampled stochastically.
    pub fn stochastic(self, lights: usize) -> bool {
        match self {
            LightSampling::Auto => lights > MANY_LIGHTS,
            LightSampling::Exact => false,
            LightSampling::Stochastic => lights > 0,
        }
    }
}

/// Walker's alias table: draws index `i` with probability `weight[i] / sum` in O(1).
#[derive(Clone, Debug, Default)]
pub struct AliasTable {
    /// Per bin: the probability of keeping the bin, and its alias.
    bins: Vec<(f64, u32)>,
    pmf: Vec<f64>,
}

impl AliasTable {
    /// Weights must be finite and non-negative with a positive sum.
    pub fn new(weights: &[f64]) -> Self {
        let n = weights.len();
        let total: f64 = weights.iter().sum();
        assert!(total > 0.0 && total.is_finite(), "positive finite weights");
        let pmf: Vec<f64> = weights.iter().map(|w| w / total).collect();
        let mut scaled: Vec<f64> = pmf.iter().map(|p| p * n as f64).collect();
        let mut bins = vec![(1.0, 0u32); n];
        let (mut small, mut large): (Vec<usize>, Vec<usize>) =
            (0..n).partition(|&i| scaled[i] < 1.0);
        while let (Some(s), Some(&l)) = (small.pop(), large.last()) {
            bins[s] = (scaled[s], l as u32);
            scaled[l] -= 1.0 - scaled[s];
            if scaled[l] < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        // What is left is 1 up to rounding.
        for i in small.into_iter().chain(large) {
            bins[i] = (1.0, i as u32);
        }
        Self { bins, pmf }
    }

    /// The index for a uniform `u` in [0, 1), and its probability.
    #[inline]
    pub fn sample(&self, u: f64) -> (usize, f64) {
        let n = self.bins.len();
        let x = u * n as f64;
        let i = (x as usize).min(n - 1);
        let (keep, alias) = self.bins[i];
        let k = if x - (i as f64) < keep {
            i
        } else {
            alias as usize
        };
        (k, self.pmf[k])
    }

    /// The probability of each index.
    pub fn pmf(&self) -> &[f64] {
        &self.pmf
    }

    /// Per bin: the probability of keeping the bin, and its alias (a device that
    /// draws from the same table uploads them).
    pub fn bins(&self) -> &[(f64, u32)] {
        &self.bins
    }
}

/// What the stochastic path reads per light, rebuilt after every light edit.
#[derive(Clone, Debug, Default)]
pub struct LightSelection {
    pub table: AliasTable,
    pub lights: Vec<PackedLight>,
}

/// A light as a candidate needs it: a point `origin + edge_u x + edge_v y`, and what
/// turns its falloff into the resampling weight `target / p_src`.
#[derive(Clone, Copy, Debug, Default)]
pub struct PackedLight {
    pub origin: DVec3,
    pub edge_u: DVec3,
    pub edge_v: DVec3,
    /// The unit normal an area light emits along; zero for a point light.
    pub normal: DVec3,
    /// `1 / area` (1 for a point light): the source pdf per unit area is
    /// `pmf x inv_area`.
    pub inv_area: f64,
    /// `target / p_src = w_scale x cos_l / r^2`: the target is the floored emission
    /// (selection weight / (4 pi), or / (pi A)) times the falloff, so the resampling
    /// weight is the table's total weight over 4 pi (point) or pi (area) times the
    /// geometry, whatever the light's emission.
    pub w_scale: f64,
}

impl LightSelection {
    /// `None` for a scene without lights.
    pub fn new(lights: &[Light]) -> Option<Self> {
        if lights.is_empty() {
            return None;
        }
        // Capped so the sum of many huge (finite) emissions stays finite.
        let cap = f64::MAX / (2.0 * lights.len() as f64);
        let power: Vec<f64> = lights.iter().map(|l| light_power(l).min(cap)).collect();
        let mean = power.iter().sum::<f64>() / power.len() as f64;
        let floor = if mean > 0.0 { POWER_FLOOR * mean } else { 1.0 };
        let weights: Vec<f64> = power.iter().map(|p| p + floor).collect();
        let total: f64 = weights.iter().sum();
        let packed = lights
            .iter()
            .map(|l| match *l {
                Light::Point { position, .. } => PackedLight {
                    origin: position,
                    inv_area: 1.0,
                    w_scale: total / (4.0 * PI),
                    ..Default::default()
                },
                Light::Area {
                    corner,
                    edge_u,
                    edge_v,
                    ..
                } => {
                    let cross = edge_u.cross(edge_v);
                    let area = cross.length();
                    PackedLight {
                        origin: corner,
                        edge_u,
                        edge_v,
                        normal: cross / area,
                        inv_area: 1.0 / area,
                        w_scale: total / PI,
                    }
                }
            })
            .collect();
        Some(Self {
            table: AliasTable::new(&weights),
            lights: packed,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::rng::SampleStream;

    #[test]
    fn huge_finite_emissions_still_give_a_valid_table() {
        // Each point light's power (4 pi x 1e308) overflows f64; the sum of thirty of
        // them would be infinite without the cap.
        let lights: Vec<Light> = (0..30)
            .map(|i| Light::Point {
                position: glam::DVec3::new(i as f64, 1.0, 0.0),
                intensity: glam::DVec3::splat(if i % 2 == 0 { 1e308 } else { 1.0 }),
            })
            .collect();
        let sel = LightSelection::new(&lights).expect("lights");
        let sum: f64 = sel.table.pmf().iter().sum();
        assert!((sum - 1.0).abs() < 1e-9, "{sum}");
        assert!(sel.table.pmf().iter().all(|p| p.is_finite() && *p > 0.0));
        assert!(sel.lights.iter().all(|l| l.w_scale.is_finite()));
    }

    #[test]
    fn the_selection_pmf_sums_to_one_and_matches_the_draws() {
        let weights: Vec<f64> = (0..1000).map(|i| ((i * 37) % 101) as f64 + 0.5).collect();
        let t = AliasTable::new(&weights);
        let sum: f64 = t.pmf().iter().sum();
        assert!((sum - 1.0).abs() < 1e-12, "{sum}");
        // The table's own probabilities: each bin's keep mass plus the alias mass it
        // receives equals the pmf.
        let n = weights.len() as f64;
        let mut mass = vec![0.0; weights.len()];
        for (i, &(keep, alias)) in t.bins.iter().enumerate() {
            mass[i] += keep / n;
            mass[alias as usize] += (1.0 - keep) / n;
        }
        for (m, p) in mass.iter().zip(t.pmf()) {
            assert!((m - p).abs() < 1e-12, "{m} vs {p}");
        }
        // Draws: chi-square over 10 groups of 100 indices.
        let draws = 200_000;
        let mut hist = [0.0; 10];
        let rng = SampleStream::new(&[5]);
        for d in 0..draws {
            let (k, p) = t.sample(rng.at(d));
            assert_eq!(p, t.pmf()[k]);
            hist[k / 100] += 1.0;
        }
        let chi2: f64 = (0..10)
            .map(|g| {
                let e = t.pmf()[g * 100..(g + 1) * 100].iter().sum::<f64>() * draws as f64;
                (hist[g] - e).powi(2) / e
            })
            .sum();
        // 9 degrees of freedom: 27.9 is the 0.999 quantile.
        assert!(chi2 < 27.9, "chi2 {chi2}");
    }

    #[test]
    fn every_light_keeps_a_positive_probability() {
        let lights: Vec<Light> = (0..20)
            .map(|i| Light::Point {
                position: DVec3::ZERO,
                intensity: DVec3::splat(if i == 3 { 0.0 } else { i as f64 }),
            })
            .collect();
        let s = LightSelection::new(&lights).expect("lights");
        assert!(s.table.pmf().iter().all(|&p| p > 0.0));
        assert!(s.lights.iter().all(|l| l.w_scale > 0.0 && l.inv_area > 0.0));
        let sum: f64 = s.table.pmf().iter().sum();
        assert!((sum - 1.0).abs() < 1e-12);
    }
}

/// A shading point as the many-light estimate reads it: where, towards the eye, the
/// shadow rays' origin just off the surface, the material and the path's throughput.
pub struct ShadingPoint<'a> {
    pub s: &'a Shading,
    pub wo: DVec3,
    pub lift: DVec3,
    pub material: &'a ShadedMaterial<'a>,
    pub throughput: DVec3,
}

/// A candidate of `add_chosen_lights`: a point on a light, unshadowed.
#[derive(Clone, Copy, Default)]
struct Candidate {
    light: usize,
    q: DVec3,
    to: DVec3,
    d2: f64,
    falloff: f64,
    pmf: f64,
    w: f64,
}

impl LightSelection {
    /// `LIGHT_SAMPLES x light_samples` lights, each kept from `CANDIDATES` drawn by
    /// power by resampled importance sampling (Talbot et al. 2005) towards the
    /// unshadowed `emission x falloff` (zero behind a one-sided area light or below the
    /// surface, where the contribution is zero too, so the estimate stays unbiased):
    /// `f(y) / target(y) x mean_j(target_j / p_j)` with one shadow ray to `y`, added to
    /// the light's layer of `out` (`targets`). Draws `LIGHT_SAMPLES x (CANDIDATES + 1)`
    /// dimensions per light sample whatever it finds (a candidate's light and point
    /// from one: 32, 16 and 16 bits). The spmm and the biscale modes' estimate above
    /// `MANY_LIGHTS` lights.
    #[allow(clippy::too_many_arguments)]
    pub fn add_chosen_lights(
        &self,
        at: &ShadingPoint,
        light_samples: u32,
        bvh: &SceneBvh,
        targets: &[LightTarget],
        rng: &mut SampleStream,
        shadow_rays: &mut u64,
        out: &mut [DVec3],
    ) {
        let ShadingPoint {
            s,
            wo,
            lift,
            material,
            throughput,
        } = *at;
        // `light_samples` times the selections, each weighted by its share.
        let selections = LIGHT_SAMPLES * light_samples as usize;
        for _ in 0..selections {
            let mut candidates = [Candidate::default(); CANDIDATES];
            let mut total = 0.0;
            for c in &mut candidates {
                let [u_light, u_x, u_y] = rng.next_32_16_16();
                let (k, pmf) = self.table.sample(u_light);
                let l = &self.lights[k];
                let q = l.origin + l.edge_u * u_x + l.edge_v * u_y;
                let to = q - s.p;
                let d2 = to.length_squared();
                // Zero below the surface and behind a one-sided area light, where the
                // contribution is zero too.
                let cos_l = if l.normal == DVec3::ZERO {
                    1.0
                } else {
                    -to.dot(l.normal) / d2.sqrt()
                };
                let falloff = if to.dot(s.n) > 0.0 && cos_l > 0.0 {
                    cos_l / d2
                } else {
                    0.0
                };
                let w = l.w_scale * falloff;
                if w.is_finite() {
                    total += w;
                }
                *c = Candidate {
                    light: k,
                    q,
                    to,
                    d2,
                    falloff,
                    pmf,
                    w,
                };
            }
            let pick = rng.next() * total;
            if !(total > 0.0 && total.is_finite()) {
                continue;
            }
            let mut acc = 0.0;
            let mut chosen = None;
            for c in &candidates {
                if !(c.w > 0.0 && c.w.is_finite()) {
                    continue;
                }
                acc += c.w;
                chosen = Some(*c);
                if pick < acc {
                    break;
                }
            }
            let Some(c) = chosen else {
                continue;
            };
            // target(y) = w(y) p_src(y), p_src per light or per unit area; the estimate
            // is f(y) / target(y) x total / M.
            let target = c.w * c.pmf * self.lights[c.light].inv_area;
            let wi = c.to / c.d2.sqrt();
            *shadow_rays += 1;
            if bvh.occluded(lift, wi, 0.0, (c.q - lift).length() * (1.0 - 1e-6)) {
                continue;
            }
            let t = targets[c.light];
            let weight = total / (CANDIDATES as f64 * target * selections as f64);
            out[t.layer] +=
                throughput * material.response(s, wi, wo) * (c.falloff * weight) * t.factor;
        }
    }
}
