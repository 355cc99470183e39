//! Geometry every render mode and the editor share: the scene's triangles in a BVH
//! (closest-hit and occlusion queries, refitting), the pinhole camera's primary rays,
//! picking (what surface, texel and cluster lie under an image position) and the
//! weight brush built on it (which texels a dab covers).
//! Nothing here knows about films, layers or modes.

pub mod brush;
pub mod bvh;
pub mod camera;
pub mod pick;

pub use brush::{Brush, BrushUnits};
pub use bvh::{Hit, SceneBvh};

pub use camera::{PinholeCamera, Ray};
use glam::DVec3;
pub use pick::{Pick, pick};

/// Where the ray from `origin` along unit `dir` meets the front face of the
/// parallelogram `corner + a edge_u + b edge_v` (a, b in [0, 1], emitting towards
/// edge_u x edge_v): its distance and `cos_l area / r^2`, the reciprocal of the
/// solid-angle pdf of a uniform point on it.
pub fn hit_parallelogram(
    origin: DVec3,
    dir: DVec3,
    corner: DVec3,
    edge_u: DVec3,
    edge_v: DVec3,
) -> Option<(f64, f64)> {
    let normal = edge_u.cross(edge_v);
    let facing = -dir.dot(normal);
    if facing.is_nan() || facing <= 0.0 {
        return None;
    }
    let t = (origin - corner).dot(normal) / facing;
    if !(t > 0.0 && t.is_finite()) {
        return None;
    }
    let rel = origin + dir * t - corner;
    let n2 = normal.length_squared();
    let a = rel.cross(edge_v).dot(normal) / n2;
    let b = edge_u.cross(rel).dot(normal) / n2;
    if !((0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)) {
        return None;
    }
    // cos_l |N| / t^2 with cos_l = facing / |N|.
    Some((t, facing / (t * t)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ray_meets_the_front_of_a_unit_square_above_with_its_solid_angle_density() {
        // Square 1 m above the origin, facing down; straight up: distance 1 and
        // cos_l A / r^2 = 1.
        let (corner, eu, ev) = (DVec3::new(-0.5, 1.0, -0.5), DVec3::X, DVec3::Z);
        let (t, f) = hit_parallelogram(DVec3::ZERO, DVec3::Y, corner, eu, ev).expect("hit");
        assert!(
            (t - 1.0).abs() < 1e-12 && (f - 1.0).abs() < 1e-12,
            "{t} {f}"
        );
        // From above it is its back: no hit; beside it: no hit.
        assert!(hit_parallelogram(DVec3::new(0.0, 2.0, 0.0), -DVec3::Y, corner, eu, ev).is_none());
        assert!(hit_parallelogram(DVec3::new(2.0, 0.0, 0.0), DVec3::Y, corner, eu, ev).is_none());
    }
}
