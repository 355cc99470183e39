//! The preview after an edit that restarts every pixel (a camera move, a resize, a
//! mesh edit): the next frame's samples of one pixel per `stride` x `stride` block go
//! first and the viewport shows them spread over the image, so the edit shows in a
//! fraction of a frame's time. The preview's samples are the frame's own (the frame
//! then completes the other pixels), so the film is an uninterrupted render's and the
//! preview costs nothing in the end. The spread image is for the viewport only.

use rayon::prelude::*;

use meso_materials::image::Image;

/// Previewed pixels of an image about this many pixels across: a preview costs about
/// a 128 x 128 frame whatever the viewport's size.
const PREVIEW_SIDE: u32 = 128;

/// The block side for an image of this size: 1 (no preview) up to 256 pixels across,
/// then the longer side over `PREVIEW_SIDE`, rounded, at most 16.
pub fn stride_for(width: u32, height: u32) -> u32 {
    let side = width.max(height);
    ((side + PREVIEW_SIDE / 2) / PREVIEW_SIDE).clamp(1, 16)
}

/// The previewed pixel of block `block` along an axis of `len` pixels: the block's
/// centre, or the last pixel for a block cut by the image's edge.
fn centre(block: u32, stride: u32, len: u32) -> u32 {
    (block * stride + stride / 2).min(len.saturating_sub(1))
}

fn blocks(len: u32, stride: u32) -> u32 {
    len.div_ceil(stride)
}

/// The size of the image of one pixel per block (`gather`).
pub fn grid_size(width: u32, height: u32, stride: u32) -> (u32, u32) {
    let stride = stride.max(1);
    (blocks(width, stride), blocks(height, stride))
}

/// The previewed pixels of `image` as an image of one pixel per block.
pub fn gather(image: &Image, stride: u32) -> Image {
    let (w, h) = (image.width(), image.height());
    let (gw, gh) = grid_size(w, h, stride);
    let pixels = grid_pixels(w, h, stride)
        .iter()
        .map(|&p| image.pixels()[p as usize])
        .collect();
    Image::from_pixels(gw, gh, pixels).unwrap_or_else(|_| Image::new(gw, gh))
}

/// `image` with its previewed pixels replaced by `grid`'s (from `gather`'s layout);
/// `None` when `grid` is not the grid's size.
pub fn scatter(image: &Image, grid: &Image, stride: u32) -> Option<Image> {
    let (w, h) = (image.width(), image.height());
    if (grid.width(), grid.height()) != grid_size(w, h, stride) {
        return None;
    }
    let mut out = image.clone();
    for (&p, &v) in grid_pixels(w, h, stride).iter().zip(grid.pixels()) {
        out.pixels_mut()[p as usize] = v;
    }
    Some(out)
}

/// The previewed pixels, row-major indices, one per block.
pub fn grid_pixels(width: u32, height: u32, stride: u32) -> Vec<u32> {
    let stride = stride.max(1);
    let (bx, by) = (blocks(width, stride), blocks(height, stride));
    (0..by)
        .flat_map(|j| {
            let y = centre(j, stride, height);
            (0..bx).map(move |i| y * width + centre(i, stride, width))
        })
        .collect()
}

/// Per pixel along an axis: the two previewed pixels around it and the second's
/// weight (outside the first and last previewed pixel, the nearest one alone).
fn axis_weights(len: u32, stride: u32) -> Vec<(u32, u32, f32)> {
    let last = blocks(len, stride).saturating_sub(1);
    (0..len)
        .map(|x| {
            // The block whose previewed pixel is at or before x (the first one if none).
            let b = (x.saturating_sub(stride / 2) / stride).min(last);
            let (c0, b1) = (centre(b, stride, len), (b + 1).min(last));
            let c1 = centre(b1, stride, len);
            if x <= c0 || c1 <= c0 {
                (c0, c0, 0.0)
            } else {
                (c0, c1, ((x - c0) as f32 / (c1 - c0) as f32).min(1.0))
            }
        })
        .collect()
}

/// The image the viewport shows from a film whose only samples are the previewed
/// pixels (`grid_pixels`): each pixel bilinear between the four previewed pixels around
/// it; the other pixels of `image` are not read.
pub fn spread(image: &Image, stride: u32) -> Image {
    let (w, h) = (image.width(), image.height());
    let stride = stride.max(1);
    let (cols, rows) = (axis_weights(w, stride), axis_weights(h, stride));
    bilinear(image, (&cols, &rows))
}

/// Per output column (or row): the two source columns (rows) around it and the
/// second's weight.
pub(crate) type AxisWeights = [(u32, u32, f32)];

/// An image of `cols.len()` x `rows.len()` pixels, each bilinear between four pixels
/// of `src`: per column and per row, the two source columns (rows) and the second's
/// weight. Shared by the preview's spread and the half-resolution denoiser's.
pub(crate) fn bilinear(src: &Image, (cols, rows): (&AxisWeights, &AxisWeights)) -> Image {
    let mut out = Image::new(cols.len() as u32, rows.len() as u32);
    let lerp = |a: [f32; 3], b: [f32; 3], t: f32| std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t);
    out.pixels_mut()
        .par_chunks_mut(cols.len().max(1))
        .zip(rows.par_iter())
        .for_each(|(row, &(y0, y1, ty))| {
            for (p, &(x0, x1, tx)) in row.iter_mut().zip(cols) {
                let top = lerp(src.get(x0, y0), src.get(x1, y0), tx);
                let bottom = lerp(src.get(x0, y1), src.get(x1, y1), tx);
                *p = lerp(top, bottom, ty);
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stride_keeps_a_preview_about_128_pixels_across() {
        assert_eq!(stride_for(64, 64), 1);
        assert_eq!(stride_for(256, 200), 2);
        assert_eq!(stride_for(512, 512), 4);
        assert_eq!(stride_for(1920, 1080), 15);
        assert_eq!(stride_for(8192, 8192), 16);
    }

    #[test]
    fn the_grid_has_one_pixel_in_every_block_and_no_other() {
        for (w, h, s) in [(10, 7, 4), (8, 8, 4), (1, 1, 4), (13, 5, 1), (9, 9, 16)] {
            let grid = grid_pixels(w, h, s);
            let mut per_block = vec![0; (w.div_ceil(s) * h.div_ceil(s)) as usize];
            for &p in &grid {
                let (x, y) = (p % w, p / w);
                assert!(x < w && y < h, "{w}x{h}/{s}: pixel {p} outside");
                per_block[((y / s) * w.div_ceil(s) + x / s) as usize] += 1;
            }
            assert!(
                per_block.iter().all(|&n| n == 1),
                "{w}x{h}/{s}: {per_block:?}"
            );
        }
    }

    /// An image that is NaN everywhere but on the grid, where it is a linear ramp.
    fn ramp_on_grid(w: u32, h: u32, s: u32) -> (Image, impl Fn(f32, f32) -> [f32; 3]) {
        let f = |x: f32, y: f32| [0.5 + 0.25 * x, 2.0 - 0.125 * y, x + y];
        let mut img =
            Image::from_pixels(w, h, vec![[f32::NAN; 3]; (w * h) as usize]).expect("size matches");
        for p in grid_pixels(w, h, s) {
            img.pixels_mut()[p as usize] = f((p % w) as f32, (p / w) as f32);
        }
        (img, f)
    }

    #[test]
    fn spreading_reads_only_the_grid_keeps_it_and_is_exact_on_a_ramp() {
        let (w, h, s) = (37u32, 22u32, 4u32);
        let (img, f) = ramp_on_grid(w, h, s);
        let out = spread(&img, s);
        let grid = grid_pixels(w, h, s);
        let (first, last) = (s / 2, |len: u32| centre(len.div_ceil(s) - 1, s, len));
        for y in 0..h {
            for x in 0..w {
                let got = out.get(x, y);
                assert!(
                    got.iter().all(|v| v.is_finite()),
                    "({x}, {y}) read off the grid"
                );
                if grid.contains(&(y * w + x)) {
                    assert_eq!(got, img.get(x, y), "grid pixel ({x}, {y}) changed");
                }
                // Inside the grid's hull the ramp is reproduced; outside it, the
                // nearest previewed row or column's value.
                let cx = (x.max(first).min(last(w))) as f32;
                let cy = (y.max(first).min(last(h))) as f32;
                let want = f(cx, cy);
                for k in 0..3 {
                    assert!(
                        (got[k] - want[k]).abs() < 1e-4,
                        "({x}, {y}): {got:?} vs {want:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn gather_and_scatter_move_the_grid_pixels_and_nothing_else() {
        let (w, h, s) = (37u32, 22u32, 4u32);
        let (img, _) = ramp_on_grid(w, h, s);
        let grid = gather(&img, s);
        assert_eq!((grid.width(), grid.height()), grid_size(w, h, s));
        assert!(grid.pixels().iter().flatten().all(|v| v.is_finite()));
        let doubled = Image::from_pixels(
            grid.width(),
            grid.height(),
            grid.pixels().iter().map(|p| p.map(|v| 2.0 * v)).collect(),
        )
        .expect("size");
        let back = scatter(&img, &doubled, s).expect("the grid's size");
        for (p, (a, b)) in img.pixels().iter().zip(back.pixels()).enumerate() {
            if grid_pixels(w, h, s).contains(&(p as u32)) {
                assert_eq!(b.map(|v| v / 2.0), *a);
            } else {
                assert!(
                    a[0].is_nan() && b[0].is_nan(),
                    "pixel {p} off the grid changed"
                );
            }
        }
        assert!(
            scatter(&img, &img, s).is_none(),
            "a full-size image is not a grid"
        );
    }

    #[test]
    fn a_stride_of_one_is_the_image_itself() {
        let (img, _) = ramp_on_grid(9, 6, 1);
        assert_eq!(spread(&img, 1), img);
    }
}
