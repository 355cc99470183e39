//! The half/difference parametrisation of Rusinkiewicz 1998 as the MERL reference
//! reader (`BRDFRead.cpp`, Matusik et al. 2003) indexes it, and the table lookups: the
//! reference's nearest cell, and a trilinear interpolation over the same bin centres.
//! The angles are computed from wi + wo and wi - wo, which makes every lookup exactly
//! reciprocal; the reference's rotations agree with them except on bin edges.

use std::f64::consts::{FRAC_PI_2, PI};

use glam::DVec3;

use crate::angle::atan2;

use super::{MerlBrdf, PHI_D_RES, SCALE, THETA_D_RES, THETA_H_RES, cell_index};

/// The isotropic Rusinkiewicz coordinates of a pair of directions: theta_h in
/// [0, pi/2] (half vector from the normal), theta_d in [0, pi/2] (wi from the half
/// vector), phi_d in [0, pi) (the difference azimuth folded by reciprocity, phi_d and
/// phi_d + pi being the same pair with wi and wo exchanged).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfDiff {
    pub theta_h: f64,
    pub theta_d: f64,
    pub phi_d: f64,
}

impl HalfDiff {
    /// The coordinates of unit directions `wi`, `wo` (local frame, z = normal), both
    /// above the horizon. Symmetric bit for bit: exchanging `wi` and `wo` negates
    /// wi - wo exactly, and the fold below maps both signs to the same numbers.
    #[inline]
    pub fn from_directions(wi: DVec3, wo: DVec3) -> Self {
        let s = wi + wo; // 2 cos(theta_d) h
        let d = wi - wo; // 2 sin(theta_d) times the difference vector's tangential part
        let s_len = s.length();
        let s_xy = (s.x * s.x + s.y * s.y).sqrt();
        // atan2 forms stay accurate where acos of a cosine near 1 would not (the fast
        // one: within 2e-13 rad, `angle`).
        let theta_h = atan2(s_xy, s.z);
        let theta_d = atan2(d.length(), s_len);
        // Rotate d into the half vector's frame: by -phi_h about z, then by -theta_h
        // about y (the reference's `rotate_vector` calls), keeping x and y.
        let (cos_ph, sin_ph) = if s_xy > 0.0 {
            (s.x / s_xy, s.y / s_xy)
        } else {
            (1.0, 0.0)
        };
        let (cos_th, sin_th) = (s.z / s_len, s_xy / s_len);
        let mut x = cos_th * (cos_ph * d.x + sin_ph * d.y) - sin_th * d.z;
        let mut y = cos_ph * d.y - sin_ph * d.x;
        // Fold phi_d into [0, pi): (x, y) and (-x, -y) are the same cell.
        if y < 0.0 || (y == 0.0 && x < 0.0) {
            x = -x;
            y = -y;
        }
        let phi_d = atan2(y.abs(), x);
        Self {
            theta_h,
            theta_d,
            phi_d,
        }
    }

    /// The centre of a cell: the middle of its bin in each index, through the inverse
    /// of each index map (theta_h = (i + 1/2)^2 / 90^2 * pi/2 for the square-root one).
    pub fn bin_centre(theta_h_index: usize, theta_d_index: usize, phi_d_index: usize) -> Self {
        let t = (theta_h_index as f64 + 0.5) / THETA_H_RES as f64;
        Self {
            theta_h: t * t * FRAC_PI_2,
            theta_d: (theta_d_index as f64 + 0.5) / THETA_D_RES as f64 * FRAC_PI_2,
            phi_d: (phi_d_index as f64 + 0.5) / PHI_D_RES as f64 * PI,
        }
    }

    /// A pair of directions with these coordinates and the half vector at azimuth
    /// `phi_h`: the inverse rotations of `from_directions`. Either may lie below the
    /// horizon (where theta_h + theta_d > pi/2 allows it).
    pub fn to_directions(&self, phi_h: f64) -> (DVec3, DVec3) {
        let (sin_td, cos_td) = self.theta_d.sin_cos();
        let (sin_pd, cos_pd) = self.phi_d.sin_cos();
        let (sin_th, cos_th) = self.theta_h.sin_cos();
        let (sin_ph, cos_ph) = phi_h.sin_cos();
        let to_world = |d: DVec3| {
            let x = cos_th * d.x + sin_th * d.z;
            let z = cos_th * d.z - sin_th * d.x;
            DVec3::new(cos_ph * x - sin_ph * d.y, sin_ph * x + cos_ph * d.y, z)
        };
        let d = DVec3::new(sin_td * cos_pd, sin_td * sin_pd, cos_td);
        (to_world(d), to_world(DVec3::new(-d.x, -d.y, d.z)))
    }

    /// The reference reader's indices: theta_h by floor(sqrt(theta_h / (pi/2)) * 90),
    /// theta_d and phi_d linearly, each clamped to its range.
    #[inline]
    pub fn indices(&self) -> (usize, usize, usize) {
        // `as usize` saturates: negatives (and NaN) go to 0.
        let th = ((self.theta_h / FRAC_PI_2).max(0.0).sqrt() * THETA_H_RES as f64) as usize;
        let td = (self.theta_d / FRAC_PI_2 * THETA_D_RES as f64) as usize;
        let pd = (self.phi_d / PI * PHI_D_RES as f64) as usize;
        (
            th.min(THETA_H_RES - 1),
            td.min(THETA_D_RES - 1),
            pd.min(PHI_D_RES - 1),
        )
    }

    /// The nearest cell, `cell_index` of `indices`.
    #[inline]
    pub fn cell(&self) -> usize {
        let (th, td, pd) = self.indices();
        cell_index(th, td, pd)
    }

    /// Continuous index coordinates, with the bin centres at integers.
    fn continuous(&self) -> [f64; 3] {
        [
            (self.theta_h / FRAC_PI_2).max(0.0).sqrt() * THETA_H_RES as f64 - 0.5,
            self.theta_d / FRAC_PI_2 * THETA_D_RES as f64 - 0.5,
            self.phi_d / PI * PHI_D_RES as f64 - 0.5,
        ]
    }
}

/// The two neighbouring bins of a continuous coordinate and the weight of the upper,
/// clamped at the ends (theta) or wrapped (phi_d, periodic with period pi).
fn neighbours(c: f64, res: usize, periodic: bool) -> ([usize; 2], f64) {
    let lo = c.floor();
    let t = c - lo;
    let lo = lo as i64;
    let pick = |i: i64| {
        if periodic {
            i.rem_euclid(res as i64) as usize
        } else {
            i.clamp(0, res as i64 - 1) as usize
        }
    };
    ([pick(lo), pick(lo + 1)], t)
}

impl MerlBrdf {
    /// f(wi, wo) in 1/sr per channel, as the reference reader looks the table up: the
    /// cell that holds the pair's half/difference angles. 0 when either direction is
    /// at or below the horizon, and in channels where the cell has no data. `wi`, `wo`
    /// unit vectors in the local frame (z = normal).
    #[inline]
    pub fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        self.cell_value(HalfDiff::from_directions(wi, wo).cell())
    }

    /// f(wi, wo) interpolated trilinearly between the centres of the eight cells around
    /// the pair (theta_h in its square-root index, phi_d periodic). Cells without data
    /// are left out and the other weights renormalised per channel, so an edge of the
    /// measured region is not darkened; equal to `eval` at every bin centre.
    pub fn eval_trilinear(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let [ch, cd, cp] = HalfDiff::from_directions(wi, wo).continuous();
        let (ih, th) = neighbours(ch, THETA_H_RES, false);
        let (id, td) = neighbours(cd, THETA_D_RES, false);
        let (ip, tp) = neighbours(cp, PHI_D_RES, true);
        let mut sum = [0.0f64; 3];
        let mut weight = [0.0f64; 3];
        for (a, wa) in ih.into_iter().zip([1.0 - th, th]) {
            for (b, wb) in id.into_iter().zip([1.0 - td, td]) {
                for (c, wc) in ip.into_iter().zip([1.0 - tp, tp]) {
                    let w = wa * wb * wc;
                    if w == 0.0 {
                        continue;
                    }
                    let s = self.stored()[cell_index(a, b, c)];
                    for k in 0..3 {
                        if s[k] >= 0.0 {
                            sum[k] += w * s[k];
                            weight[k] += w;
                        }
                    }
                }
            }
        }
        let value = |k: usize| {
            if weight[k] > 0.0 {
                (sum[k] / weight[k] * SCALE[k]).max(0.0)
            } else {
                0.0
            }
        };
        DVec3::new(value(0), value(1), value(2))
    }
}
