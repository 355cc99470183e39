//! What the adaptive mode knows of a surface point: the shading frame at a hit (the
//! same frame as the spmm mode's: interpolated normal turned to the viewer, tangent
//! along +u) and the materials it shades (analytic BRDFs and MERL tables: response
//! f cos_i, importance sampling and its pdf). Mirrors and SPMM packs are refused by
//! the mode's `supports`.

use glam::{DVec2, DVec3};

use meso_render::geometry::Hit;
use meso_render::scene::{Material, Scene};

/// A surface point ready to shade.
#[derive(Clone, Copy, Debug)]
pub struct Surface {
    pub p: DVec3,
    pub t: DVec3,
    pub b: DVec3,
    pub n: DVec3,
    pub material: usize,
}

impl Surface {
    /// The frame at `hit` for a ray travelling along `dir` (the spmm mode's rule, so
    /// both modes shade the same frame and converge to the same image).
    pub fn at(scene: &Scene, hit: &Hit, dir: DVec3) -> Self {
        let s = crate::trace::shading::shading_at(scene, hit, dir);
        Self {
            p: s.p,
            t: s.t,
            b: s.b,
            n: s.n,
            material: s.material,
        }
    }

    pub fn to_local(&self, w: DVec3) -> DVec3 {
        DVec3::new(w.dot(self.t), w.dot(self.b), w.dot(self.n))
    }

    pub fn to_world(&self, l: DVec3) -> DVec3 {
        self.t * l.x + self.b * l.y + self.n * l.z
    }
}

/// f(wi, wo) in RGB, 1/sr, local directions (no cosine); 0 for materials not shaded here.
pub fn brdf(material: &Material, wi: DVec3, wo: DVec3) -> DVec3 {
    match material {
        Material::Brdf { brdf, albedo } => *albedo * brdf.eval(wi, wo),
        Material::Merl { brdf, tint } => *tint * brdf.eval(wi, wo),
        _ => DVec3::ZERO,
    }
}

/// A direction drawn by the material's importance sampling for `wo` (local), with its
/// solid-angle pdf.
pub fn sample(material: &Material, wo: DVec3, u: DVec2) -> Option<(DVec3, f64)> {
    let s = match material {
        Material::Brdf { brdf, .. } => brdf.sample(wo, u),
        Material::Merl { brdf, .. } => brdf.sample(wo, u),
        _ => None,
    }?;
    (s.pdf > 0.0 && s.pdf.is_finite()).then_some((s.wi, s.pdf))
}

/// The pdf with which `sample` returns `wi` for `wo` (local).
pub fn pdf(material: &Material, wo: DVec3, wi: DVec3) -> f64 {
    match material {
        Material::Brdf { brdf, .. } => brdf.pdf(wo, wi),
        Material::Merl { brdf, .. } => brdf.pdf(wo, wi),
        _ => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_render::geometry::hit_parallelogram;

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
