//! The area-preserving grid of local directions over a hemisphere (Sun et al. 2010,
//! section 6.1.1, after Shirley and Chiu's concentric map): the unit square maps to the
//! disk by concentric squares, the disk to the upper hemisphere (z > 0) by
//! z = 1 - r^2, (x, y) scaled by sqrt(2 - r^2). Both steps preserve area, so the
//! `res` x `res` cells of the square are cells of equal solid angle 2 pi / res^2. Used
//! for the M local incident directions and for the tabulated view directions.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use glam::{DVec2, DVec3};

/// The square [0, 1]^2 to the upper hemisphere (unit vector, z >= 0).
pub fn square_to_hemisphere(s: DVec2) -> DVec3 {
    let (a, b) = (2.0 * s.x - 1.0, 2.0 * s.y - 1.0);
    if a == 0.0 && b == 0.0 {
        return DVec3::Z;
    }
    let (r, phi) = if a.abs() > b.abs() {
        (a, FRAC_PI_4 * (b / a))
    } else {
        (b, FRAC_PI_2 - FRAC_PI_4 * (a / b))
    };
    let (x, y) = (r * phi.cos(), r * phi.sin());
    let r2 = r * r;
    let k = (2.0 - r2).max(0.0).sqrt();
    DVec3::new(x * k, y * k, 1.0 - r2)
}

/// The inverse of `square_to_hemisphere` for a unit vector; a direction below the
/// horizon is first lifted onto it (z = 0, same azimuth).
pub fn hemisphere_to_square(d: DVec3) -> DVec2 {
    let z = d.z.clamp(0.0, 1.0);
    let r = (1.0 - z).sqrt();
    let phi = d.y.atan2(d.x);
    if r == 0.0 {
        return DVec2::splat(0.5);
    }
    let (a, b) = if (-FRAC_PI_4..=FRAC_PI_4).contains(&phi) {
        (r, r * phi / FRAC_PI_4)
    } else if phi > FRAC_PI_4 && phi <= 3.0 * FRAC_PI_4 {
        (r * (FRAC_PI_2 - phi) / FRAC_PI_4, r)
    } else if (-3.0 * FRAC_PI_4..-FRAC_PI_4).contains(&phi) {
        (r * (FRAC_PI_2 + phi) / FRAC_PI_4, -r)
    } else if phi > 0.0 {
        (-r, -r * (phi - PI) / FRAC_PI_4)
    } else {
        (-r, -r * (phi + PI) / FRAC_PI_4)
    };
    DVec2::new(
        ((a + 1.0) * 0.5).clamp(0.0, 1.0),
        ((b + 1.0) * 0.5).clamp(0.0, 1.0),
    )
}

/// `res` x `res` equal-area cells over the hemisphere; cell `m = iy * res + ix`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HemisphereGrid {
    pub res: u32,
}

impl HemisphereGrid {
    pub fn new(res: u32) -> Self {
        assert!(res > 0, "a grid has at least one cell");
        Self { res }
    }

    pub fn len(&self) -> usize {
        (self.res * self.res) as usize
    }

    pub fn is_empty(&self) -> bool {
        false
    }

    /// Solid angle of every cell.
    pub fn cell_solid_angle(&self) -> f64 {
        2.0 * PI / self.len() as f64
    }

    /// The cell a local direction falls in (below the horizon: lifted onto it). This
    /// is the binning rule of the transfer: an environment pixel's visible fraction
    /// goes to the cell that contains its centre direction.
    pub fn cell_of(&self, d: DVec3) -> usize {
        let s = hemisphere_to_square(d);
        let n = self.res as f64;
        let ix = ((s.x * n) as u32).min(self.res - 1);
        let iy = ((s.y * n) as u32).min(self.res - 1);
        (iy * self.res + ix) as usize
    }

    /// The direction at the centre of cell `m`.
    pub fn centre(&self, m: usize) -> DVec3 {
        self.at(m, DVec2::splat(0.5))
    }

    /// The direction at offset `f` in [0, 1]^2 inside cell `m`.
    pub fn at(&self, m: usize, f: DVec2) -> DVec3 {
        let (ix, iy) = (m as u32 % self.res, m as u32 / self.res);
        let n = self.res as f64;
        square_to_hemisphere(DVec2::new((ix as f64 + f.x) / n, (iy as f64 + f.y) / n))
    }

    /// `k` x `k` stratified directions (sub-cell centres) of cell `m`, for cell averages.
    pub fn strata(&self, m: usize, k: u32) -> impl Iterator<Item = DVec3> + '_ {
        (0..k * k).map(move |i| {
            let f = DVec2::new(
                ((i % k) as f64 + 0.5) / k as f64,
                ((i / k) as f64 + 0.5) / k as f64,
            );
            self.at(m, f)
        })
    }

    /// Bilinear weights of a direction over the cell centres (clamped at the border of
    /// the square): four (cell, weight) pairs summing to one.
    pub fn bilinear(&self, d: DVec3) -> [(usize, f32); 4] {
        let s = hemisphere_to_square(d);
        let n = self.res as f64;
        let (fx, fy) = (
            (s.x * n - 0.5).clamp(0.0, n - 1.0),
            (s.y * n - 0.5).clamp(0.0, n - 1.0),
        );
        let (x0, y0) = (
            (fx.floor() as u32).min(self.res - 1),
            (fy.floor() as u32).min(self.res - 1),
        );
        let (x1, y1) = ((x0 + 1).min(self.res - 1), (y0 + 1).min(self.res - 1));
        let (tx, ty) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
        let c = |x: u32, y: u32| (y * self.res + x) as usize;
        [
            (c(x0, y0), (1.0 - tx) * (1.0 - ty)),
            (c(x1, y0), tx * (1.0 - ty)),
            (c(x0, y1), (1.0 - tx) * ty),
            (c(x1, y1), tx * ty),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::rng::SampleStream;

    #[test]
    fn the_map_round_trips_and_stays_on_the_hemisphere() {
        let rng = SampleStream::new(&[3]);
        for i in 0..10_000 {
            let s = DVec2::new(rng.at(2 * i), rng.at(2 * i + 1));
            let d = square_to_hemisphere(s);
            assert!((d.length() - 1.0).abs() < 1e-12 && d.z >= 0.0, "{s} {d}");
            let back = hemisphere_to_square(d);
            assert!((back - s).length() < 1e-9, "{s} -> {d} -> {back}");
        }
    }

    #[test]
    fn cells_have_equal_solid_angle() {
        // Uniform directions over the hemisphere (z uniform, phi uniform) land in every
        // cell equally often when the map preserves area.
        let grid = HemisphereGrid::new(8);
        let rng = SampleStream::new(&[5]);
        let n = 640_000;
        let mut counts = vec![0u32; grid.len()];
        for i in 0..n {
            let z = rng.at(2 * i);
            let phi = 2.0 * PI * rng.at(2 * i + 1);
            let r = (1.0 - z * z).sqrt();
            counts[grid.cell_of(DVec3::new(r * phi.cos(), r * phi.sin(), z))] += 1;
        }
        let expected = n as f64 / grid.len() as f64;
        for (m, &c) in counts.iter().enumerate() {
            // 10,000 expected per cell: 5 sigma is 500.
            assert!((c as f64 - expected).abs() < 500.0, "cell {m}: {c}");
        }
    }

    #[test]
    fn a_cell_contains_its_own_directions() {
        let grid = HemisphereGrid::new(12);
        for m in 0..grid.len() {
            for d in grid.strata(m, 3) {
                assert_eq!(grid.cell_of(d), m);
            }
            let w: f32 = grid.bilinear(grid.centre(m)).iter().map(|p| p.1).sum();
            assert!((w - 1.0).abs() < 1e-6);
        }
    }
}
