//! Importance sampling of a MERL table by tabulated distributions (the piecewise-
//! constant 2D sampling of pbrt-v3, section 13.6.7): per band of theta_o, a 2D density
//! over (cos theta_i, phi_i - phi_o) proportional to the table's luminance times
//! cos theta_i at the band's centre, plus a uniform floor so that the pdf is positive
//! wherever the BRDF is. No interpolation between bands.

use std::f64::consts::{FRAC_PI_2, PI};

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::MerlBrdf;
use crate::angle::atan2;
use crate::brdf::BrdfSample;

/// Bands of theta_o, uniform in angle (2 degrees each).
pub(crate) const WO_BANDS: usize = 45;
/// Rows uniform in cos(theta_i): equal solid angle, so the density is constant in a cell.
pub(crate) const Z_BINS: usize = 64;
/// Columns of phi_i - phi_o over [0, 2 pi).
pub(crate) const PHI_BINS: usize = 128;
/// Sub-samples per cell side when the table is averaged over a cell.
const SUB: usize = 2;
/// Share of a band's mass spread uniformly over the hemisphere: keeps the pdf
/// positive in cells where the band centre's view sees nothing but another view in
/// the band does, at the cost of 5% of samples drawn uniformly.
const FLOOR: f64 = 0.05;
/// Rec. 709 luminance weights.
const LUMINANCE: DVec3 = DVec3::new(0.2126, 0.7152, 0.0722);

/// The sampling tables of one MERL material (`MerlBrdf::sampler`).
#[derive(Clone, Debug)]
pub struct MerlSampler {
    /// Probability of each cell, [band][row][column], summing to 1 per band.
    cell_prob: Vec<f64>,
    /// Cumulative row probabilities, [band][Z_BINS + 1].
    row_cdf: Vec<f64>,
    /// Cumulative column probabilities within each row, [band][row][PHI_BINS + 1].
    col_cdf: Vec<f64>,
    /// Guide tables of the row CDFs ([band][Z_BINS]) and the column CDFs
    /// ([band][row][PHI_BINS]): `crate::cdf`.
    row_guide: Vec<u32>,
    col_guide: Vec<u32>,
}

/// Normalised cumulative sums of `w`, length w.len() + 1, ending at exactly 1;
/// uniform when `w` sums to 0.
fn cdf(w: &[f64]) -> Vec<f64> {
    let total: f64 = w.iter().sum();
    let mut out = Vec::with_capacity(w.len() + 1);
    out.push(0.0);
    let mut acc = 0.0;
    for (k, x) in w.iter().enumerate() {
        acc += x;
        out.push(if total > 0.0 {
            acc / total
        } else {
            (k + 1) as f64 / w.len() as f64
        });
    }
    *out.last_mut().expect("at least the leading 0") = 1.0;
    out
}

/// The bin of `cdf` holding `u` in [0, 1), found through its `guide`, and `u` rescaled
/// to [0, 1) inside it. Bins of zero mass are never chosen.
fn pick(cdf: &[f64], guide: &[u32], u: f64) -> (usize, f64) {
    let k = crate::cdf::find(cdf, guide, u);
    let width = cdf[k + 1] - cdf[k];
    let t = if width > 0.0 {
        ((u - cdf[k]) / width).clamp(0.0, 1.0)
    } else {
        0.5
    };
    (k, t)
}

fn band_of(wo: DVec3) -> usize {
    let theta_o = atan2((wo.x * wo.x + wo.y * wo.y).sqrt(), wo.z);
    ((theta_o / FRAC_PI_2 * WO_BANDS as f64) as usize).min(WO_BANDS - 1)
}

fn azimuth(w: DVec3) -> f64 {
    atan2(w.y, w.x)
}

const CELL_SOLID_ANGLE: f64 = 2.0 * PI / (Z_BINS * PHI_BINS) as f64;

impl MerlSampler {
    /// Bytes of the tables (the same for every table).
    pub fn full_bytes() -> usize {
        (WO_BANDS * Z_BINS * PHI_BINS
            + WO_BANDS * (Z_BINS + 1)
            + WO_BANDS * Z_BINS * (PHI_BINS + 1))
            * size_of::<f64>()
            + (WO_BANDS * Z_BINS + WO_BANDS * Z_BINS * PHI_BINS) * size_of::<u32>()
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        (self.cell_prob.len() + self.row_cdf.len() + self.col_cdf.len()) * size_of::<f64>()
            + (self.row_guide.len() + self.col_guide.len()) * size_of::<u32>()
    }

    pub fn new(brdf: &MerlBrdf) -> Self {
        let cells = Z_BINS * PHI_BINS;
        let bands: Vec<(Vec<f64>, Vec<f64>, Vec<f64>)> = (0..WO_BANDS)
            .into_par_iter()
            .map(|band| {
                let theta_o = (band as f64 + 0.5) / WO_BANDS as f64 * FRAC_PI_2;
                let wo = DVec3::new(theta_o.sin(), 0.0, theta_o.cos());
                let mut w = vec![0.0f64; cells];
                for row in 0..Z_BINS {
                    for col in 0..PHI_BINS {
                        let mut acc = 0.0;
                        for a in 0..SUB {
                            for b in 0..SUB {
                                let z =
                                    (row as f64 + (a as f64 + 0.5) / SUB as f64) / Z_BINS as f64;
                                let phi = (col as f64 + (b as f64 + 0.5) / SUB as f64)
                                    / PHI_BINS as f64
                                    * 2.0
                                    * PI;
                                let wi = crate::brdf::warp::spherical(z, phi);
                                acc += brdf.eval(wi, wo).dot(LUMINANCE) * z;
                            }
                        }
                        w[row * PHI_BINS + col] = acc;
                    }
                }
                let total: f64 = w.iter().sum();
                let floor = if total > 0.0 {
                    FLOOR * total / cells as f64
                } else {
                    1.0
                };
                w.iter_mut().for_each(|x| *x += floor);
                let total: f64 = w.iter().sum();
                let prob: Vec<f64> = w.iter().map(|x| x / total).collect();
                let row_mass: Vec<f64> = prob
                    .chunks_exact(PHI_BINS)
                    .map(|r| r.iter().sum())
                    .collect();
                let rows = cdf(&row_mass);
                let cols: Vec<f64> = prob.chunks_exact(PHI_BINS).flat_map(cdf).collect();
                (prob, rows, cols)
            })
            .collect();
        let mut s = Self {
            cell_prob: Vec::with_capacity(WO_BANDS * cells),
            row_cdf: Vec::with_capacity(WO_BANDS * (Z_BINS + 1)),
            col_cdf: Vec::with_capacity(WO_BANDS * Z_BINS * (PHI_BINS + 1)),
            row_guide: Vec::with_capacity(WO_BANDS * Z_BINS),
            col_guide: Vec::with_capacity(WO_BANDS * Z_BINS * PHI_BINS),
        };
        for (prob, rows, cols) in bands {
            crate::cdf::build_guide(&rows, Z_BINS, &mut s.row_guide);
            for row in cols.chunks_exact(PHI_BINS + 1) {
                crate::cdf::build_guide(row, PHI_BINS, &mut s.col_guide);
            }
            s.cell_prob.extend(prob);
            s.row_cdf.extend(rows);
            s.col_cdf.extend(cols);
        }
        s
    }

    /// Draws `wi` for `wo` (unit, local frame) from two uniform numbers in [0, 1).
    /// `None` when `wo` is at or below the horizon or the drawn direction lies on it.
    pub fn sample(&self, wo: DVec3, u: DVec2) -> Option<BrdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let band = band_of(wo);
        let rows = &self.row_cdf[band * (Z_BINS + 1)..(band + 1) * (Z_BINS + 1)];
        let (row, tz) = pick(
            rows,
            &self.row_guide[band * Z_BINS..(band + 1) * Z_BINS],
            u.x,
        );
        let line = band * Z_BINS + row;
        let cols_at = line * (PHI_BINS + 1);
        let (col, tp) = pick(
            &self.col_cdf[cols_at..cols_at + PHI_BINS + 1],
            &self.col_guide[line * PHI_BINS..(line + 1) * PHI_BINS],
            u.y,
        );
        let z = (row as f64 + tz) / Z_BINS as f64;
        if z <= 0.0 {
            return None;
        }
        let phi = (col as f64 + tp) / PHI_BINS as f64 * 2.0 * PI + azimuth(wo);
        let wi = crate::brdf::warp::spherical(z.min(1.0), phi);
        let pdf = self.cell_prob[(band * Z_BINS + row) * PHI_BINS + col] / CELL_SOLID_ANGLE;
        Some(BrdfSample { wi, pdf })
    }

    /// The tables as they are, for a device that samples with them (the GPU mode):
    /// each cell's probability [band][row][column], the row CDFs [band][Z_BINS + 1]
    /// and the column CDFs [band][row][PHI_BINS + 1].
    pub fn tables(&self) -> (&[f64], &[f64], &[f64]) {
        (&self.cell_prob, &self.row_cdf, &self.col_cdf)
    }

    /// Solid-angle density of `sample(wo, ·)` at `wi`; 0 below the horizon.
    pub fn pdf(&self, wo: DVec3, wi: DVec3) -> f64 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let band = band_of(wo);
        let row = ((wi.z * Z_BINS as f64) as usize).min(Z_BINS - 1);
        let phi = (azimuth(wi) - azimuth(wo)).rem_euclid(2.0 * PI);
        let col = ((phi / (2.0 * PI) * PHI_BINS as f64) as usize).min(PHI_BINS - 1);
        self.cell_prob[(band * Z_BINS + row) * PHI_BINS + col] / CELL_SOLID_ANGLE
    }
}

impl MerlBrdf {
    /// Draws `wi` for `wo` with density `pdf(wo, wi)` (`MerlSampler::sample`).
    pub fn sample(&self, wo: DVec3, u: DVec2) -> Option<BrdfSample> {
        self.sampler().sample(wo, u)
    }

    /// Solid-angle density with which `sample(wo, ·)` returns `wi`.
    pub fn pdf(&self, wo: DVec3, wi: DVec3) -> f64 {
        self.sampler().pdf(wo, wi)
    }
}
