//! The filter at half the resolution (`Denoiser::apply_halved`): the viewport's first
//! picture after an emission edit, when the full filter would take too long.

use rayon::prelude::*;

use meso_materials::image::Image;

use super::{Denoiser, Guides};

impl Guides {
    /// The guides of the image of half the size (rounded up) that `halve` makes: each
    /// 2 x 2 block's top-left pixel's.
    pub fn halved(&self) -> Guides {
        let (w, hw) = (self.width as usize, self.width.div_ceil(2) as usize);
        let n = hw * self.height.div_ceil(2) as usize;
        let pick = |i: usize| 2 * (i / hw) * w + 2 * (i % hw);
        Guides {
            width: hw as u32,
            height: self.height.div_ceil(2),
            normal: (0..n).map(|i| self.normal[pick(i)]).collect(),
            depth: (0..n).map(|i| self.depth[pick(i)]).collect(),
            albedo: (0..n).map(|i| self.albedo[pick(i)]).collect(),
        }
    }
}

impl Denoiser {
    /// The filter at half the resolution, for the viewport's first picture after an
    /// edit that keeps the samples (an emission edit) while `apply` would take too
    /// long: the image averaged over 2 x 2 blocks, filtered with `half_guides`
    /// (`Guides::halved`) by one pass fewer (the same footprint in full pixels) and
    /// half the colour tolerance (a block's mean has half a pixel's noise), then
    /// spread back bilinearly. About a quarter of `apply`'s time; softer at edges
    /// (within two pixels of a depth edge, tested). `None` when the guides are not the halved image's size.
    pub fn apply_halved(&self, image: &Image, half_guides: &Guides) -> Option<Image> {
        let (w, h) = (image.width(), image.height());
        if (half_guides.width, half_guides.height) != (w.div_ceil(2), h.div_ceil(2)) {
            return None;
        }
        let coarse = Denoiser {
            passes: self.passes.saturating_sub(1).max(1),
            sigma_color: self.sigma_color / 2.0,
            ..*self
        };
        let filtered = coarse.apply(&halve(image), half_guides)?;
        Some(double(&filtered, w, h))
    }
}

/// Each 2 x 2 block's mean (the pixels of it inside the image).
fn halve(image: &Image) -> Image {
    let (w, h) = (image.width(), image.height());
    let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = Image::new(hw, hh);
    out.pixels_mut()
        .par_chunks_mut(hw as usize)
        .enumerate()
        .for_each(|(by, row)| {
            for (bx, p) in row.iter_mut().enumerate() {
                let (mut sum, mut n) = ([0.0f32; 3], 0.0f32);
                for y in (2 * by as u32)..(2 * by as u32 + 2).min(h) {
                    for x in (2 * bx as u32)..(2 * bx as u32 + 2).min(w) {
                        let v = image.get(x, y);
                        (0..3).for_each(|k| sum[k] += v[k]);
                        n += 1.0;
                    }
                }
                *p = sum.map(|s| s / n);
            }
        });
    out
}

/// `small` (from `halve`) spread back to `w` x `h` bilinearly, its pixels' centres at
/// their blocks' centres.
fn double(small: &Image, w: u32, h: u32) -> Image {
    let (sw, sh) = (small.width(), small.height());
    // Along an axis: the two coarse pixels around full pixel x and the second's weight.
    let axis = |len: u32, coarse: u32| -> Vec<(u32, u32, f32)> {
        (0..len)
            .map(|x| {
                let u = (x as f32 + 0.5) / 2.0 - 0.5;
                let i0 = u.floor().max(0.0) as u32;
                let i0 = i0.min(coarse - 1);
                let i1 = (i0 + 1).min(coarse - 1);
                (i0, i1, (u - i0 as f32).clamp(0.0, 1.0))
            })
            .collect()
    };
    let (cols, rows) = (axis(w, sw), axis(h, sh));
    crate::preview::bilinear(small, (&cols, &rows))
}
