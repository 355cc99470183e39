//! The viewport denoiser: an edge-avoiding a-trous wavelet filter (Dammertz et al.
//! 2010) of the accumulated image, guided by what the first hit of each pixel's
//! centre ray sees (normal, depth, albedo), so it blurs noise within a surface and
//! stops at silhouettes, creases and texture edges. It is for looking at early frames
//! only: the studio fades it out as samples accumulate, `meso render` applies it only
//! with `--denoise`, and references, goldens and reports' progressive errors never
//! see it (the convergence report lists it as its own rows).

use rayon::prelude::*;

use crate::image::Image;

/// What the first hit of each pixel's centre ray sees, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Guides {
    pub width: u32,
    pub height: u32,
    /// Shading normal (unit; zero where the ray leaves the scene).
    pub normal: Vec<[f32; 3]>,
    /// Distance along the ray (infinite where it leaves the scene).
    pub depth: Vec<f32>,
    /// A colour the surface reflects (the BRDF's albedo, a pack's texel response at
    /// normal incidence, a mirror's reflectance); the background's own colour.
    pub albedo: Vec<[f32; 3]>,
}

/// The filter's edge-stopping parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Denoiser {
    /// Passes with the 5x5 B3-spline kernel at steps 1, 2, 4, ...: a footprint of
    /// `4 * 2^passes + 1` pixels.
    pub passes: u32,
    /// Colour difference (of `c / (1 + c)`, so bright highlights do not dominate) at
    /// which a neighbour's weight falls to 1/e; halved at every pass.
    pub sigma_color: f32,
    /// Exponent of the normals' cosine.
    pub normal_power: i32,
    /// Relative depth difference at which the weight falls to 1/e.
    pub sigma_depth: f32,
    /// Albedo difference at which the weight falls to 1/e.
    pub sigma_albedo: f32,
}

impl Default for Denoiser {
    fn default() -> Self {
        Self {
            passes: 4,
            sigma_color: 0.6,
            normal_power: 64,
            sigma_depth: 0.03,
            sigma_albedo: 0.1,
        }
    }
}

impl Denoiser {
    /// The filter for an image of `samples` samples per pixel: the colour tolerance
    /// shrinks as the noise does (1 / sqrt(samples)), so later frames keep their
    /// detail.
    pub fn for_samples(samples: u32) -> Self {
        let d = Self::default();
        Self {
            sigma_color: d.sigma_color / (samples.max(1) as f32).sqrt(),
            ..d
        }
    }
}

/// Samples per pixel at which the studio's denoiser has faded out entirely.
pub const FADE_SAMPLES: u32 = 32;

/// The studio's blend of the denoised image after `samples` samples per pixel: 1 at
/// one sample, falling linearly to 0 at `FADE_SAMPLES`.
pub fn viewport_strength(samples: u32) -> f32 {
    if samples >= FADE_SAMPLES {
        0.0
    } else {
        1.0 - samples.saturating_sub(1) as f32 / (FADE_SAMPLES - 1) as f32
    }
}

const KERNEL: [f32; 5] = [1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0];

fn compress(c: [f32; 3]) -> [f32; 3] {
    c.map(|v| v.max(0.0) / (1.0 + v.max(0.0)))
}

fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

impl Denoiser {
    /// The filtered image. `None` when the guides do not match the image's size.
    pub fn apply(&self, image: &Image, guides: &Guides) -> Option<Image> {
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
                .map(|p| self.filter_pixel((src, &compressed), guides, p, step, sigma_c))
                .collect();
            current = next;
        }
        Image::from_pixels(w, h, current).ok()
    }

    fn filter_pixel(
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

/// `noisy` where `strength` is 0, `denoised` where it is 1, linear in between.
pub fn blend(noisy: &Image, denoised: &Image, strength: f32) -> Image {
    let mut out = noisy.clone();
    let s = strength.clamp(0.0, 1.0);
    for (o, d) in out.pixels_mut().iter_mut().zip(denoised.pixels()) {
        for k in 0..3 {
            o[k] += s * (d[k] - o[k]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat_guides(w: u32, h: u32) -> Guides {
        let n = (w * h) as usize;
        Guides {
            width: w,
            height: h,
            normal: vec![[0.0, 0.0, 1.0]; n],
            depth: vec![1.0; n],
            albedo: vec![[0.5; 3]; n],
        }
    }

    fn noisy(w: u32, h: u32, level: f32, amplitude: f32) -> Image {
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let u = crate::rng::SampleStream::new(&[u64::from(x), u64::from(y)]).at(0) as f32;
                img.set(x, y, [level + amplitude * (u - 0.5) * 2.0; 3]);
            }
        }
        img
    }

    fn rms(img: &Image, level: f32) -> f32 {
        (img.pixels()
            .iter()
            .map(|p| (p[0] - level).powi(2))
            .sum::<f32>()
            / img.pixels().len() as f32)
            .sqrt()
    }

    #[test]
    fn noise_on_one_flat_surface_is_smoothed_and_its_level_kept() {
        let img = noisy(64, 64, 0.5, 0.2);
        let out = Denoiser::default()
            .apply(&img, &flat_guides(64, 64))
            .expect("sizes match");
        let (before, after) = (rms(&img, 0.5), rms(&out, 0.5));
        // Uniform noise of amplitude 0.2 has RMS 0.115; the filter must cut it by 4x.
        assert!(after < before / 4.0, "{before} -> {after}");
        let mean = out.pixels().iter().map(|p| p[0]).sum::<f32>() / 4096.0;
        assert!((mean - 0.5).abs() < 0.01, "mean {mean}");
    }

    #[test]
    fn edges_in_every_guide_are_kept() {
        // Left half at 0.2, right half at 0.8, with an edge in one guide at a time:
        // the filter must keep the step (no pixel pulled across by more than 2%).
        let (w, h) = (32, 16);
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                img.set(x, y, [if x < w / 2 { 0.2 } else { 0.8 }; 3]);
            }
        }
        for guide in ["normal", "depth", "albedo", "background"] {
            let mut g = flat_guides(w, h);
            for y in 0..h {
                for x in w / 2..w {
                    let p = (y * w + x) as usize;
                    match guide {
                        "normal" => g.normal[p] = [1.0, 0.0, 0.0],
                        "depth" => g.depth[p] = 2.0,
                        "albedo" => g.albedo[p] = [0.9; 3],
                        _ => g.depth[p] = f32::INFINITY,
                    }
                }
            }
            let out = Denoiser {
                // The colour weight alone would also keep this step; switch it off.
                sigma_color: 1e6,
                ..Denoiser::default()
            }
            .apply(&img, &g)
            .expect("sizes match");
            for y in 0..h {
                for x in 0..w {
                    let want = img.get(x, y)[0];
                    let got = out.get(x, y)[0];
                    assert!(
                        (got - want).abs() < 0.02 * 0.6,
                        "{guide}: ({x}, {y}) {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_viewport_blend_fades_out_and_guides_must_match() {
        assert_eq!(viewport_strength(1), 1.0);
        assert!(viewport_strength(16) > 0.0 && viewport_strength(16) < 1.0);
        assert_eq!(viewport_strength(FADE_SAMPLES), 0.0);
        let img = noisy(8, 8, 0.5, 0.2);
        let flat = Image::from_pixels(8, 8, vec![[0.5; 3]; 64]).expect("size");
        assert_eq!(blend(&img, &flat, 0.0), img);
        assert_eq!(blend(&img, &flat, 1.0), flat);
        assert!(
            Denoiser::default()
                .apply(&img, &flat_guides(8, 9))
                .is_none()
        );
    }
}
