//! The `[environment]` of a scene: a lat-long map, its strength and its turn about +y
//! (docs/scenes.md). The map's convention, lookup and sampler are in `crate::environment`.

use std::sync::Arc;

use glam::DVec3;

use super::Problem;
use crate::environment::{YTurn, check_map, pixel_of, rotate_y};
use meso_materials::image::Image;

/// A lat-long environment as a scene holds it: the map, a radiance multiplier and a
/// turn about +y. What the unrotated map shows in direction d is seen in direction
/// R_y(angle) d (docs/scenes.md).
#[derive(Clone, Debug)]
pub struct Environment {
    pub map: Arc<Image>,
    /// Radiance multiplier, finite and >= 0.
    pub strength: f64,
    pub rotate_y_deg: f64,
    /// Combine map sampling with BRDF sampling by multiple importance sampling (the
    /// default); false samples the map alone (kept to measure what MIS gains).
    pub mis: bool,
}

impl Environment {
    /// Its rotation about +y (map space to world space).
    pub fn turn(&self) -> YTurn {
        YTurn::degrees(self.rotate_y_deg)
    }

    /// The map's radiance seen in world direction `dir` (unit), before `strength`.
    pub fn radiance_unit(&self, dir: DVec3) -> DVec3 {
        let d = rotate_y(dir, -self.rotate_y_deg);
        let (x, y) = pixel_of(self.map.width(), self.map.height(), d);
        let p = self.map.get(x, y);
        DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    }

    /// True if `other` lights the scene exactly as `self` up to `strength` (the same
    /// map, rotation and sampling): a strength edit keeps every sample.
    pub fn same_but_strength(&self, other: &Environment) -> bool {
        Arc::ptr_eq(&self.map, &other.map)
            && self.rotate_y_deg == other.rotate_y_deg
            && self.mis == other.mis
    }

    /// Why these values cannot light a scene, and the key at fault.
    pub fn problem(&self) -> Option<Problem> {
        if !(self.strength.is_finite() && self.strength >= 0.0) {
            Some(Problem::new(
                "strength",
                format!("{} must be finite and non-negative", self.strength),
            ))
        } else if !self.rotate_y_deg.is_finite() {
            Some(Problem::new(
                "rotate_y_deg",
                format!("{} is not finite", self.rotate_y_deg),
            ))
        } else {
            check_map(&self.map).map(|m| Problem::new("path", m))
        }
    }
}
