//! Importance sampling of a `btf` table's light directions for a view: what the
//! ambient term, the environment's material samples and their MIS weights draw from.
//!
//! Per tabulated view direction, a piecewise-constant distribution over a fixed grid
//! of the upper hemisphere (`RINGS` rings uniform in r = sqrt(1 - cos theta), which
//! is the equal-area disk's radius, so rings are finer near the pole and the horizon
//! than uniform cos theta rings would be; `SECTORS` equal azimuth sectors in the
//! tangent frame, since a BTF need not be isotropic), each cell's probability in
//! proportion to the table's texel-mean luminance there (interpolated over the light
//! set as the table shades, at 2 x 2 points per cell) times the cell's solid angle.
//! A query's view mixes the distributions of the (up to three) tabulated views its
//! interpolation weights name, with those weights, so the lobe moves smoothly with
//! the view. `BtfTable` adds the defensive share of the half-cosine, half-uniform
//! mixture (`spmm::DEFENSIVE_SHARE`), which bounds BTF / pdf at texels whose lobe
//! differs from the mean and where the grid's constant cells miss a peak.
//!
//! The texel mean is summed while a table's values are first read (`PairSums`), so an
//! out-of-core table costs no second pass over its file.

use std::f64::consts::TAU;

use glam::{DVec2, DVec3};

use crate::image::luminance;
use crate::spmm::directions::DirectionTable;

/// Rings of the grid, uniform in r = sqrt(1 - cos theta).
pub const RINGS: usize = 16;
/// Azimuth sectors of the grid, over [0, 2 pi) from the tangent.
pub const SECTORS: usize = 32;
/// Cells per view: ring-major, `ring * SECTORS + sector`.
pub const CELLS: usize = RINGS * SECTORS;

/// Per (light, view) pair, the sum over texels of the value's luminance: the table's
/// texel-mean lobe up to a factor, added block by block as the values are read.
pub(super) struct PairSums {
    sums: Vec<f64>,
}

impl PairSums {
    pub(super) fn new(pairs: usize) -> Self {
        Self {
            sums: vec![0.0; pairs],
        }
    }

    /// Adds whole texels' values (`[texel][light][view][rgb]`).
    pub(super) fn add(&mut self, texels: &[f32]) {
        let per_texel = self.sums.len() * 3;
        for texel in texels.chunks_exact(per_texel) {
            for (sum, rgb) in self.sums.iter_mut().zip(texel.chunks_exact(3)) {
                *sum += f64::from(luminance([rgb[0], rgb[1], rgb[2]]));
            }
        }
    }
}

/// The cos theta bounds (upper, lower) of ring `ring`.
fn ring_z(ring: usize) -> (f64, f64) {
    let r = |k: usize| k as f64 / RINGS as f64;
    (1.0 - r(ring) * r(ring), 1.0 - r(ring + 1) * r(ring + 1))
}

/// Solid angle of a cell of ring `ring`.
fn cell_solid_angle(ring: usize) -> f64 {
    let (top, bottom) = ring_z(ring);
    (top - bottom) * TAU / SECTORS as f64
}

/// The unit direction at cos theta `z` and azimuth `phi`.
fn direction(z: f64, phi: f64) -> DVec3 {
    let s = (1.0 - z * z).max(0.0).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// The cell holding `li` (above the surface).
fn cell_of(li: DVec3) -> usize {
    let r = (1.0 - li.z).max(0.0).sqrt();
    let ring = ((r * RINGS as f64) as usize).min(RINGS - 1);
    let phi = li.y.atan2(li.x).rem_euclid(TAU);
    let sector = ((phi / TAU * SECTORS as f64) as usize).min(SECTORS - 1);
    ring * SECTORS + sector
}

/// The per-view cell distributions of one table.
#[derive(Clone, Debug)]
pub struct LobeSampler {
    /// Per view, `CELLS + 1` cumulative probabilities (0 first, 1 last), f32 as a
    /// device holds them, so both draw from the same table.
    cdfs: Vec<f32>,
}

impl LobeSampler {
    /// The distributions of a table with light set `lights` and `views` view
    /// directions whose texel sums are `sums` (`[light][view]`). A view whose lobe
    /// sums to nothing gets cells in proportion to their solid angle.
    pub(super) fn new(lights: &DirectionTable, views: usize, sums: &PairSums) -> Self {
        // The light interpolation at each cell's 2 x 2 points, shared by every view.
        let points: Vec<[(u32, f64); 3]> = (0..CELLS)
            .flat_map(|cell| {
                let (ring, sector) = (cell / SECTORS, cell % SECTORS);
                let (top, bottom) = ring_z(ring);
                (0..4).map(move |k| {
                    let z = top + (bottom - top) * (0.25 + 0.5 * (k / 2) as f64);
                    let phi = (sector as f64 + 0.25 + 0.5 * (k % 2) as f64) * TAU / SECTORS as f64;
                    lights.cosine_weights(direction(z, phi))
                })
            })
            .collect();
        let mut cdfs = Vec::with_capacity(views * (CELLS + 1));
        let mut mass = vec![0.0f64; CELLS];
        for v in 0..views {
            for (cell, m) in mass.iter_mut().enumerate() {
                let lobe: f64 = points[cell * 4..][..4]
                    .iter()
                    .map(|weights| {
                        let value: f64 = weights
                            .iter()
                            .map(|&(l, w)| w * sums.sums[l as usize * views + v])
                            .sum();
                        value.max(0.0)
                    })
                    .sum();
                *m = lobe * cell_solid_angle(cell / SECTORS);
            }
            let total: f64 = mass.iter().sum();
            if !(total > 0.0 && total.is_finite()) {
                for (cell, m) in mass.iter_mut().enumerate() {
                    *m = cell_solid_angle(cell / SECTORS);
                }
            }
            let total: f64 = mass.iter().sum();
            cdfs.push(0.0);
            let mut running = 0.0;
            for m in &mass[..CELLS - 1] {
                running += m;
                cdfs.push((running / total) as f32);
            }
            cdfs.push(1.0);
        }
        Self { cdfs }
    }

    /// The cumulative probabilities, `CELLS + 1` per view (for a device).
    pub fn cdfs(&self) -> &[f32] {
        &self.cdfs
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.cdfs.len() * 4
    }

    fn cell_probability(&self, view: u32, cell: usize) -> f64 {
        let at = view as usize * (CELLS + 1) + cell;
        f64::from(self.cdfs[at + 1]) - f64::from(self.cdfs[at])
    }

    /// The solid-angle pdf of light direction `li` for a view with interpolation
    /// weights `view_weights` (0 below the surface).
    pub fn pdf(&self, view_weights: [(u32, f64); 3], li: DVec3) -> f64 {
        if li.z.is_nan() || li.z <= 0.0 {
            return 0.0;
        }
        let cell = cell_of(li);
        let p: f64 = view_weights
            .iter()
            .filter(|&&(_, w)| w > 0.0)
            .map(|&(v, w)| w * self.cell_probability(v, cell))
            .sum();
        p / cell_solid_angle(cell / SECTORS)
    }

    /// A light direction for a view with interpolation weights `view_weights`, from
    /// two uniform numbers: the first picks the view (by weight), then the cell (by
    /// the view's CDF) and, rescaled, cos theta within it; the second the azimuth.
    /// `None` for a direction on the horizon.
    pub fn sample(&self, view_weights: [(u32, f64); 3], u: DVec2) -> Option<DVec3> {
        let mut x = u.x;
        let mut view = None;
        for &(v, w) in view_weights.iter().filter(|&&(_, w)| w > 0.0) {
            view = Some(v);
            if x < w {
                x /= w;
                break;
            }
            x -= w;
        }
        // Past the weights' rounded sum: the last view, at its top.
        let x = x.min(1.0 - f64::EPSILON);
        let cdf = &self.cdfs[view? as usize * (CELLS + 1)..][..CELLS + 1];
        let cell = cdf[1..]
            .partition_point(|&c| f64::from(c) <= x)
            .min(CELLS - 1);
        let (c0, c1) = (f64::from(cdf[cell]), f64::from(cdf[cell + 1]));
        let t = if c1 > c0 {
            ((x - c0) / (c1 - c0)).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let (ring, sector) = (cell / SECTORS, cell % SECTORS);
        let (top, bottom) = ring_z(ring);
        let z = top + (bottom - top) * t;
        let phi = (sector as f64 + u.y) * TAU / SECTORS as f64;
        (z > 0.0).then(|| direction(z, phi))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::btf::Btf;
    use crate::btf::directions::{bonn81, from_angles_deg};
    use crate::btf::table::BtfTable;
    use crate::rng::SampleStream;
    use crate::spmm::{defensive_pdf, defensive_sample};

    /// A 1 x 1 table of `brdf` on the Bonn 81 directions.
    fn table(brdf: &AnalyticBrdf) -> BtfTable {
        let dirs = bonn81();
        let btf = Btf::from_brdf(brdf, DVec3::new(0.8, 0.6, 0.4), 1, 1, dirs.clone(), dirs)
            .expect("valid BTF");
        BtfTable::new(&btf).expect("shadeable")
    }

    fn glossy_tables() -> Vec<(&'static str, BtfTable)> {
        let ct =
            AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.3), ("f0", 0.04)]).expect("valid");
        let ward =
            AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.15), ("ay", 0.45)]).expect("valid");
        vec![
            ("cook-torrance m 0.3", table(&ct)),
            ("ward 0.15 x 0.45", table(&ward)),
        ]
    }

    /// Views at the pole, between rings, on the outermost ring and beyond it (outside
    /// the set's hull: the nearest hull point's weights).
    fn views() -> Vec<DVec3> {
        [(0.0, 0.0), (37.0, 20.0), (75.0, 200.0), (84.0, 133.0)]
            .iter()
            .map(|&(t, p)| from_angles_deg(t, p))
            .collect()
    }

    /// The pdf integrates to 1 over the hemisphere (midpoint rule, uniform in cos
    /// theta and azimuth, 400 x 800 points) for every view, including the defensive
    /// share: a lobe's cells weighed by a wrong solid angle would not.
    #[test]
    fn the_pdf_integrates_to_one() {
        let (nz, nphi) = (400, 800);
        let cell = TAU / (nz * nphi) as f64;
        for (name, table) in glossy_tables() {
            for wo in views() {
                let mut total = 0.0;
                for i in 0..nz {
                    for j in 0..nphi {
                        let z = (i as f64 + 0.5) / nz as f64;
                        let phi = (j as f64 + 0.5) / nphi as f64 * TAU;
                        total += table.pdf(direction(z, phi), wo) * cell;
                    }
                }
                assert!((total - 1.0).abs() < 2e-3, "{name} at {wo}: {total}");
            }
        }
    }

    /// Drawn directions follow the stated pdf: over 8 regions of the hemisphere (two
    /// bands of cos theta by four azimuth quadrants), the mean of 1_R / pdf over
    /// 100,000 draws is the region's solid angle pi / 4, within 4 standard errors.
    #[test]
    fn draws_follow_the_pdf() {
        for (name, table) in glossy_tables() {
            for wo in views() {
                let n = 100_000;
                let mut rng = SampleStream::new(&[7, (wo.z * 1e6) as u64]);
                let mut sums = [0.0f64; 8];
                let mut squares = [0.0f64; 8];
                for _ in 0..n {
                    let u = DVec2::new(rng.next(), rng.next());
                    let Some((wi, pdf)) = table.sample(wo, u) else {
                        continue;
                    };
                    assert!(wi.z > 0.0 && (wi.length() - 1.0).abs() < 1e-9, "{wi}");
                    assert!((pdf - table.pdf(wi, wo)).abs() <= 1e-12 * pdf, "{name}");
                    let quadrant = (wi.y.atan2(wi.x).rem_euclid(TAU) / (TAU / 4.0)) as usize;
                    let region = quadrant.min(3) * 2 + usize::from(wi.z < 0.5);
                    sums[region] += 1.0 / pdf;
                    squares[region] += 1.0 / (pdf * pdf);
                }
                for r in 0..8 {
                    let mean = sums[r] / n as f64;
                    let var = squares[r] / n as f64 - mean * mean;
                    let err = (var / n as f64).sqrt();
                    let want = TAU / 8.0;
                    assert!(
                        (mean - want).abs() < 4.0 * err + 1e-9,
                        "{name} at {wo}, region {r}: {mean} +- {err} against {want}"
                    );
                }
            }
        }
    }

    /// The lobe makes the unoccluded ambient estimate (BTF / pdf) far less noisy than
    /// the defensive mixture alone, the sampling tables had before, with the same
    /// mean: per-sample variance over 200,000 draws at each view.
    #[test]
    fn the_lobe_lowers_the_ambient_estimates_variance() {
        for (name, table) in glossy_tables() {
            for wo in views() {
                let n = 200_000;
                let mut rng = SampleStream::new(&[11, (wo.x * 1e6) as u64]);
                let (mut lobe, mut defensive) = (Vec::new(), Vec::new());
                for _ in 0..n {
                    let u = DVec2::new(rng.next(), rng.next());
                    lobe.push(
                        table
                            .sample(wo, u)
                            .map_or(0.0, |(wi, pdf)| table.eval_texel(0, wi, wo).y / pdf),
                    );
                    let wi = defensive_sample(u);
                    defensive.push(table.eval_texel(0, wi, wo).y / defensive_pdf(wi));
                }
                let stats = |v: &[f64]| {
                    let mean = v.iter().sum::<f64>() / v.len() as f64;
                    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64;
                    (mean, var)
                };
                let ((m1, v1), (m0, v0)) = (stats(&lobe), stats(&defensive));
                let err = ((v1 + v0) / n as f64).sqrt();
                eprintln!(
                    "{name} at {wo}: mean {m1:.4} / {m0:.4}, variance ratio {:.3}",
                    v1 / v0
                );
                assert!(
                    (m1 - m0).abs() < 4.0 * err,
                    "{name} at {wo}: {m1} against {m0}"
                );
                assert!(v1 < 0.1 * v0, "{name} at {wo}: variance {v1} against {v0}");
            }
        }
    }

    #[test]
    fn cells_tile_the_hemisphere() {
        let total: f64 = (0..RINGS)
            .map(|r| cell_solid_angle(r) * SECTORS as f64)
            .sum();
        assert!((total - TAU).abs() < 1e-12, "{total}");
        // The cell of a cell's own centre is that cell.
        for cell in 0..CELLS {
            let (ring, sector) = (cell / SECTORS, cell % SECTORS);
            let (top, bottom) = ring_z(ring);
            let d = direction(
                0.5 * (top + bottom),
                (sector as f64 + 0.5) * TAU / SECTORS as f64,
            );
            assert_eq!(cell_of(d), cell);
        }
    }
}
