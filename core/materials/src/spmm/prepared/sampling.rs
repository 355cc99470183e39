//! Importance sampling of a texel's BTF for light gathered over the hemisphere
//! (ambient occlusion, environment maps, material samples in MIS): a mixture of the
//! texel's own basis functions, each drawn by its analytic BRDF's sampler in its
//! basis frame and chosen in proportion to its weight times its albedo, plus a small
//! defensive share of the half-cosine half-uniform mixture. The defensive share
//! bounds BTF / pdf where the bases say little: the PCA residual, grazing light
//! under tilted basis normals. Lambertian bases are then sampled in proportion to
//! their cosine about their own normals, so an unoccluded ambient term on a pack of
//! tilted Lambertian lobes carries almost no noise (docs/rendering.md).

use std::f64::consts::PI;

use glam::{DVec2, DVec3};

use super::PreparedSpmm;
use crate::brdf::{AnalyticBrdf, warp};

/// The share of directions drawn from the defensive mixture.
pub const DEFENSIVE_SHARE: f64 = 0.1;

/// A direction of the defensive mixture (half cosine-distributed, half uniform over
/// the upper hemisphere of the texel's frame), from two uniform numbers.
pub fn defensive_sample(u: DVec2) -> DVec3 {
    if u.x < 0.5 {
        warp::cosine_hemisphere(DVec2::new(2.0 * u.x, u.y))
    } else {
        // Uniform: cos theta = uniform in [0, 1).
        let z = 1.0 - u.y;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f64::consts::TAU * (2.0 * u.x - 1.0);
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

/// The defensive mixture's solid-angle pdf; at least 1 / 4 pi over the hemisphere.
pub fn defensive_pdf(w: DVec3) -> f64 {
    if w.z > 0.0 {
        0.5 * w.z / PI + 0.25 / PI
    } else {
        0.0
    }
}

/// The albedo of `brdf` at normal view: the mean of f cos / pdf over a fixed 8 x 8
/// stratified set of its own samples (a deterministic estimate; it only sets how
/// often a basis is chosen, so its error costs variance, never bias).
pub(super) fn selection_albedo(brdf: &AnalyticBrdf) -> f64 {
    const N: u32 = 8;
    let wo = DVec3::Z;
    let mut sum = 0.0;
    for i in 0..N {
        for j in 0..N {
            let u = DVec2::new(
                (f64::from(i) + 0.5) / f64::from(N),
                (f64::from(j) + 0.5) / f64::from(N),
            );
            if let Some(s) = brdf.sample(wo, u) {
                let v = brdf.eval(s.wi, wo) * s.wi.z / s.pdf;
                if v.is_finite() {
                    sum += v;
                }
            }
        }
    }
    sum / f64::from(N * N)
}

impl PreparedSpmm {
    /// Selection weight of weight entry `i` of a texel of cluster `c`.
    fn selection(&self, c: usize, i: usize) -> f64 {
        let w = self.rgb[i];
        let luminance =
            0.2126 * f64::from(w[0]) + 0.7152 * f64::from(w[1]) + 0.0722 * f64::from(w[2]);
        let s = luminance.max(0.0) * self.basis_albedo[c][usize::from(self.basis[i])];
        if s.is_finite() { s } else { 0.0 }
    }

    /// The entries of texel `t` and the sum of their selection weights.
    fn selection_total(&self, t: usize) -> (usize, std::ops::Range<usize>, f64) {
        let c = self.texel_cluster[t] as usize;
        let entries = self.offsets[t] as usize..self.offsets[t + 1] as usize;
        let total = entries.clone().map(|i| self.selection(c, i)).sum();
        (c, entries, total)
    }

    /// A direction `wi` (texel frame) drawn for view `wo` at texel `t`, with its pdf
    /// (`texel_pdf`). `None` when the drawn direction is below the texel's horizon,
    /// where the BTF is zero (that probability is simply missing).
    pub fn sample_texel(&self, t: usize, wo: DVec3, u: DVec2) -> Option<(DVec3, f64)> {
        if wo.z <= 0.0 {
            return None;
        }
        let (c, entries, total) = self.selection_total(t);
        let wi = if total <= 0.0 || u.x < DEFENSIVE_SHARE {
            let x = if total <= 0.0 {
                u.x
            } else {
                u.x / DEFENSIVE_SHARE
            };
            defensive_sample(DVec2::new(x.min(1.0 - f64::EPSILON), u.y))
        } else {
            // Reuse u.x: its position inside the chosen entry's interval is uniform.
            let mut x = (u.x - DEFENSIVE_SHARE) / (1.0 - DEFENSIVE_SHARE) * total;
            let mut chosen = entries.end - 1;
            for i in entries.clone() {
                let s = self.selection(c, i);
                if x < s {
                    chosen = i;
                    x /= s;
                    break;
                }
                x -= s;
            }
            let x = x.clamp(0.0, 1.0 - f64::EPSILON);
            let basis = &self.bases[c][usize::from(self.basis[chosen])];
            let frame = basis.frame();
            let s = basis
                .brdf()
                .sample(frame.to_local(wo), DVec2::new(x, u.y))?;
            frame.to_world(s.wi)
        };
        if wi.z <= 0.0 {
            return None;
        }
        // The selection was summed above: the pdf reuses it (a per-ray path).
        let pdf = self.mixture_pdf((c, entries, total), wi, wo);
        (pdf > 0.0 && pdf.is_finite()).then_some((wi, pdf))
    }

    /// The solid-angle density with which `sample_texel(t, wo, ·)` returns `wi`.
    pub fn texel_pdf(&self, t: usize, wi: DVec3, wo: DVec3) -> f64 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        self.mixture_pdf(self.selection_total(t), wi, wo)
    }

    /// `texel_pdf` from the texel's cluster, weight entries and selection total.
    fn mixture_pdf(
        &self,
        (c, entries, total): (usize, std::ops::Range<usize>, f64),
        wi: DVec3,
        wo: DVec3,
    ) -> f64 {
        if total <= 0.0 {
            return defensive_pdf(wi);
        }
        let mut mixture = 0.0;
        for i in entries {
            let s = self.selection(c, i);
            if s > 0.0 {
                let basis = &self.bases[c][usize::from(self.basis[i])];
                let frame = basis.frame();
                mixture += s * basis.brdf().pdf(frame.to_local(wo), frame.to_local(wi));
            }
        }
        DEFENSIVE_SHARE * defensive_pdf(wi) + (1.0 - DEFENSIVE_SHARE) * mixture / total
    }

    /// `sample_texel` at the texel nearest to `uv` (tiled by `uv_scale`), as the
    /// renderer's nearest filtering reads it; `None` for a non-finite UV.
    pub fn sample_uv(
        &self,
        uv: DVec2,
        uv_scale: DVec2,
        wo: DVec3,
        u: DVec2,
    ) -> Option<(DVec3, f64)> {
        uv.is_finite()
            .then(|| self.sample_texel(self.grid.nearest(uv, uv_scale), wo, u))
            .flatten()
    }

    /// `texel_pdf` at the texel nearest to `uv`.
    pub fn pdf_uv(&self, uv: DVec2, uv_scale: DVec2, wi: DVec3, wo: DVec3) -> f64 {
        if !uv.is_finite() {
            return 0.0;
        }
        self.texel_pdf(self.grid.nearest(uv, uv_scale), wi, wo)
    }
}

/// The selection albedo of every basis, per cluster.
pub(super) fn basis_albedos(bases: &[Vec<crate::brdf::BasisFunction>]) -> Vec<Vec<f64>> {
    bases
        .iter()
        .map(|c| c.iter().map(|b| selection_albedo(b.brdf())).collect())
        .collect()
}

#[cfg(test)]
mod tests {
    use glam::{DVec2, DVec3};

    use crate::brdf::chi2_tests::{
        Binning, PHI_BINS, SIGNIFICANCE, THETA_BINS, histogram, p_value,
    };
    use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
    use crate::spmm::{Cluster, PrepareRequest, PreparedSpmm, SparseWeights, SpmmMaterial};

    fn tilted(x: f64, y: f64) -> DVec3 {
        DVec3::new(x, y, (1.0 - x * x - y * y).sqrt())
    }

    /// One texel of three tilted bases (Lambertian, Cook-Torrance, anisotropic Ward)
    /// with unequal colour weights, as a fitted pack's texel looks; `zero` gives the
    /// texel no weight at all (the defensive mixture alone).
    fn texel(zero: bool) -> PreparedSpmm {
        let basis = |model, params: &[(&str, f64)], n| {
            BasisFunction::new(AnalyticBrdf::new(model, params).expect("valid"), n)
                .expect("unit normal")
        };
        let bases = vec![
            basis(BrdfModel::Lambertian, &[], tilted(0.35, 0.0)),
            basis(
                BrdfModel::CookTorrance,
                &[("m", 0.28), ("f0", 0.04)],
                tilted(-0.3, 0.2),
            ),
            basis(
                BrdfModel::Ward,
                &[("ax", 0.3), ("ay", 0.15)],
                tilted(0.0, -0.4),
            ),
        ];
        let w = if zero { 0.0 } else { 1.0 };
        let pack = SpmmMaterial::new(
            "sampling test".into(),
            "test".into(),
            1,
            1,
            vec![Cluster { bases }],
            vec![0],
            SparseWeights {
                offsets: vec![0, 3],
                basis: vec![0, 1, 2],
                rgb: vec![
                    [0.3 * w, 0.2 * w, 0.1 * w],
                    [0.9 * w; 3],
                    [0.2 * w, 0.5 * w, 0.4 * w],
                ],
            },
            None,
        )
        .expect("valid material");
        pack.prepare(&PrepareRequest {
            used_clusters: None,
            residual: false,
            max_npca: 0,
        })
    }

    /// The texel sampler draws what its pdf says, at normal, oblique and grazing view,
    /// with weights and without (chi-square over the sphere, as the BRDF samplers).
    #[test]
    fn the_texel_sampler_matches_its_pdf() {
        let views = [tilted(0.0, 0.0), tilted(0.6, 0.5), tilted(-0.99, 0.05)];
        let cases: Vec<(bool, DVec3)> = views
            .iter()
            .map(|&v| (false, v))
            .chain([(true, views[1])])
            .collect();
        let alpha = 1.0 - (1.0 - SIGNIFICANCE).powf(1.0 / 64.0);
        let binning = Binning::new(DVec3::Z, 1.0);
        for (i, (zero, wo)) in cases.into_iter().enumerate() {
            let p = texel(zero);
            let (observed, accepted) = histogram(
                |u| p.sample_texel(0, wo, u).map(|s| s.0),
                |w| binning.index(w),
                THETA_BINS * PHI_BINS,
                500 + i as u64,
            );
            let expected = binning.integrate(|wi| p.texel_pdf(0, wi, wo));
            let pv = p_value(&observed, &expected, accepted, 1e-6).expect("chi-square runs");
            assert!(
                pv > alpha,
                "case {i} (wo {wo}, zero weights {zero}): p = {pv}"
            );
        }
    }

    /// The test above fails for a pdf that forgets the defensive share.
    #[test]
    fn the_chi_square_notices_a_pdf_without_its_defensive_share() {
        let p = texel(false);
        let wo = tilted(0.6, 0.5);
        let binning = Binning::new(DVec3::Z, 1.0);
        let (observed, accepted) = histogram(
            |u| p.sample_texel(0, wo, u).map(|s| s.0),
            |w| binning.index(w),
            THETA_BINS * PHI_BINS,
            9,
        );
        let wrong = binning.integrate(|wi| {
            let d = super::DEFENSIVE_SHARE;
            (p.texel_pdf(0, wi, wo) - d * super::defensive_pdf(wi)) / (1.0 - d)
        });
        let pv = p_value(&observed, &wrong, accepted, 1e-6).unwrap_or(0.0);
        assert!(pv < 1e-6, "p = {pv}");
    }

    /// A Lambertian basis's BTF over the mixture's pdf is nearly constant where it
    /// dominates: the point of drawing from the bases.
    #[test]
    fn a_lambertian_texel_is_drawn_nearly_in_proportion_to_its_btf() {
        let p = texel(false);
        let wo = tilted(0.2, 0.1);
        let mut ratios = Vec::new();
        for i in 0..64 {
            for j in 0..64 {
                let u = DVec2::new((i as f64 + 0.5) / 64.0, (j as f64 + 0.5) / 64.0);
                if let Some((wi, pdf)) = p.sample_texel(0, wo, u) {
                    ratios.push(p.eval_texel(0, wi, wo).x / pdf);
                }
            }
        }
        let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
        let var = ratios.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / ratios.len() as f64;
        // The defensive mixture alone: ratio spread for the same texel.
        let mut defensive = Vec::new();
        for i in 0..64 {
            for j in 0..64 {
                let u = DVec2::new((i as f64 + 0.5) / 64.0, (j as f64 + 0.5) / 64.0);
                let wi = super::defensive_sample(u);
                defensive.push(p.eval_texel(0, wi, wo).x / super::defensive_pdf(wi));
            }
        }
        let dmean = defensive.iter().sum::<f64>() / defensive.len() as f64;
        let dvar =
            defensive.iter().map(|r| (r - dmean).powi(2)).sum::<f64>() / defensive.len() as f64;
        assert!(
            (mean - dmean).abs() < 0.05 * dmean,
            "both estimate the texel's albedo: {mean} vs {dmean}"
        );
        assert!(
            var < 0.5 * dvar,
            "variance {var} vs the defensive mixture's {dvar}"
        );
    }
}
