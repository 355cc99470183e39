//! The viewport denoiser: an edge-avoiding a-trous wavelet filter (Dammertz et al.
//! 2010) of the accumulated image, guided by what the first hit of each pixel's
//! centre ray sees (normal, depth, albedo), so it blurs noise within a surface and
//! stops at silhouettes, creases and texture edges. It is for looking at early frames
//! only: the studio fades it out as samples accumulate, `meso render` applies it only
//! with `--denoise`, and references, goldens and reports' progressive errors never
//! see it (the convergence report lists it as its own rows).
//!
//! This file holds the guides, the parameters, the studio's fade and blend; each
//! form of the filter lives with its machinery: `planar.rs` (`apply`, what runs),
//! `reference.rs` (`apply_reference`, the textbook form it is tested against),
//! `halved.rs` (`apply_halved`), `polynomial_exp.rs` (the vectorisable `exp`).

mod halved;
mod planar;
mod polynomial_exp;
mod reference;
#[cfg(test)]
mod tests;

use meso_materials::image::Image;

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

/// What the studio's viewport filters a frame of `samples` samples per pixel with: the
/// denoiser for that many samples and the blend's strength, or `None` once the blend
/// has faded out.
pub fn viewport_filter(samples: u32) -> Option<(Denoiser, f32)> {
    let strength = viewport_strength(samples);
    (strength > 0.0).then(|| (Denoiser::for_samples(samples), strength))
}

/// The B3-spline's 5 taps along one axis; a pass applies it along both.
const KERNEL: [f32; 5] = [1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0];

/// One channel as `c / (1 + c)`: bright highlights do not dominate the colour weight.
fn compress_channel(v: f32) -> f32 {
    v.max(0.0) / (1.0 + v.max(0.0))
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
