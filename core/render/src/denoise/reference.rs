//! The filter as Dammertz et al. write it (`Denoiser::apply_reference`): one
//! neighbour at a time with the library's `exp`, kept as the definition the
//! vectorised `apply` is tested and benchmarked against.

use rayon::prelude::*;

use meso_materials::image::Image;

use super::{Denoiser, Guides, KERNEL, compress_channel};

/// A colour with each channel compressed (`compress_channel`).
pub(super) fn compress(c: [f32; 3]) -> [f32; 3] {
    c.map(compress_channel)
}

/// The squared distance of two colours (or albedos).
fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

impl Denoiser {
    /// The filter as Dammertz et al. write it, one neighbour at a time with the
    /// library's `exp`: what `apply` is tested and benchmarked against.
    pub fn apply_reference(&self, image: &Image, guides: &Guides) -> Option<Image> {
        let (w, h) = (image.width(), image.height());
        if (guides.width, guides.height) != (w, h) {
            return None;
        }
        let mut current: Vec<[f32; 3]> = image.pixels().to_vec();
        for pass in 0..self.passes {
            let step = 1i64 << pass;
            let sigma_c = self.sigma_color / (1u32 << pass) as f32;
            let src = &current;
            // Each pixel's compressed colour once per pass, not once per neighbour.
            let compressed: Vec<[f32; 3]> = src.par_iter().map(|&c| compress(c)).collect();
            let next: Vec<[f32; 3]> = (0..(w * h) as usize)
                .into_par_iter()
                .map(|p| self.filter_pixel_reference((src, &compressed), guides, p, step, sigma_c))
                .collect();
            current = next;
        }
        Image::from_pixels(w, h, current).ok()
    }

    fn filter_pixel_reference(
        &self,
        (src, compressed): (&[[f32; 3]], &[[f32; 3]]),
        g: &Guides,
        p: usize,
        step: i64,
        sigma_c: f32,
    ) -> [f32; 3] {
        let (w, h) = (i64::from(g.width), i64::from(g.height));
        let (x, y) = (p as i64 % w, p as i64 / w);
        let (cp, np, zp, ap) = (compressed[p], g.normal[p], g.depth[p], g.albedo[p]);
        let mut sum = [0.0f32; 3];
        let mut total = 0.0f32;
        for (j, ky) in KERNEL.iter().enumerate() {
            let qy = y + (j as i64 - 2) * step;
            if !(0..h).contains(&qy) {
                continue;
            }
            for (i, kx) in KERNEL.iter().enumerate() {
                let qx = x + (i as i64 - 2) * step;
                if !(0..w).contains(&qx) {
                    continue;
                }
                let q = (qy * w + qx) as usize;
                let weight =
                    kx * ky * self.edge_weight(cp, np, zp, ap, compressed[q], g, q, sigma_c);
                for k in 0..3 {
                    sum[k] += weight * src[q][k];
                }
                total += weight;
            }
        }
        // The centre's own weight is positive, so `total` is too.
        sum.map(|s| s / total)
    }

    #[allow(clippy::too_many_arguments)]
    fn edge_weight(
        &self,
        cp: [f32; 3],
        np: [f32; 3],
        zp: f32,
        ap: [f32; 3],
        // Both colours compressed (`compress`).
        cq: [f32; 3],
        g: &Guides,
        q: usize,
        sigma_c: f32,
    ) -> f32 {
        let zq = g.depth[q];
        // Background and surface never mix; two background pixels always do.
        match (zp.is_finite(), zq.is_finite()) {
            (false, false) => return 1.0,
            (true, false) | (false, true) => return 0.0,
            (true, true) => {}
        }
        let nq = g.normal[q];
        let cos = (np[0] * nq[0] + np[1] * nq[1] + np[2] * nq[2]).max(0.0);
        let w_normal = cos.powi(self.normal_power);
        if w_normal == 0.0 {
            return 0.0;
        }
        // The depth, albedo and colour weights are exponentials: one exp of the sum.
        let depth = (zp - zq).abs() / (self.sigma_depth * zp.max(1e-6));
        let albedo = dist2(ap, g.albedo[q]).sqrt() / self.sigma_albedo;
        let color = dist2(cp, cq) / (sigma_c * sigma_c);
        w_normal * (-(depth + albedo + color)).exp()
    }
}
