//! The tiled height field a synthesis ray traces: bilinear heights and normals, region
//! lookup, and the ray marching of view, shadow and gather rays. Its own module because
//! it is the geometry, apart from how a recipe builds it and how the hits are shaded.

use glam::{DVec2, DVec3};

/// A tiled height field over the patch: `grid_w x grid_h` samples, sample (i, j) at
/// x = (i + 0.5) / detail, y = (j + 0.5) / detail in texel widths (x right, y up: j = 0
/// is the bottom row of the patch), heights in texel widths.
#[derive(Clone, Debug)]
pub struct HeightField {
    pub grid_w: usize,
    pub grid_h: usize,
    pub detail: f64,
    pub heights: Vec<f64>,
    pub regions: Vec<u8>,
    pub(super) h_min: f64,
    pub(super) h_max: f64,
}

impl HeightField {
    pub fn new(
        grid_w: usize,
        grid_h: usize,
        detail: f64,
        heights: Vec<f64>,
        regions: Vec<u8>,
    ) -> Self {
        let h_min = heights.iter().copied().fold(f64::INFINITY, f64::min);
        let h_max = heights.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Self {
            grid_w,
            grid_h,
            detail,
            heights,
            regions,
            h_min,
            h_max,
        }
    }

    fn at(&self, i: isize, j: isize) -> f64 {
        let i = i.rem_euclid(self.grid_w as isize) as usize;
        let j = j.rem_euclid(self.grid_h as isize) as usize;
        self.heights[j * self.grid_w + i]
    }

    /// Bilinear height at (x, y) in texel units, wrapping.
    pub(super) fn height(&self, p: DVec2) -> f64 {
        let gx = p.x * self.detail - 0.5;
        let gy = p.y * self.detail - 0.5;
        let (fx, fy) = (gx.floor(), gy.floor());
        let (tx, ty) = (gx - fx, gy - fy);
        let (i, j) = (fx as isize, fy as isize);
        let h00 = self.at(i, j);
        let h10 = self.at(i + 1, j);
        let h01 = self.at(i, j + 1);
        let h11 = self.at(i + 1, j + 1);
        (h00 * (1.0 - tx) + h10 * tx) * (1.0 - ty) + (h01 * (1.0 - tx) + h11 * tx) * ty
    }

    /// Surface normal of the bilinear surface at (x, y).
    pub(super) fn normal(&self, p: DVec2) -> DVec3 {
        let gx = p.x * self.detail - 0.5;
        let gy = p.y * self.detail - 0.5;
        let (fx, fy) = (gx.floor(), gy.floor());
        let (tx, ty) = (gx - fx, gy - fy);
        let (i, j) = (fx as isize, fy as isize);
        let h00 = self.at(i, j);
        let h10 = self.at(i + 1, j);
        let h01 = self.at(i, j + 1);
        let h11 = self.at(i + 1, j + 1);
        // Derivatives of the bilinear patch, per texel unit.
        let dx = ((h10 - h00) * (1.0 - ty) + (h11 - h01) * ty) * self.detail;
        let dy = ((h01 - h00) * (1.0 - tx) + (h11 - h10) * tx) * self.detail;
        DVec3::new(-dx, -dy, 1.0).normalize()
    }

    pub(super) fn region(&self, p: DVec2) -> usize {
        let i = ((p.x * self.detail).floor() as isize).rem_euclid(self.grid_w as isize) as usize;
        let j = ((p.y * self.detail).floor() as isize).rem_euclid(self.grid_h as isize) as usize;
        usize::from(self.regions[j * self.grid_w + i])
    }

    /// First intersection of the ray `o + t d` (d pointing down or sideways) with the
    /// surface, marching in steps of half a height sample and bisecting the crossing.
    pub(super) fn intersect_down(&self, o: DVec3, d: DVec3) -> Option<DVec3> {
        if d.z >= 0.0 {
            return None;
        }
        let horizontal = d.truncate().length();
        if horizontal < 1e-12 {
            let h = self.height(o.truncate());
            return Some(DVec3::new(o.x, o.y, h));
        }
        let step = 0.5 / (self.detail * horizontal);
        let (mut t0, mut t) = (0.0, 0.0);
        // d.z < 0: the ray ends below h_min, where it is surely under the surface.
        loop {
            let p = o + d * t;
            if p.z <= self.height(p.truncate()) {
                break;
            }
            t0 = t;
            t += step;
        }
        let (mut a, mut b) = (t0, t);
        for _ in 0..24 {
            let m = 0.5 * (a + b);
            let p = o + d * m;
            if p.z <= self.height(p.truncate()) {
                b = m;
            } else {
                a = m;
            }
        }
        let p = o + d * b;
        Some(DVec3::new(p.x, p.y, self.height(p.truncate())))
    }

    /// Whether the ray from surface point `p` towards `d` (d.z > 0) is blocked before
    /// it leaves the height field's slab.
    pub(super) fn occluded(&self, p: DVec3, d: DVec3) -> bool {
        self.hit_up(p, d).is_some()
    }

    /// Where a gather ray from surface point `p` towards `d` (in the hemisphere of the
    /// surface normal) first meets the surface, if it does before leaving the slab.
    pub(super) fn gather_hit(&self, p: DVec3, d: DVec3) -> Option<DVec2> {
        if d.z > 0.0 {
            return self.hit_up(p, d);
        }
        // Downwards: start half a marching step out, clear of the point's own patch.
        let horizontal = d.truncate().length().max(1e-12);
        let o = p + d * (0.25 / (self.detail * horizontal));
        self.intersect_down(o, d).map(|q| q.truncate())
    }

    /// Where the ray from surface point `p` towards `d` (d.z > 0) first goes under the
    /// surface before leaving the slab (for gather rays), if it does.
    fn hit_up(&self, p: DVec3, d: DVec3) -> Option<DVec2> {
        let horizontal = d.truncate().length();
        if horizontal < 1e-12 {
            return None;
        }
        let step = 0.5 / (self.detail * horizontal);
        // Start half a step out so the starting point's own patch does not occlude.
        let mut t = 0.5 * step;
        loop {
            let q = p + d * t;
            if q.z > self.h_max {
                return None;
            }
            if q.z < self.height(q.truncate()) - 1e-6 {
                return Some(q.truncate());
            }
            t += step;
        }
    }
}
