//! Distant lighting from a latitude-longitude HDR map (docs/scenes.md, `[environment]`):
//! the direction convention (+y up; u = 0.5 + atan2(z, x) / 2 pi, v = acos(y) / pi,
//! row 0 at the zenith), the rotation about +y, the nearest-pixel lookup every mode
//! uses, and the importance sampler (`sampler.rs`); `scene::Environment` holds a map
//! with its strength and rotation. The map is piecewise constant over
//! its pixels: lookup, sampling pdf and closed-form tests all read it that way.

mod sampler;
mod split;
#[cfg(test)]
mod tests;

use glam::DVec3;
use std::f64::consts::{PI, TAU};

use meso_materials::image::Image;
pub use sampler::{EnvironmentSample, EnvironmentSampler};
pub use split::{DEFAULT_TRACED_SHARE, EnvironmentSplit, sampled_parts};

/// The lat-long map's pixel seen in direction `dir` (unit, map space).
pub fn pixel_of(width: u32, height: u32, dir: DVec3) -> (u32, u32) {
    let u = 0.5 + dir.z.atan2(dir.x) / TAU;
    let v = dir.y.clamp(-1.0, 1.0).acos() / PI;
    let x = ((u * width as f64).max(0.0) as u32).min(width - 1);
    let y = ((v * height as f64).max(0.0) as u32).min(height - 1);
    (x, y)
}

/// The unit direction at map coordinates (u, v) in [0, 1]^2.
pub fn direction_at(u: f64, v: f64) -> DVec3 {
    let phi = TAU * (u - 0.5);
    let theta = PI * v;
    let s = theta.sin();
    DVec3::new(s * phi.cos(), theta.cos(), s * phi.sin())
}

/// The solid angle of row `y` of a `width` x `height` lat-long map's pixels.
pub fn pixel_solid_angle(width: u32, height: u32, y: u32) -> f64 {
    let (t0, t1) = (
        PI * y as f64 / height as f64,
        PI * (y + 1) as f64 / height as f64,
    );
    TAU / width as f64 * (t0.cos() - t1.cos())
}

/// The right-handed rotation about +y by `deg` degrees.
pub fn rotate_y(dir: DVec3, deg: f64) -> DVec3 {
    YTurn::degrees(deg).apply(dir)
}

/// A right-handed rotation about +y with its sine and cosine computed once: a shading
/// point turns several directions by the environment's rotation and back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct YTurn {
    sin: f64,
    cos: f64,
}

impl YTurn {
    pub fn degrees(deg: f64) -> Self {
        let (sin, cos) = deg.to_radians().sin_cos();
        Self { sin, cos }
    }

    /// `dir` turned by the rotation (map space to world space for an environment).
    #[inline]
    pub fn apply(self, dir: DVec3) -> DVec3 {
        let (s, c) = (self.sin, self.cos);
        DVec3::new(c * dir.x + s * dir.z, dir.y, -s * dir.x + c * dir.z)
    }

    /// `dir` turned back: `rotate_y(dir, -deg)` bit for bit (sine is odd).
    #[inline]
    pub fn undo(self, dir: DVec3) -> DVec3 {
        Self {
            sin: -self.sin,
            cos: self.cos,
        }
        .apply(dir)
    }
}

/// Why an image cannot be an environment map: empty, or a pixel that is negative or
/// not finite (it would make every sample that sees it invalid).
pub fn check_map(map: &Image) -> Option<String> {
    if map.width() == 0 || map.height() == 0 {
        return Some("the map has no pixels".into());
    }
    let w = map.width() as usize;
    map.pixels()
        .iter()
        .position(|p| p.iter().any(|c| !c.is_finite() || *c < 0.0))
        .map(|i| {
            format!(
                "pixel ({}, {}) is {:?}: environment radiance must be finite and >= 0",
                i % w,
                i / w,
                map.pixels()[i]
            )
        })
}
