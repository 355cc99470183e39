//! A per-texel strength in [0, 1] over a material's texel grid: what a brush stroke
//! covered, a selection, a cluster, or a mask image. Weight edits take one to limit
//! themselves to part of the material (`WeightTarget::texels`).

use glam::DVec2;

use super::{SpmmError, SpmmMaterial};

/// How a brush's strength falls off from its centre (d = distance / radius).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Falloff {
    /// Full strength out to the radius.
    Constant,
    /// 1 - d.
    #[default]
    Linear,
    /// (1 - d^2)^2: soft edges, flat centre.
    Smooth,
}

impl Falloff {
    pub const ALL: [Falloff; 3] = [Falloff::Constant, Falloff::Linear, Falloff::Smooth];

    pub fn name(self) -> &'static str {
        match self {
            Falloff::Constant => "constant",
            Falloff::Linear => "linear",
            Falloff::Smooth => "smooth",
        }
    }

    /// The factor at relative distance `d` (0 at and beyond 1, except `Constant` at 1).
    pub fn at(self, d: f64) -> f64 {
        if !(0.0..=1.0).contains(&d) {
            return 0.0;
        }
        match self {
            Falloff::Constant => 1.0,
            Falloff::Linear => 1.0 - d,
            Falloff::Smooth => (1.0 - d * d).powi(2),
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct TexelMask {
    width: u32,
    height: u32,
    strength: Vec<f32>,
}

impl TexelMask {
    /// Nothing selected.
    pub fn empty(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            strength: vec![0.0; width as usize * height as usize],
        }
    }

    /// Strengths given row-major; each must be finite and in [0, 1].
    pub fn from_strengths(width: u32, height: u32, strength: Vec<f32>) -> Result<Self, SpmmError> {
        let n = width as usize * height as usize;
        if strength.len() != n {
            return Err(SpmmError::Edit(format!(
                "texel mask of {} values for a {width}x{height} grid ({n} texels)",
                strength.len()
            )));
        }
        if let Some(i) = strength
            .iter()
            .position(|s| !(s.is_finite() && (0.0..=1.0).contains(s)))
        {
            return Err(SpmmError::Edit(format!(
                "texel mask value {} at texel {i} ({}, {}) must lie in [0, 1]",
                strength[i],
                i % width as usize,
                i / width as usize
            )));
        }
        Ok(Self {
            width,
            height,
            strength,
        })
    }

    /// A mask image in texel space (one pixel per texel, row 0 the top row of texels):
    /// its grey level (8 or 16 bits; an RGB image's luma), read as data (no sRGB
    /// decoding), over the full range is the strength: white 1, black 0. It must be `width` x `height`.
    pub fn read_image(path: &std::path::Path, width: u32, height: u32) -> Result<Self, SpmmError> {
        let at = || format!("texel mask `{}`", path.display());
        let img = image::ImageReader::open(path)
            .map_err(|e| SpmmError::Edit(format!("{}: {e}", at())))?
            .with_guessed_format()
            .map_err(|e| SpmmError::Edit(format!("{}: {e}", at())))?
            .decode()
            .map_err(|e| SpmmError::Edit(format!("{}: {e}", at())))?;
        if (img.width(), img.height()) != (width, height) {
            return Err(SpmmError::Edit(format!(
                "{}: {}x{} pixels, but the material has {width}x{height} texels",
                at(),
                img.width(),
                img.height()
            )));
        }
        let grey = img.to_luma16();
        let strength = grey.pixels().map(|p| f32::from(p.0[0]) / 65535.0).collect();
        Self::from_strengths(width, height, strength)
    }

    /// Full strength on the texels of `cluster`.
    pub fn of_cluster(m: &SpmmMaterial, cluster: usize) -> Self {
        Self {
            width: m.width(),
            height: m.height(),
            strength: m
                .texel_cluster()
                .iter()
                .map(|&c| if c as usize == cluster { 1.0 } else { 0.0 })
                .collect(),
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn strength(&self, texel: usize) -> f32 {
        self.strength[texel]
    }
    pub fn strengths(&self) -> &[f32] {
        &self.strength
    }
    /// Texels with a strength above 0.
    pub fn covered(&self) -> impl Iterator<Item = usize> + '_ {
        self.strength
            .iter()
            .enumerate()
            .filter(|(_, s)| **s > 0.0)
            .map(|(t, _)| t)
    }
    pub fn is_empty(&self) -> bool {
        self.covered().next().is_none()
    }

    /// Stamps a disc centred at `centre` (continuous texel coordinates: x right, y
    /// down, texel centres at +0.5) of `radius` texels; the grid wraps, as packs tile.
    /// Each texel keeps the larger of its strength and the stamp's, so a stroke of
    /// overlapping stamps never exceeds its strength.
    pub fn stamp(&mut self, centre: DVec2, radius: f64, strength: f32, falloff: Falloff) {
        if !(centre.is_finite() && radius.is_finite() && radius > 0.0) {
            return;
        }
        let strength = strength.clamp(0.0, 1.0);
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        let x_range = (centre.x - radius).floor() as i64..=(centre.x + radius).ceil() as i64;
        let y_range = (centre.y - radius).floor() as i64..=(centre.y + radius).ceil() as i64;
        for y in y_range {
            for x in x_range.clone() {
                let d = DVec2::new(x as f64 + 0.5, y as f64 + 0.5).distance(centre) / radius;
                let s = (f64::from(strength) * falloff.at(d)) as f32;
                if s > 0.0 {
                    let t = (y.rem_euclid(h) * w + x.rem_euclid(w)) as usize;
                    self.strength[t] = self.strength[t].max(s);
                }
            }
        }
    }

    /// Sets one texel's strength (clamped to [0, 1]), keeping the larger one.
    pub fn raise(&mut self, texel: usize, strength: f32) {
        if let Some(s) = self.strength.get_mut(texel) {
            *s = s.max(strength.clamp(0.0, 1.0));
        }
    }

    /// The product of two masks' strengths (a stroke limited to a selection).
    pub fn intersected(&self, other: &TexelMask) -> Result<Self, SpmmError> {
        if (self.width, self.height) != (other.width, other.height) {
            return Err(SpmmError::Edit(format!(
                "texel masks of {}x{} and {}x{} texels cannot be combined",
                self.width, self.height, other.width, other.height
            )));
        }
        Ok(Self {
            width: self.width,
            height: self.height,
            strength: self
                .strength
                .iter()
                .zip(&other.strength)
                .map(|(a, b)| a * b)
                .collect(),
        })
    }
}
