//! The lobe bound of fitted bases, two checks (docs/fitting.md, "The lobe bound"):
//!
//! 1. **Sharpness.** A basis fitted to a BTF is known only at the BTF's tabulated
//!    direction pairs, so it may not peak between them far above what it takes there:
//!    its peak over the measured range (both directions no lower than the lowest
//!    tabulated polar angle of their set) must stay within `MAX_PEAK_RATIO` times its
//!    largest value at the tabulated pairs. A lobe sharper than the angular spacing of
//!    the directions fails it (its peak falls between tabulated pairs).
//! 2. **Hemisphere.** Each basis times its largest weight (any texel, any channel) must
//!    stay within `HEMISPHERE_MULTIPLE` times the pack's largest value at the tabulated
//!    pairs (basis sum plus residual: what the fit makes equal to the BTF there, so a
//!    stand-in for the BTF's maximum) anywhere on the hemisphere down to
//!    `HORIZON_Z` (88.2 degrees), both directions, far beyond the measured rings. Every
//!    microfacet basis grows without limit as light and view approach opposite horizon
//!    directions (h -> n while cos_o -> 0 and G stays near 1, so
//!    f cos_i ~ D F / (4 cos_o)); this bounds that growth by the data's brightness down
//!    to the stated angle. Beyond it (the last 1/32 of cos theta) it still grows as
//!    1/cos_o: bounding that band needs an evaluation rule of docs/brdf.md.
//!
//! Peaks are found by dense sampling (a stratified grid of 24 x 24 light directions
//! times 16 x 16 views, uniform in cos theta and phi, plus for each light the mirror
//! direction about the basis normal and the light itself) followed by a shrinking-step
//! local search from the 8 best samples on both directions, which walks to the edge of
//! the range where a lobe diverges towards it. The validator checks every pack with a
//! residual (its direction sets are the BTF's); the fitter drops bases that break the
//! first check and caps weights so that none breaks the second.

use glam::DVec3;
use rayon::prelude::*;

use super::SpmmMaterial;
use crate::brdf::{BasisFunction, warp};

/// Largest allowed ratio of a basis's peak over the measured range to its largest
/// tabulated value (check 1).
pub const MAX_PEAK_RATIO: f64 = 4.0;

/// Largest allowed ratio of a weighted basis's peak on the hemisphere (down to
/// `HORIZON_Z`) to the pack's largest value at the tabulated pairs (check 2). The
/// brightest measured value times 4: a lone sample may be a few times the brightest
/// highlight the data holds, never the 1e5-1e11 times that made fireflies.
pub const HEMISPHERE_MULTIPLE: f64 = 4.0;

/// The lowest cos theta the hemisphere check samples (88.2 degrees): 1/32, the
/// outermost of 16 rings even in cos theta. Below it microfacet bases diverge as
/// 1/cos_o whatever their weight; the band is 1/32 of the hemisphere's solid angle.
pub const HORIZON_Z: f64 = 1.0 / 32.0;

/// A basis's peak over the measured range ("anywhere") and at the tabulated pairs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LobePeaks {
    pub anywhere: f64,
    pub tabulated: f64,
    /// Where the peak anywhere was found.
    pub wi: DVec3,
    pub wo: DVec3,
}

impl LobePeaks {
    /// `anywhere / tabulated` (infinite when the basis is 0 at every tabulated pair
    /// but not elsewhere, 1 for a basis that is 0 everywhere).
    pub fn ratio(&self) -> f64 {
        if self.anywhere <= 0.0 {
            1.0
        } else if self.tabulated <= 0.0 {
            f64::INFINITY
        } else {
            self.anywhere / self.tabulated
        }
    }
}

/// Directions of a stratified grid over the cap z >= `min_z` (`n` x `n` cells,
/// uniform in cos theta and phi, cell centres).
fn grid(n: usize, min_z: f64) -> Vec<DVec3> {
    let mut d = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let z = 1.0 - (1.0 - min_z) * (i as f64 + 0.5) / n as f64;
            d.push(warp::spherical(
                z,
                std::f64::consts::TAU * (j as f64 + 0.5) / n as f64,
            ));
        }
    }
    d
}

/// `d` moved by (dx, dy) in its tangent plane, if it stays in the cap z >= `min_z`.
fn nudge(d: DVec3, dx: f64, dy: f64, min_z: f64) -> Option<DVec3> {
    let (t, b) = warp::orthonormal_basis(d);
    let n = (d + t * dx + b * dy).normalize();
    (n.z >= min_z).then_some(n)
}

/// The lowest z of a direction set (its outermost polar angle).
fn lowest(dirs: &[DVec3]) -> f64 {
    dirs.iter().map(|d| d.z).fold(1.0, f64::min)
}

/// The peak of `basis` over light directions with z >= `zi` and views with z >=
/// `zo`: (value, light, view), by dense sampling and local search.
fn search_peak(basis: &BasisFunction, zi: f64, zo: f64) -> (f64, DVec3, DVec3) {
    let n = basis.frame().z;
    let wis = grid(24, zi);
    let wos = grid(16, zo);
    // (value, wi, wo), the best few kept for the local search.
    let mut best: Vec<(f64, DVec3, DVec3)> = Vec::new();
    let consider = |v: f64, wi: DVec3, wo: DVec3, best: &mut Vec<(f64, DVec3, DVec3)>| {
        if best.len() < 8 || v > best[best.len() - 1].0 {
            best.push((v, wi, wo));
            best.sort_by(|a, b| b.0.total_cmp(&a.0));
            best.truncate(8);
        }
    };
    for &wi in &wis {
        for &wo in &wos {
            consider(basis.eval(wi, wo), wi, wo, &mut best);
        }
        // Specular lobes peak near the mirror direction about the basis normal.
        if let Some(r) = warp::reflect(wi, n).filter(|r| r.z >= zo) {
            consider(basis.eval(wi, r), wi, r, &mut best);
        }
        if wi.z >= zo {
            consider(basis.eval(wi, wi), wi, wi, &mut best);
        }
    }
    // Local search: shrinking steps on both directions from each of the best samples.
    let mut peak = best.first().copied().unwrap_or((0.0, DVec3::Z, DVec3::Z));
    for &(v0, wi0, wo0) in &best {
        let (mut v, mut wi, mut wo) = (v0, wi0, wo0);
        let mut step = 0.08;
        while step > 1e-5 {
            let mut moved = false;
            for (dx, dy) in [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)] {
                for which in 0..2 {
                    let (ci, co) = if which == 0 {
                        (nudge(wi, dx * step, dy * step, zi), Some(wo))
                    } else {
                        (Some(wi), nudge(wo, dx * step, dy * step, zo))
                    };
                    if let (Some(ci), Some(co)) = (ci, co) {
                        let c = basis.eval(ci, co);
                        if c > v {
                            (v, wi, wo) = (c, ci, co);
                            moved = true;
                        }
                    }
                }
            }
            if !moved {
                step *= 0.5;
            }
        }
        if v > peak.0 {
            peak = (v, wi, wo);
        }
    }
    peak
}

/// The peaks of `basis` over the measured range (dense sampling and local search) and
/// at the tabulated pairs `lights` x `views`.
pub fn lobe_peaks(basis: &BasisFunction, lights: &[DVec3], views: &[DVec3]) -> LobePeaks {
    let mut tabulated = 0.0f64;
    for &wi in lights {
        for &wo in views {
            tabulated = tabulated.max(basis.eval(wi, wo));
        }
    }
    let (v, wi, wo) = search_peak(basis, lowest(lights), lowest(views));
    LobePeaks {
        anywhere: v.max(tabulated),
        tabulated,
        wi,
        wo,
    }
}

/// The peak of `basis` (unit weight) on the hemisphere down to `HORIZON_Z`, both
/// directions: (value, light, view).
pub fn hemisphere_peak(basis: &BasisFunction) -> (f64, DVec3, DVec3) {
    search_peak(basis, HORIZON_Z, HORIZON_Z)
}

/// A basis breaking the lobe bound.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum LobeBoundError {
    #[error(
        "cluster {cluster} basis {basis} ({model}): peaks at {anywhere:.4e} between the tabulated directions (light {wi:?}, view {wo:?}), {ratio:.1}x its largest value {tabulated:.4e} at them; at most {MAX_PEAK_RATIO}x is allowed (a lobe sharper than the measured directions support)"
    )]
    TooSharp {
        cluster: usize,
        basis: usize,
        model: &'static str,
        anywhere: f64,
        tabulated: f64,
        ratio: f64,
        wi: [f64; 3],
        wo: [f64; 3],
    },
    #[error(
        "cluster {cluster} basis {basis} ({model}): with its largest weight {weight:.4e} it reaches {peak:.4e} on the hemisphere (light {wi:?}, view {wo:?}), {ratio:.1}x the pack's largest value {pack_max:.4e} at the tabulated directions; at most {HEMISPHERE_MULTIPLE}x is allowed down to 88.2 degrees (a lobe brighter than the data outside the measured directions)"
    )]
    TooBright {
        cluster: usize,
        basis: usize,
        model: &'static str,
        weight: f64,
        peak: f64,
        pack_max: f64,
        ratio: f64,
        wi: [f64; 3],
        wo: [f64; 3],
    },
}

impl LobeBoundError {
    /// (cluster, basis) at fault.
    pub fn place(&self) -> (usize, usize) {
        match self {
            LobeBoundError::TooSharp { cluster, basis, .. }
            | LobeBoundError::TooBright { cluster, basis, .. } => (*cluster, *basis),
        }
    }
}

/// Whether `basis` keeps within the sharpness bound on these direction sets.
pub fn within_bound(basis: &BasisFunction, lights: &[DVec3], views: &[DVec3]) -> bool {
    lobe_peaks(basis, lights, views).ratio() <= MAX_PEAK_RATIO
}

/// Per cluster, per basis: its largest weight over the cluster's texels and channels.
pub fn largest_weights(m: &SpmmMaterial) -> Vec<Vec<f64>> {
    let mut w: Vec<Vec<f64>> = m
        .clusters()
        .iter()
        .map(|c| vec![0.0; c.bases.len()])
        .collect();
    for (t, &c) in m.texel_cluster().iter().enumerate() {
        for (j, rgb) in m.texel_weights(t) {
            let v = rgb.iter().fold(0.0f64, |a, &x| a.max(f64::from(x)));
            let slot = &mut w[c as usize][j as usize];
            *slot = slot.max(v);
        }
    }
    w
}

/// The pack's largest value at its residual's tabulated pairs (basis sum plus the
/// residual's mean and components, any texel and channel); 0 without a residual.
pub fn tabulated_maximum(m: &SpmmMaterial) -> f64 {
    let Some(r) = m.residual() else {
        return 0.0;
    };
    let (nl, nv) = (r.light_dirs.len(), r.view_dirs.len());
    let d = nl * nv * 3;
    let k = r.npca;
    // Each basis at every tabulated pair, per cluster.
    let tables: Vec<Vec<Vec<f64>>> = m
        .clusters()
        .par_iter()
        .map(|c| {
            c.bases
                .iter()
                .map(|b| {
                    let mut col = Vec::with_capacity(nl * nv);
                    for &wi in &r.light_dirs {
                        for &wo in &r.view_dirs {
                            col.push(b.eval(wi, wo));
                        }
                    }
                    col
                })
                .collect()
        })
        .collect();
    (0..m.texel_cluster().len())
        .into_par_iter()
        .map(|t| {
            let c = m.texel_cluster()[t] as usize;
            let mut acc: Vec<f64> = r.mean[c * d..(c + 1) * d]
                .iter()
                .map(|&x| f64::from(x))
                .collect();
            for kk in 0..k {
                let coef = f64::from(r.coefficients[t * k + kk]);
                let comp = &r.components[(c * k + kk) * d..(c * k + kk + 1) * d];
                for (a, &x) in acc.iter_mut().zip(comp) {
                    *a += coef * f64::from(x);
                }
            }
            for (j, rgb) in m.texel_weights(t) {
                for (p, &v) in tables[c][j as usize].iter().enumerate() {
                    for ch in 0..3 {
                        acc[p * 3 + ch] += f64::from(rgb[ch]) * v;
                    }
                }
            }
            acc.into_iter().fold(0.0f64, f64::max)
        })
        .reduce(|| 0.0, f64::max)
}

/// Checks every basis of a pack with a residual against both bounds (the first
/// breach in cluster, basis order); packs without one (made by hand, not fitted) have
/// no measured directions.
pub fn check_lobes(m: &SpmmMaterial) -> Result<(), LobeBoundError> {
    let Some(r) = m.residual() else {
        return Ok(());
    };
    let all: Vec<(usize, usize, &BasisFunction)> = m
        .clusters()
        .iter()
        .enumerate()
        .flat_map(|(c, cl)| cl.bases.iter().enumerate().map(move |(j, b)| (c, j, b)))
        .collect();
    let sharp: Vec<Option<LobeBoundError>> = all
        .par_iter()
        .map(|&(cluster, basis, b)| {
            let p = lobe_peaks(b, &r.light_dirs, &r.view_dirs);
            (p.ratio() > MAX_PEAK_RATIO).then(|| LobeBoundError::TooSharp {
                cluster,
                basis,
                model: b.brdf().model().name(),
                anywhere: p.anywhere,
                tabulated: p.tabulated,
                ratio: p.ratio(),
                wi: p.wi.to_array(),
                wo: p.wo.to_array(),
            })
        })
        .collect();
    if let Some(e) = sharp.into_iter().flatten().next() {
        return Err(e);
    }
    let weights = largest_weights(m);
    let pack_max = tabulated_maximum(m);
    let bright: Vec<Option<LobeBoundError>> = all
        .par_iter()
        .map(|&(cluster, basis, b)| {
            let weight = weights[cluster][basis];
            if weight <= 0.0 {
                return None;
            }
            let (v, wi, wo) = hemisphere_peak(b);
            let peak = weight * v;
            let ratio = if pack_max > 0.0 {
                peak / pack_max
            } else {
                f64::INFINITY
            };
            (peak > 0.0 && ratio > HEMISPHERE_MULTIPLE).then(|| LobeBoundError::TooBright {
                cluster,
                basis,
                model: b.brdf().model().name(),
                weight,
                peak,
                pack_max,
                ratio,
                wi: wi.to_array(),
                wo: wo.to_array(),
            })
        })
        .collect();
    match bright.into_iter().flatten().next() {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::btf::directions::bonn81;

    fn phong(n: f64, normal: DVec3) -> BasisFunction {
        BasisFunction::new(
            AnalyticBrdf::new(BrdfModel::BlinnPhong, &[("n", n)]).expect("valid"),
            normal.normalize(),
        )
        .expect("valid")
    }

    #[test]
    fn broad_lobes_pass_and_sharp_ones_between_the_directions_fail() {
        let d = bonn81();
        let broad = lobe_peaks(&phong(20.0, DVec3::new(0.1, 0.05, 1.0)), &d, &d);
        assert!(broad.ratio() < 1.5, "{broad:?}");
        // A Blinn-Phong n = 1e5 tilted so that its mirror pairs fall between the
        // tabulated ones: the peak anywhere is far above the tabulated maximum.
        let sharp = phong(1e5, DVec3::new(0.21, 0.13, 1.0));
        let p = lobe_peaks(&sharp, &d, &d);
        assert!(p.ratio() > MAX_PEAK_RATIO, "{p:?}");
        // The search finds the true peak: for Blinn-Phong it is at h = n, where the
        // value is the normalised lobe's maximum times the cosine there; a direct
        // evaluation at a mirror pair about the normal is never above it.
        let n = sharp.frame().z;
        let wi = warp::spherical(0.8, 0.7);
        let wo = warp::reflect(wi, n).expect("above");
        assert!(p.anywhere >= sharp.eval(wi, wo) * (1.0 - 1e-6), "{p:?}");
        // The Lambertian is flat: its peak is at a tabulated pair (the pole).
        let lamb = BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
            .expect("valid");
        assert!((lobe_peaks(&lamb, &d, &d).ratio() - 1.0).abs() < 1e-9);
    }

    /// A hand-made one-texel pack with a residual on the Bonn directions: cluster 0
    /// holds a Lambertian and `second`.
    fn pack_with(second: BasisFunction) -> SpmmMaterial {
        pack_weighted(second, 0.2)
    }

    fn pack_weighted(second: BasisFunction, weight: f32) -> SpmmMaterial {
        let lamb = BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
            .expect("valid");
        let d = bonn81();
        let table = d.len() * d.len() * 3;
        SpmmMaterial::new(
            "sharp".into(),
            "test".into(),
            1,
            1,
            vec![crate::spmm::Cluster {
                bases: vec![lamb, second],
            }],
            vec![0],
            crate::spmm::SparseWeights {
                offsets: vec![0, 2],
                basis: vec![0, 1],
                rgb: vec![[0.5; 3], [weight; 3]],
            },
            Some(crate::spmm::Residual {
                light_dirs: d.clone(),
                view_dirs: d,
                npca: 0,
                mean: vec![0.0; table],
                components: Vec::new(),
                coefficients: Vec::new(),
            }),
        )
        .expect("a valid pack")
    }

    #[test]
    fn the_validator_names_the_cluster_and_basis_of_a_too_sharp_lobe() {
        assert_eq!(check_lobes(&pack_with(phong(20.0, DVec3::Z))), Ok(()));
        let e = check_lobes(&pack_with(phong(1e5, DVec3::new(0.21, 0.13, 1.0))))
            .expect_err("too sharp");
        let LobeBoundError::TooSharp {
            cluster,
            basis,
            model,
            ratio,
            ..
        } = e.clone()
        else {
            panic!("{e}")
        };
        assert_eq!((cluster, basis, model), (0, 1, "blinn_phong"));
        assert!(ratio > MAX_PEAK_RATIO);
        assert!(
            e.to_string().starts_with("cluster 0 basis 1 (blinn_phong)"),
            "{e}"
        );
    }

    #[test]
    fn a_lobe_fine_at_the_measured_directions_but_exploding_at_grazing_is_caught() {
        // A rough Cook-Torrance about +z: broad, so it peaks at the tabulated pairs
        // within the measured range, but towards opposite horizon directions it grows
        // as D F / (4 cos_o), 20-odd times its value on the 75 degree ring.
        let ct = BasisFunction::new(
            AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.3), ("f0", 0.05)]).expect("valid"),
            DVec3::Z,
        )
        .expect("valid");
        let d = bonn81();
        assert!(within_bound(&ct, &d, &d), "{:?}", lobe_peaks(&ct, &d, &d));
        let (peak, wi, wo) = hemisphere_peak(&ct);
        assert!(wo.z < 0.05 && wi.z < 0.05, "{wi:?} {wo:?}");
        // Never below a direct evaluation at a mirror pair on the horizon ring (within
        // the local search's last step, 1e-5: the value grows as 1/cos_o there).
        let grazing = warp::spherical(HORIZON_Z, 0.3);
        let mirror = warp::reflect(grazing, DVec3::Z).expect("above");
        let direct = ct.eval(grazing, mirror);
        assert!(
            peak >= direct * (1.0 - 1e-4),
            "{peak} vs {direct} {wi:?} {wo:?}"
        );
        let measured = lobe_peaks(&ct, &d, &d).anywhere;
        assert!(peak > 10.0 * measured, "{peak} vs {measured}");

        // Weighted 0.2 next to a Lambertian at 0.5 it is over the hemisphere bound...
        let m = pack_weighted(ct, 0.2);
        let e = check_lobes(&m).expect_err("too bright at grazing");
        assert_eq!(e.place(), (0, 1), "{e}");
        let LobeBoundError::TooBright {
            weight,
            peak: weighted,
            pack_max,
            ratio,
            ..
        } = e.clone()
        else {
            panic!("{e}")
        };
        assert!(
            (weight - 0.2).abs() < 1e-6 && ratio > HEMISPHERE_MULTIPLE,
            "{e}"
        );
        assert!((weighted - 0.2 * peak).abs() <= 1e-6 * weighted, "{e}");
        // ...the pack's maximum is at a tabulated pair: the Lambertian's pole value
        // plus the lobe's largest tabulated value, both at most that.
        let lamb_pole =
            0.5 * pack_with(phong(20.0, DVec3::Z)).clusters()[0].bases[0].eval(DVec3::Z, DVec3::Z);
        let ct_tab = 0.2 * lobe_peaks(&ct, &d, &d).tabulated;
        assert!(
            pack_max <= (lamb_pole + ct_tab) * (1.0 + 1e-6),
            "{pack_max}"
        );
        assert!(
            pack_max >= lamb_pole.max(ct_tab) * (1.0 - 1e-6),
            "{pack_max}"
        );
        assert!(
            e.to_string()
                .starts_with("cluster 0 basis 1 (cook_torrance)"),
            "{e}"
        );
        // ...and within it at a fortieth of that weight.
        assert_eq!(check_lobes(&pack_weighted(ct, 0.005)), Ok(()));
    }
}
