//! An analytic BRDF of the dictionary written out as a MERL table: each cell holds the
//! model at its bin centre (`HalfDiff::bin_centre`) times the albedo, divided by the
//! channel's scale. The format is isotropic, so anisotropic models are sampled with
//! the half vector in the x-z plane (phi_h = 0); nothing averages over phi_h.

use std::f64::consts::{FRAC_PI_2, PI};

use glam::DVec3;
use rayon::prelude::*;

use super::{
    CELLS, HalfDiff, MerlBrdf, MerlError, MerlFault, PHI_D_RES, SCALE, THETA_D_RES, THETA_H_RES,
    cell_indices,
};
use crate::brdf::AnalyticBrdf;

/// What a cell that no pair of directions above the horizon can reach holds: no data.
const NO_DATA: f64 = -1.0;

fn above(hd: &HalfDiff) -> bool {
    let (wi, wo) = hd.to_directions(0.0);
    wi.z > 0.0 && wo.z > 0.0
}

/// The lower edge of each bin and the point of the phi_d bin nearest pi/2.
fn most_open_corner(th: usize, td: usize, pd: usize) -> HalfDiff {
    let t = th as f64 / THETA_H_RES as f64;
    let (p0, p1) = (
        pd as f64 / PHI_D_RES as f64 * PI,
        (pd + 1) as f64 / PHI_D_RES as f64 * PI,
    );
    HalfDiff {
        theta_h: t * t * FRAC_PI_2,
        theta_d: td as f64 / THETA_D_RES as f64 * FRAC_PI_2,
        phi_d: FRAC_PI_2.clamp(p0, p1),
    }
}

fn lerp(a: &HalfDiff, b: &HalfDiff, t: f64) -> HalfDiff {
    HalfDiff {
        theta_h: a.theta_h + t * (b.theta_h - a.theta_h),
        theta_d: a.theta_d + t * (b.theta_d - a.theta_d),
        phi_d: a.phi_d + t * (b.phi_d - a.phi_d),
    }
}

/// Where a cell is evaluated: its centre when both directions lie above the horizon
/// there; otherwise a point of the cell that does, or `None` when no point does.
///
/// Both directions lie above the horizon exactly when tan(theta_h) tan(theta_d)
/// |cos(phi_d)| < 1, which shrinks as each angle moves towards the cell's lower
/// theta edges and phi_d towards pi/2. So a cell straddling the horizon holds valid
/// pairs if and only if that corner is one, and along the segment from the centre to
/// the corner validity is monotone: bisection finds where it starts, and the cell is
/// evaluated halfway between there and the corner, clear of the grazing limit.
fn evaluation_point(cell: usize) -> Option<HalfDiff> {
    let (th, td, pd) = cell_indices(cell);
    let centre = HalfDiff::bin_centre(th, td, pd);
    if above(&centre) {
        return Some(centre);
    }
    let corner = most_open_corner(th, td, pd);
    if !above(&corner) {
        return None;
    }
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if above(&lerp(&centre, &corner, mid)) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let point = lerp(&centre, &corner, 0.5 * (hi + 1.0));
    Some(if above(&point) { point } else { corner })
}

/// The MERL table of `albedo` times `brdf`: cell value = albedo * f at the cell's
/// evaluation point, stored as value / `SCALE`. Cells that no pair above the horizon
/// reaches hold no data (-1). `albedo` must be finite and non-negative.
pub fn tabulate(brdf: &AnalyticBrdf, albedo: DVec3) -> Result<MerlBrdf, MerlError> {
    if !albedo.is_finite() || albedo.min_element() < 0.0 {
        return Err(MerlFault::Albedo {
            albedo: albedo.to_array(),
        }
        .into());
    }
    let stored: Vec<[f64; 3]> = (0..CELLS)
        .into_par_iter()
        .map(|cell| match evaluation_point(cell) {
            Some(hd) => {
                let (wi, wo) = hd.to_directions(0.0);
                let f = brdf.eval(wi, wo);
                [0, 1, 2].map(|c| albedo[c] * f / SCALE[c])
            }
            None => [NO_DATA; 3],
        })
        .collect();
    MerlBrdf::from_stored(stored)
}
