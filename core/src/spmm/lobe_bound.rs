//! The lobe bound of fitted bases: a basis fitted to a BTF is known only at the BTF's
//! tabulated direction pairs, so it may not peak between them far above what it
//! takes there. Its peak over the measured range (both directions no lower than the
//! lowest tabulated polar angle of their set; dense sampling: a stratified grid of
//! light directions with views on a grid and at the mirror direction about the basis
//! normal, then a local search from the best samples) must stay within
//! `MAX_PEAK_RATIO` times its largest value at the tabulated pairs. A lobe sharper
//! than the angular spacing of the directions fails it (its peak falls between
//! tabulated pairs), and since the fitted sum matches the BTF at those pairs, its
//! weighted peak in the measured range stays within that multiple of the BTF's
//! maximum. The validator checks it on every pack with a residual (the residual's
//! direction sets are the BTF's); the fitter drops bases that break it.
//!
//! Below the measured range (towards the horizon) the bound does not hold and is not
//! checked: every microfacet basis grows without limit as light and view approach
//! opposite horizon directions (h -> n while cos_o -> 0 and G stays about 1/2, so
//! f cos_i ~ D F / (8 cos_o)); docs/fitting.md has the measured peaks.

use glam::DVec3;

use super::SpmmMaterial;
use crate::brdf::{BasisFunction, warp};

/// Largest allowed ratio of a basis's peak anywhere to its largest tabulated value.
pub const MAX_PEAK_RATIO: f64 = 4.0;

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

/// The peaks of `basis` over the measured range (dense sampling and local search) and
/// at the tabulated pairs `lights` x `views`.
pub fn lobe_peaks(basis: &BasisFunction, lights: &[DVec3], views: &[DVec3]) -> LobePeaks {
    let mut tabulated = 0.0f64;
    for &wi in lights {
        for &wo in views {
            tabulated = tabulated.max(basis.eval(wi, wo));
        }
    }
    let n = basis.frame().z;
    let (zi, zo) = (lowest(lights), lowest(views));
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
    LobePeaks {
        anywhere: peak.0.max(tabulated),
        tabulated,
        wi: peak.1,
        wo: peak.2,
    }
}

/// A basis breaking the lobe bound.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[error(
    "cluster {cluster} basis {basis} ({model}): peaks at {anywhere:.4e} between the tabulated directions (light {wi:?}, view {wo:?}), {ratio:.1}x its largest value {tabulated:.4e} at them; at most {MAX_PEAK_RATIO}x is allowed (a lobe sharper than the measured directions support)"
)]
pub struct LobeBoundError {
    pub cluster: usize,
    pub basis: usize,
    pub model: &'static str,
    pub anywhere: f64,
    pub tabulated: f64,
    pub ratio: f64,
    pub wi: [f64; 3],
    pub wo: [f64; 3],
}

/// Whether `basis` keeps within the bound on these direction sets.
pub fn within_bound(basis: &BasisFunction, lights: &[DVec3], views: &[DVec3]) -> bool {
    lobe_peaks(basis, lights, views).ratio() <= MAX_PEAK_RATIO
}

/// Checks every basis of a pack with a residual against the residual's direction
/// sets; packs without one (made by hand, not fitted) have no measured directions.
pub fn check_lobes(m: &SpmmMaterial) -> Result<(), LobeBoundError> {
    let Some(r) = m.residual() else {
        return Ok(());
    };
    for (cluster, c) in m.clusters().iter().enumerate() {
        for (basis, b) in c.bases.iter().enumerate() {
            let p = lobe_peaks(b, &r.light_dirs, &r.view_dirs);
            if p.ratio() > MAX_PEAK_RATIO {
                return Err(LobeBoundError {
                    cluster,
                    basis,
                    model: b.brdf().model().name(),
                    anywhere: p.anywhere,
                    tabulated: p.tabulated,
                    ratio: p.ratio(),
                    wi: p.wi.to_array(),
                    wo: p.wo.to_array(),
                });
            }
        }
    }
    Ok(())
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
                rgb: vec![[0.5; 3], [0.2; 3]],
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
        assert_eq!((e.cluster, e.basis, e.model), (0, 1, "blinn_phong"));
        assert!(e.ratio > MAX_PEAK_RATIO);
        assert!(
            e.to_string().starts_with("cluster 0 basis 1 (blinn_phong)"),
            "{e}"
        );
    }
}
