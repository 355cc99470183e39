//! The meso-scale side (Sun et al. 2010, eq. 3): each material's BTF tabulated at the
//! M local incident cells and a grid of view directions, so a pixel's shading is dot
//! products of length M with the interpolated local incident radiance L*. Each table
//! entry is the BTF (cosine included) averaged over its local cell (3 x 3 strata), so
//! sum_m b_m L*_m integrates BTF x radiance over the hemisphere. SPMM packs are linear
//! in their basis functions and PCA terms, so each cluster's basis functions and
//! residual components are tabulated once and a texel combines them with its own
//! weights at shading time (far smaller than a table per texel); analytic BRDFs are
//! one tabulated function times the albedo. Views: `HemisphereGrid` cell centres,
//! interpolated bilinearly in the area-preserving square.

use std::sync::Arc;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::hemisphere::HemisphereGrid;
use meso_materials::brdf::AnalyticBrdf;
use meso_materials::merl::MerlBrdf;
use meso_materials::spmm::{MOVING_NPCA, SpmmMaterial};
use meso_render::scene::Material;

/// Strata per side for the cell averages.
const STRATA: u32 = 3;

/// A tabulated material.
pub enum BtfTable {
    Brdf {
        /// [view][M]
        rows: Vec<f32>,
        albedo: [f32; 3],
    },
    Spmm(Box<SpmmTable>),
    /// A MERL table times its tint: RGB, [view][channel][M].
    Rgb {
        rows: Vec<f32>,
    },
}

pub struct SpmmTable {
    material: Arc<SpmmMaterial>,
    uv_scale: DVec2,
    /// Per cluster, [basis][view][M].
    bases: Vec<Vec<f32>>,
    /// Per cluster, [term (mean, then k components)][view][channel][M]; empty without
    /// a residual in use.
    residual: Vec<Vec<f32>>,
    /// PCA components used.
    k: usize,
}

impl SpmmTable {
    /// The pack's clusters.
    pub fn clusters(&self) -> usize {
        self.bases.len()
    }

    /// Cluster `c`'s basis rows, [basis][view][M].
    pub fn basis_rows(&self, c: usize) -> &[f32] {
        self.bases.get(c).map_or(&[], Vec::as_slice)
    }

    /// Cluster `c`'s residual rows, [term][view][channel][M]; empty without a
    /// residual in use.
    pub fn residual_rows(&self, c: usize) -> &[f32] {
        self.residual.get(c).map_or(&[], Vec::as_slice)
    }

    /// The residual's PCA terms tabulated (0 without a residual in use).
    pub fn terms(&self) -> usize {
        if self.residual.is_empty() { 0 } else { self.k }
    }
}

/// How a pixel's view direction reads the tabulated views.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ViewLookup {
    /// The four surrounding views, weighted bilinearly (the exact interpolant).
    Bilinear,
    /// One of those four views, chosen with probability equal to its bilinear weight
    /// from the uniform number in [0, 1): an unbiased estimate of `Bilinear` at a
    /// quarter of the dot products (stochastic filtering; the progressive film
    /// averages the choice away as it averages the pixel jitter).
    Pick(f64),
    /// The view with the largest weight, no SPMM residual: the seed's trick while the
    /// camera is dragged (biased, never accumulated with the others).
    Nearest,
}

/// The shared geometry of the tables.
#[derive(Clone, Copy, Debug)]
pub struct Tabulation {
    pub local: HemisphereGrid,
    pub views: HemisphereGrid,
}

#[inline(always)]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    // Eight independent partial sums so the compiler vectorises the loop.
    let mut acc = [0.0f32; 8];
    let (ac, bc) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (x, y) in ac.zip(bc) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    let mut s: f32 = acc.iter().sum();
    for (x, y) in ar.iter().zip(br) {
        s += x * y;
    }
    s
}

impl Tabulation {
    /// Cell average over local cell `m` of `f(wi)`.
    fn cell_mean(&self, m: usize, f: impl Fn(DVec3) -> f64) -> f64 {
        let s: f64 = self.local.strata(m, STRATA).map(f).sum();
        s / (STRATA * STRATA) as f64
    }

    /// `None` for materials without a table: mirrors (the ray is followed) and `btf`
    /// materials (evaluated per pixel by the mode).
    pub fn table(&self, material: &Material) -> Option<BtfTable> {
        self.table_reusing(None, material)
    }

    /// `table` of an edited material, taking from `before` (the table of the
    /// material before the edit) what the edit left as it was: an SPMM cluster's
    /// basis rows when its bases are unchanged, the residual's when the residual and
    /// its use are. A weight edit so costs no tabulation, a basis edit one cluster's.
    pub fn table_reusing(
        &self,
        before: Option<&BtfTable>,
        material: &Material,
    ) -> Option<BtfTable> {
        match material {
            Material::Brdf { brdf, albedo } => Some(self.brdf_table(brdf, *albedo)),
            Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            } => {
                let before = match before {
                    Some(BtfTable::Spmm(t)) => Some(t.as_ref()),
                    _ => None,
                };
                Some(BtfTable::Spmm(Box::new(self.spmm_table(
                    material,
                    *uv_scale,
                    (*residual, *npca),
                    before,
                ))))
            }
            Material::Merl { brdf, tint } => Some(self.merl_table(brdf, *tint)),
            Material::Mirror { .. } | Material::Btf { .. } => None,
        }
    }

    /// A measured table as an analytic BRDF is tabulated, per channel (its colour
    /// varies with the directions), times its tint.
    fn merl_table(&self, brdf: &MerlBrdf, tint: DVec3) -> BtfTable {
        let (mc, vc) = (self.local.len(), self.views.len());
        let rows = (0..vc * 3 * mc)
            .into_par_iter()
            .map(|i| {
                let (v, ch, m) = (i / (3 * mc), (i / mc) % 3, i % mc);
                let wo = self.views.centre(v);
                self.cell_mean(m, |wi| brdf.eval(wi, wo)[ch] * tint[ch] * wi.z.max(0.0)) as f32
            })
            .collect();
        BtfTable::Rgb { rows }
    }

    fn brdf_table(&self, brdf: &AnalyticBrdf, albedo: DVec3) -> BtfTable {
        let (mc, vc) = (self.local.len(), self.views.len());
        let rows = (0..vc * mc)
            .into_par_iter()
            .map(|i| {
                let wo = self.views.centre(i / mc);
                self.cell_mean(i % mc, |wi| brdf.eval(wi, wo) * wi.z.max(0.0)) as f32
            })
            .collect();
        BtfTable::Brdf {
            rows,
            albedo: [albedo.x as f32, albedo.y as f32, albedo.z as f32],
        }
    }

    fn spmm_table(
        &self,
        material: &Arc<SpmmMaterial>,
        uv_scale: DVec2,
        (use_residual, npca): (bool, usize),
        before: Option<&SpmmTable>,
    ) -> SpmmTable {
        let (mc, vc) = (self.local.len(), self.views.len());
        let kept_bases = |c: usize| {
            let old = before?;
            let same = old.material.clusters().get(c)?.bases == material.clusters()[c].bases;
            same.then(|| old.bases[c].clone())
        };
        let kept_residual = before.and_then(|old| {
            let (a, b) = (old.material.residual(), material.residual());
            let same = match (a, b) {
                (Some(a), Some(b)) => std::ptr::eq(a, b) || a == b,
                (None, None) => true,
                _ => false,
            };
            let uses = use_residual && material.residual_tables().is_some();
            let k = material
                .residual()
                .filter(|_| uses)
                .map_or(0, |r| r.npca.min(npca));
            let used = old.k == k && old.residual.is_empty() != uses;
            (same && used && old.material.clusters().len() == material.clusters().len())
                .then(|| (old.residual.clone(), old.k))
        });
        // Per cluster, in parallel over its (basis, view) rows: an edit re-tabulates
        // one cluster, which must not run on one core.
        let bases: Vec<Vec<f32>> = (material.clusters().iter().enumerate())
            .map(|(c, cluster)| {
                kept_bases(c).unwrap_or_else(|| {
                    let b = &cluster.bases;
                    (0..b.len() * vc)
                        .into_par_iter()
                        .flat_map_iter(|i| {
                            let (basis, wo) = (&b[i / vc], self.views.centre(i % vc));
                            (0..mc).map(move |m| self.cell_mean(m, |wi| basis.eval(wi, wo)) as f32)
                        })
                        .collect()
                })
            })
            .collect();
        let (residual, k) = match (
            use_residual,
            material.residual(),
            material.residual_tables(),
        ) {
            _ if kept_residual.is_some() => kept_residual.unwrap_or_default(),
            (true, Some(r), Some((lights, views))) => {
                let k = r.npca.min(npca);
                let (nl, nv) = (r.light_dirs.len(), r.view_dirs.len());
                // Interpolation weights of every stratum and every view centre.
                let strata: Vec<Vec<[(u32, f64); 3]>> = (0..mc)
                    .map(|m| {
                        self.local
                            .strata(m, STRATA)
                            .map(|d| lights.cosine_weights(d))
                            .collect()
                    })
                    .collect();
                let view_w: Vec<[(u32, f64); 3]> = (0..vc)
                    .map(|v| views.weights(self.views.centre(v)))
                    .collect();
                let table_at = |c: usize, term: usize, l: usize, v: usize| -> [f64; 3] {
                    let i = if term == 0 {
                        ((c * nl + l) * nv + v) * 3
                    } else {
                        (((c * r.npca + term - 1) * nl + l) * nv + v) * 3
                    };
                    let t = if term == 0 { &r.mean } else { &r.components };
                    [t[i] as f64, t[i + 1] as f64, t[i + 2] as f64]
                };
                let per_cluster = (0..material.clusters().len())
                    .into_par_iter()
                    .map(|c| {
                        let mut out = vec![0.0f32; (1 + k) * vc * 3 * mc];
                        for term in 0..=k {
                            for v in 0..vc {
                                for m in 0..mc {
                                    let mut acc = [0.0f64; 3];
                                    for s in &strata[m] {
                                        for &(l, wl) in s {
                                            for &(vv, wv) in &view_w[v] {
                                                let w = wl * wv;
                                                if w == 0.0 {
                                                    continue;
                                                }
                                                let e = table_at(c, term, l as usize, vv as usize);
                                                for ch in 0..3 {
                                                    acc[ch] += w * e[ch];
                                                }
                                            }
                                        }
                                    }
                                    let n = strata[m].len() as f64;
                                    for ch in 0..3 {
                                        out[((term * vc + v) * 3 + ch) * mc + m] =
                                            (acc[ch] / n) as f32;
                                    }
                                }
                            }
                        }
                        out
                    })
                    .collect();
                (per_cluster, k)
            }
            _ => (Vec::new(), 0),
        };
        SpmmTable {
            material: material.clone(),
            uv_scale,
            bases,
            residual,
            k,
        }
    }
}

/// The (view, weight) pairs `lookup` keeps of the four bilinear ones.
fn select_views(views: [(usize, f32); 4], lookup: ViewLookup) -> [(usize, f32); 4] {
    let total: f32 = views.iter().map(|v| v.1).sum();
    let one = |v: usize| [(v, total), (0, 0.0), (0, 0.0), (0, 0.0)];
    match lookup {
        ViewLookup::Bilinear => views,
        ViewLookup::Nearest => one(views
            .iter()
            .copied()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0, |v| v.0)),
        ViewLookup::Pick(u) => {
            let mut left = u * f64::from(total);
            // The last view with a weight takes what rounding leaves.
            let mut chosen = views.iter().rposition(|v| v.1 > 0.0).unwrap_or(0);
            for (i, v) in views.iter().enumerate() {
                let w = f64::from(v.1);
                if w > 0.0 && left < w {
                    chosen = i;
                    break;
                }
                left -= w;
            }
            one(views[chosen].0)
        }
    }
}

impl BtfTable {
    /// Outgoing radiance towards local `wo` at surface UV `uv`, for local incident
    /// radiance `lstar` laid out [channel][M] (eq. 3), reading the views as `lookup`
    /// says.
    pub fn shade(
        &self,
        tab: &Tabulation,
        uv: DVec2,
        wo: DVec3,
        lstar: &[f32],
        lookup: ViewLookup,
    ) -> [f32; 3] {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the CPU has AVX (checked above).
            return unsafe { self.shade_avx(tab, uv, wo, lstar, lookup) };
        }
        self.shade_here(tab, uv, wo, lstar, lookup)
    }

    /// `shade` compiled for AVX: the dot products' eight partial sums fill one 8-wide
    /// register instead of two 4-wide ones, the same multiplies and adds in the same
    /// order (no fused multiply-add), so the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn shade_avx(
        &self,
        tab: &Tabulation,
        uv: DVec2,
        wo: DVec3,
        lstar: &[f32],
        lookup: ViewLookup,
    ) -> [f32; 3] {
        self.shade_here(tab, uv, wo, lstar, lookup)
    }

    /// `shade`'s body, inlined into each of its builds.
    #[inline(always)]
    fn shade_here(
        &self,
        tab: &Tabulation,
        uv: DVec2,
        wo: DVec3,
        lstar: &[f32],
        lookup: ViewLookup,
    ) -> [f32; 3] {
        if wo.z <= 0.0 {
            return [0.0; 3];
        }
        let mc = tab.local.len();
        let (lr, lg, lb) = (&lstar[..mc], &lstar[mc..2 * mc], &lstar[2 * mc..3 * mc]);
        let moving = lookup == ViewLookup::Nearest;
        let views = select_views(tab.views.bilinear(wo), lookup);
        let mut out = [0.0f32; 3];
        match self {
            BtfTable::Brdf { rows, albedo } => {
                for (v, w) in views {
                    if w == 0.0 {
                        continue;
                    }
                    let row = &rows[v * mc..(v + 1) * mc];
                    out[0] += w * dot(row, lr);
                    out[1] += w * dot(row, lg);
                    out[2] += w * dot(row, lb);
                }
                for c in 0..3 {
                    out[c] *= albedo[c];
                }
            }
            BtfTable::Rgb { rows } => {
                for (v, w) in views {
                    if w == 0.0 {
                        continue;
                    }
                    for (ch, l) in [lr, lg, lb].into_iter().enumerate() {
                        out[ch] += w * dot(&rows[(v * 3 + ch) * mc..][..mc], l);
                    }
                }
            }
            BtfTable::Spmm(t) => {
                let vc = tab.views.len();
                let texel = t.material.texel_at(uv, t.uv_scale);
                let c = t.material.texel_cluster()[texel] as usize;
                let bases = &t.bases[c];
                for (v, w) in views {
                    if w == 0.0 {
                        continue;
                    }
                    for (j, a) in t.material.texel_weights(texel) {
                        let row = &bases[(j as usize * vc + v) * mc..][..mc];
                        out[0] += w * a[0] * dot(row, lr);
                        out[1] += w * a[1] * dot(row, lg);
                        out[2] += w * a[2] * dot(row, lb);
                    }
                    if let Some(res) = t.residual.get(c) {
                        // A moving camera keeps the mean and the first MOVING_NPCA terms.
                        let terms = if moving { t.k.min(MOVING_NPCA) } else { t.k };
                        let npca = t.material.npca();
                        let coef = t
                            .material
                            .residual()
                            .map(|r| &r.coefficients[texel * npca..texel * npca + t.k]);
                        for term in 0..=terms {
                            let a = if term == 0 {
                                1.0
                            } else {
                                coef.map_or(0.0, |c| c[term - 1])
                            };
                            let base = (term * vc + v) * 3 * mc;
                            for (ch, l) in [lr, lg, lb].into_iter().enumerate() {
                                out[ch] += w * a * dot(&res[base + ch * mc..][..mc], l);
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// Bytes of the tables.
    pub fn bytes(&self) -> usize {
        match self {
            BtfTable::Brdf { rows, .. } | BtfTable::Rgb { rows } => 4 * rows.len(),
            BtfTable::Spmm(t) => {
                4 * (t.bases.iter().map(Vec::len).sum::<usize>()
                    + t.residual.iter().map(Vec::len).sum::<usize>())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::brdf::{BasisFunction, BrdfModel};
    use meso_materials::rng::SampleStream;
    use meso_materials::spmm::testing::sample_material;

    /// `shade` (the AVX build where the CPU has it) gives the portable build's bits:
    /// an SPMM table with bases and residual terms, and an analytic BRDF's, at random
    /// views, texels and incident radiance, every view lookup. Local cells (M = 36)
    /// leave a remainder after the dot products' blocks of eight.
    #[test]
    fn every_build_of_shade_gives_the_same_bits() {
        let tab = Tabulation {
            local: HemisphereGrid::new(6),
            views: HemisphereGrid::new(5),
        };
        let material = Arc::new(sample_material(8, 8, 3, Some(4)));
        let brdf = AnalyticBrdf::with_defaults(BrdfModel::CookTorrance);
        let tables = [
            BtfTable::Spmm(Box::new(tab.spmm_table(
                &material,
                DVec2::ONE,
                (true, 4),
                None,
            ))),
            tab.brdf_table(&brdf, DVec3::new(0.8, 0.5, 0.3)),
        ];
        for k in 0..500u64 {
            let mut s = SampleStream::new(&[41, k]);
            let wo = meso_materials::brdf::warp::cosine_hemisphere(s.next_2d());
            let uv = s.next_2d();
            let lstar: Vec<f32> = (0..3 * tab.local.len()).map(|_| s.next() as f32).collect();
            let u = s.next();
            for table in &tables {
                for lookup in [
                    ViewLookup::Bilinear,
                    ViewLookup::Pick(u),
                    ViewLookup::Nearest,
                ] {
                    let got = table.shade(&tab, uv, wo, &lstar, lookup).map(f32::to_bits);
                    let portable = table.shade_here(&tab, uv, wo, &lstar, lookup);
                    assert_eq!(got, portable.map(f32::to_bits), "{wo} {uv} {lookup:?}");
                }
            }
        }
    }

    /// A table made from the table before an edit equals one made afresh, bit for
    /// bit: after a weight edit (nothing tabulated again), a basis edit (its cluster
    /// again), the residual turned off and on, and fewer PCA terms.
    #[test]
    fn a_table_reusing_the_one_before_an_edit_equals_a_fresh_one() {
        let tab = Tabulation {
            local: HemisphereGrid::new(4),
            views: HemisphereGrid::new(4),
        };
        let material = Arc::new(sample_material(8, 8, 3, Some(4)));
        let weighted = material
            .with_weight_scale(&meso_materials::spmm::WeightTarget::basis(1, 0), [1.5; 3])
            .expect("a weight edit");
        let b = &material.clusters()[1].bases[0];
        let changed = b
            .brdf()
            .with_param(b.brdf().model().param_specs()[0].name, 0.3);
        let rebased = match changed {
            Ok(brdf) => material
                .with_basis(1, 0, BasisFunction::new(brdf, b.normal()).expect("normal"))
                .expect("a basis edit"),
            Err(_) => material
                .with_basis(
                    1,
                    0,
                    BasisFunction::new(*b.brdf(), DVec3::new(0.2, 0.0, 1.0).normalize())
                        .expect("normal"),
                )
                .expect("a basis edit"),
        };
        let bits = |t: &SpmmTable| {
            let all = t.bases.iter().chain(&t.residual).flatten();
            (all.map(|v| v.to_bits()).collect::<Vec<_>>(), t.k)
        };
        let before = tab.spmm_table(&material, DVec2::ONE, (true, 4), None);
        for (edited, residual) in [
            (weighted.clone(), (true, 4)),
            (rebased, (true, 4)),
            (weighted.clone(), (false, 4)),
            (weighted, (true, 2)),
        ] {
            let edited = Arc::new(edited);
            let reused = tab.spmm_table(&edited, DVec2::ONE, residual, Some(&before));
            let fresh = tab.spmm_table(&edited, DVec2::ONE, residual, None);
            assert!(bits(&reused) == bits(&fresh), "{residual:?}");
        }
    }

    #[test]
    fn picking_one_view_is_an_unbiased_estimate_of_the_bilinear_interpolant() {
        // A glossy lobe makes the four views differ; the mean of the picked view over
        // stratified u must equal the bilinear value (each view is chosen for a share
        // of [0, 1) equal to its weight, so N strata are exact to about 4/N).
        let tab = Tabulation {
            local: HemisphereGrid::new(4),
            views: HemisphereGrid::new(6),
        };
        let brdf = AnalyticBrdf::with_defaults(BrdfModel::CookTorrance);
        let table = tab.brdf_table(&brdf, DVec3::ONE);
        let lstar: Vec<f32> = (0..3 * tab.local.len())
            .map(|i| 0.1 + (i % 7) as f32 * 0.3)
            .collect();
        for wo in [
            DVec3::new(0.3, -0.2, 0.9).normalize(),
            DVec3::new(0.8, 0.1, 0.3).normalize(),
            DVec3::new(-0.05, 0.6, 0.2).normalize(),
        ] {
            let exact = table.shade(&tab, DVec2::ZERO, wo, &lstar, ViewLookup::Bilinear);
            let n = 4096;
            let mut mean = [0.0f64; 3];
            for i in 0..n {
                let u = (i as f64 + 0.5) / n as f64;
                let v = table.shade(&tab, DVec2::ZERO, wo, &lstar, ViewLookup::Pick(u));
                for c in 0..3 {
                    mean[c] += f64::from(v[c]) / n as f64;
                }
            }
            let spread: f64 = tab
                .views
                .bilinear(wo)
                .iter()
                .map(|&(v, _)| {
                    table.shade(
                        &tab,
                        DVec2::ZERO,
                        tab.views.centre(v),
                        &lstar,
                        ViewLookup::Bilinear,
                    )[0] as f64
                })
                .fold(0.0, |a, b| a.max(b.abs()));
            for c in 0..3 {
                let e = f64::from(exact[c]);
                assert!(
                    (mean[c] - e).abs() <= 1e-3 * spread.max(e.abs()) + 1e-6,
                    "wo {wo}: channel {c}: picked mean {} vs bilinear {e}",
                    mean[c]
                );
            }
        }
    }
}
