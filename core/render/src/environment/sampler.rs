//! Importance sampling of a lat-long map: a piecewise-constant 2D distribution over its
//! pixels, each weighted by its luminance times its solid angle (the sin(theta) of
//! the parametrisation, integrated exactly over the pixel's rows). A pixel is chosen
//! by the row marginal and the column conditional, then a direction uniformly in the
//! pixel's solid angle, so the pdf in solid angle is constant over a pixel and equals
//! luminance / (sum of luminance x solid angle): positive wherever the map is not black.
//! Works in map space; `Environment` applies the rotation.

use std::f64::consts::{PI, TAU};

use glam::{DVec2, DVec3};

use super::{pixel_of, pixel_solid_angle};
use meso_materials::image::{Image, luminance};

/// A sampled direction with its pdf in solid angle and the map's radiance there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvironmentSample {
    /// Unit direction in map space.
    pub dir: DVec3,
    pub pdf: f64,
    pub radiance: DVec3,
}

#[derive(Clone, Debug)]
pub struct EnvironmentSampler {
    width: u32,
    height: u32,
    /// Per pixel, luminance (the pdf in solid angle is this / `total`).
    luminance: Vec<f64>,
    /// Row marginal CDF, `height + 1` entries from 0 to 1.
    row_cdf: Vec<f64>,
    /// Per row, the column conditional CDF, `width + 1` entries from 0 to 1.
    col_cdf: Vec<f64>,
    /// Sum over pixels of luminance x solid angle.
    total: f64,
    /// Guide tables of `row_cdf` (`height` entries) and of each row's column CDF
    /// (`width` entries per row): `meso_materials::cdf`.
    row_guide: Vec<u32>,
    col_guide: Vec<u32>,
    /// cos(pi y / height) for y in 0..=height: the rows' edges.
    row_cos: Vec<f64>,
}

/// The first interval of `cdf` (non-decreasing, cdf[0] = 0, last = 1) whose upper end
/// exceeds `u`, found through its `guide`, and `u` remapped to [0, 1) inside it.
/// Zero-width intervals are skipped.
fn pick(cdf: &[f64], guide: &[u32], u: f64) -> (usize, f64) {
    let i = meso_materials::cdf::find(cdf, guide, u);
    let width = cdf[i + 1] - cdf[i];
    let t = if width > 0.0 {
        ((u - cdf[i]) / width).clamp(0.0, 1.0 - f64::EPSILON)
    } else {
        0.5
    };
    (i, t)
}

/// Normalises running sums into a CDF in place; returns the total.
fn normalise(sums: &mut [f64]) -> f64 {
    let total = *sums.last().expect("a CDF has at least two entries");
    if total > 0.0 {
        sums.iter_mut().for_each(|c| *c /= total);
    }
    total
}

impl EnvironmentSampler {
    /// Builds the distribution; `None` if the map is black (nothing to sample).
    pub fn new(map: &Image) -> Option<Self> {
        let (w, h) = (map.width() as usize, map.height() as usize);
        if w == 0 || h == 0 {
            return None;
        }
        let luminance: Vec<f64> = map
            .pixels()
            .iter()
            .map(|p| f64::from(luminance(*p)).max(0.0))
            .collect();
        let mut col_cdf = vec![0.0; h * (w + 1)];
        let mut row_cdf = vec![0.0; h + 1];
        for y in 0..h {
            let cdf = &mut col_cdf[y * (w + 1)..(y + 1) * (w + 1)];
            for x in 0..w {
                cdf[x + 1] = cdf[x] + luminance[y * w + x];
            }
            let row_lum = normalise(cdf);
            row_cdf[y + 1] = row_cdf[y] + row_lum * pixel_solid_angle(w as u32, h as u32, y as u32);
        }
        let total = normalise(&mut row_cdf);
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        let mut row_guide = Vec::with_capacity(h);
        meso_materials::cdf::build_guide(&row_cdf, h, &mut row_guide);
        let mut col_guide = Vec::with_capacity(h * w);
        for cdf in col_cdf.chunks_exact(w + 1) {
            meso_materials::cdf::build_guide(cdf, w, &mut col_guide);
        }
        Some(Self {
            width: w as u32,
            height: h as u32,
            luminance,
            row_cdf,
            col_cdf,
            total,
            row_guide,
            col_guide,
            row_cos: (0..=h).map(|y| (PI * y as f64 / h as f64).cos()).collect(),
        })
    }

    /// A direction drawn with probability proportional to luminance x solid angle.
    pub fn sample(&self, map: &Image, u: DVec2) -> EnvironmentSample {
        let w = self.width as usize;
        let (y, ty) = pick(&self.row_cdf, &self.row_guide, u.x);
        let (x, tx) = pick(
            &self.col_cdf[y * (w + 1)..(y + 1) * (w + 1)],
            &self.col_guide[y * w..(y + 1) * w],
            u.y,
        );
        // Uniform in solid angle inside the pixel: phi uniform, cos(theta) uniform.
        let phi = TAU * ((x as f64 + tx) / w as f64 - 0.5);
        let (c0, c1) = (self.row_cos[y], self.row_cos[y + 1]);
        let cos_t = c0 + (c1 - c0) * ty;
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let dir = DVec3::new(sin_t * phi.cos(), cos_t, sin_t * phi.sin());
        let p = map.get(x as u32, y as u32);
        EnvironmentSample {
            dir,
            pdf: self.luminance[y * w + x] / self.total,
            radiance: DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64),
        }
    }

    /// The tables as they are, for a device that samples with them (the GPU mode):
    /// the row marginal CDF (`height + 1` entries), the per-row column CDFs (`height`
    /// rows of `width + 1`) and each pixel's pdf in solid angle, row by row.
    pub fn tables(&self) -> (&[f64], &[f64], impl Iterator<Item = f64> + '_) {
        (
            &self.row_cdf,
            &self.col_cdf,
            self.luminance.iter().map(|l| l / self.total),
        )
    }

    /// The pdf in solid angle of drawing map-space direction `dir`.
    pub fn pdf(&self, dir: DVec3) -> f64 {
        let (x, y) = pixel_of(self.width, self.height, dir);
        self.luminance[y as usize * self.width as usize + x as usize] / self.total
    }

    /// `pdf(dir)` and `map`'s radiance in map-space direction `dir` (the map this
    /// sampler was built from), finding the pixel once: a material-drawn direction
    /// needs both.
    pub fn pdf_and_radiance(&self, map: &Image, dir: DVec3) -> (f64, DVec3) {
        let (x, y) = pixel_of(self.width, self.height, dir);
        let p = map.get(x, y);
        (
            self.luminance[y as usize * self.width as usize + x as usize] / self.total,
            DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64),
        )
    }
}
