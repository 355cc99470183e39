//! Which pixels a material edit reaches. A mode records per pixel a box of the
//! texture coordinates its samples shaded (`Film`); an SPMM edit that changes a few
//! texels (a brush stroke, one basis of one cluster) then restarts only the pixels
//! whose box, mapped through the material's tiling onto its texel grid, covers a
//! changed texel. The test is conservative: one texel of margin on each side covers
//! f32 rounding of the box and bilinear filtering's neighbours.

use glam::DVec2;

use super::film::UvBox;
use crate::scene::Material;

/// The changed texels of one SPMM material, as a summed-area table for O(1) box
/// queries (a box of a mirror pixel can span the whole texture).
pub struct EditedTexels {
    width: i64,
    height: i64,
    uv_scale: DVec2,
    /// (width + 1) x (height + 1) prefix counts of changed texels.
    table: Vec<u32>,
}

impl EditedTexels {
    /// The texels `after` changed relative to `before`; `None` when the edit is not a
    /// texel-level change of one SPMM material (another kind, new tiling or knobs, a
    /// new grid): then every pixel that shaded the material restarts.
    pub fn between(before: &Material, after: &Material) -> Option<Self> {
        let (
            Material::Spmm {
                material: m0,
                uv_scale: s0,
                residual: r0,
                npca: n0,
            },
            Material::Spmm {
                material: m1,
                uv_scale: s1,
                residual: r1,
                npca: n1,
            },
        ) = (before, after)
        else {
            return None;
        };
        if (s0, r0, n0) != (s1, r1, n1) {
            return None;
        }
        let changed = m0.changed_texels(m1)?;
        Some(Self::new(m1.width(), m1.height(), *s1, &changed))
    }

    /// From a row-major changed flag per texel of a `width` x `height` grid tiled by
    /// `uv_scale`.
    pub fn new(width: u32, height: u32, uv_scale: DVec2, changed: &[bool]) -> Self {
        let (w, h) = (width as usize, height as usize);
        let mut table = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            for x in 0..w {
                table[(y + 1) * (w + 1) + x + 1] = u32::from(changed[y * w + x])
                    + table[y * (w + 1) + x + 1]
                    + table[(y + 1) * (w + 1) + x]
                    - table[y * (w + 1) + x];
            }
        }
        Self {
            width: i64::from(width),
            height: i64::from(height),
            uv_scale,
            table,
        }
    }

    /// Whether any texel changed at all.
    pub fn any(&self) -> bool {
        *self.table.last().unwrap_or(&0) > 0
    }

    /// Whether a pixel whose samples shaded the texture coordinates in `b` may have
    /// read a changed texel. An empty box (no SPMM shading recorded) reaches nothing.
    pub fn reaches(&self, b: &UvBox) -> bool {
        if !(b[0] <= b[2] && b[1] <= b[3]) {
            return false;
        }
        let (w, h) = (self.width as f64, self.height as f64);
        // Texel columns grow with u; rows grow as v falls (row 0 is the top), as in
        // the texel grid's nearest look-up.
        let x0 = (f64::from(b[0]) * self.uv_scale.x * w).floor() as i64 - 1;
        let x1 = (f64::from(b[2]) * self.uv_scale.x * w).floor() as i64 + 1;
        let y0 = (-f64::from(b[3]) * self.uv_scale.y * h).floor() as i64 - 1;
        let y1 = (-f64::from(b[1]) * self.uv_scale.y * h).floor() as i64 + 1;
        let xs = wrapped(x0, x1, self.width);
        let ys = wrapped(y0, y1, self.height);
        ys.iter().flatten().any(|&(ya, yb)| {
            xs.iter()
                .flatten()
                .any(|&(xa, xb)| self.count(xa, xb, ya, yb) > 0)
        })
    }

    /// Changed texels in columns xa..xb, rows ya..yb (half-open, inside the grid).
    fn count(&self, xa: i64, xb: i64, ya: i64, yb: i64) -> u32 {
        let stride = self.width + 1;
        let at = |x: i64, y: i64| self.table[(y * stride + x) as usize];
        at(xb, yb) + at(xa, ya) - at(xa, yb) - at(xb, ya)
    }
}

/// The inclusive range a..=b of a periodic axis of `n` cells as at most two half-open
/// ranges inside 0..n.
pub fn wrapped(a: i64, b: i64, n: i64) -> [Option<(i64, i64)>; 2] {
    if b - a + 1 >= n {
        return [Some((0, n)), None];
    }
    let start = a.rem_euclid(n);
    let end = start + (b - a + 1);
    if end <= n {
        [Some((start, end)), None]
    } else {
        [Some((start, n)), Some((0, end - n))]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The texel (x, y) a UV point lands in, by the spec's rule (u right, v up, row 0
    /// the top, wrapping), written out here rather than borrowed from the grid code.
    fn texel_of(u: f64, v: f64, w: i64, h: i64) -> (i64, i64) {
        let x = ((u.rem_euclid(1.0)) * w as f64).floor() as i64;
        let y = ((1.0 - v.rem_euclid(1.0)) * h as f64).floor() as i64;
        (x.min(w - 1), y.min(h - 1))
    }

    #[test]
    fn a_box_reaches_exactly_the_texels_it_covers_within_one_texel_and_wraps() {
        let (w, h) = (8i64, 4i64);
        for (cx, cy) in [(0, 0), (3, 2), (7, 3), (5, 0)] {
            let mut changed = vec![false; 32];
            changed[(cy * w + cx) as usize] = true;
            let e = EditedTexels::new(8, 4, DVec2::ONE, &changed);
            assert!(e.any());
            // Every point box (a pixel that saw one uv) over a fine grid of uv,
            // including tiled copies outside [0, 1).
            for i in -40..80 {
                for j in -20..40 {
                    let (u, v) = (i as f64 / 40.0 + 0.003, j as f64 / 20.0 + 0.004);
                    let (x, y) = texel_of(u, v, w, h);
                    let near = |a: i64, b: i64, n: i64| {
                        let d = (a - b).rem_euclid(n);
                        d <= 1 || d >= n - 1
                    };
                    let b = [u as f32, v as f32, u as f32, v as f32];
                    if (x, y) == (cx, cy) {
                        assert!(e.reaches(&b), "uv ({u}, {v}) is on the changed texel");
                    } else if !(near(x, cx, w) && near(y, cy, h)) {
                        assert!(!e.reaches(&b), "uv ({u}, {v}) is two texels away");
                    }
                }
            }
        }
        let none = EditedTexels::new(8, 4, DVec2::ONE, &[false; 32]);
        assert!(!none.any() && !none.reaches(&[0.0, 0.0, 1.0, 1.0]));
        let mut one = [false; 32];
        one[0] = true;
        let e = EditedTexels::new(8, 4, DVec2::splat(3.0), &one);
        assert!(e.reaches(&[-5.0, -5.0, 5.0, 5.0]), "a box over every tile");
        assert!(!e.reaches(&crate::film::EMPTY_UV_BOX));
    }
}
