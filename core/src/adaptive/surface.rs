//! What the adaptive mode knows of a surface point: the shading frame at a hit (the
//! same frame as the spmm mode's: interpolated normal turned to the viewer, tangent
//! along +u) and the materials it shades (analytic BRDFs and MERL tables: response
//! f cos_i, importance sampling and its pdf). Mirrors and SPMM packs are refused by
//! the mode's `supports`.

use glam::{DVec2, DVec3};

use crate::brdf::warp;
use crate::geometry::Hit;
use crate::scene::{Material, Scene};

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
        let mesh = &scene.meshes[hit.mesh];
        let [i0, i1, i2] = mesh.indices[hit.triangle].map(|i| i as usize);
        let w0 = 1.0 - hit.b1 - hit.b2;
        let (p0, p1, p2) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
        let p = p0 * w0 + p1 * hit.b1 + p2 * hit.b2;
        let mut ng = (p1 - p0).cross(p2 - p0).normalize_or(DVec3::Y);
        if ng.dot(dir) > 0.0 {
            ng = -ng;
        }
        let mut n = (mesh.normals[i0] * w0 + mesh.normals[i1] * hit.b1 + mesh.normals[i2] * hit.b2)
            .normalize_or(ng);
        if n.dot(ng) < 0.0 {
            n = -n;
        }
        let (uv0, uv1, uv2) = (mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2]);
        let (e1, e2, d1, d2) = (p1 - p0, p2 - p0, uv1 - uv0, uv2 - uv0);
        let det = d1.x * d2.y - d2.x * d1.y;
        let dpdu = if det.abs() > 1e-20 {
            (e1 * d2.y - e2 * d1.y) / det
        } else {
            DVec3::ZERO
        };
        let t = (dpdu - n * n.dot(dpdu))
            .try_normalize()
            .unwrap_or_else(|| warp::orthonormal_basis(n).0);
        let b = n.cross(t);
        Self {
            p,
            t,
            b,
            n,
            material: mesh.material,
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

/// Where a ray from `origin` along unit `dir` meets the front of the parallelogram
/// `corner + a edge_u + b edge_v` (a, b in [0, 1], emitting towards edge_u x edge_v):
/// its distance and `cos_l area / r^2`, the reciprocal of the solid-angle pdf of a
/// uniform point on it.
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
    ((0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)).then(|| (t, facing / (t * t)))
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
