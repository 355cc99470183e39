//! The shading frame at a hit: interpolated normal turned to the viewer, tangent
//! along +u (the SPMM convention). Every mode that shades the scene's surfaces uses
//! it, so they converge to the same image.

use glam::{DVec2, DVec3};

use crate::geometry::Hit;
use crate::scene::Scene;
use meso_materials::brdf::warp;

/// A surface point ready to shade.
#[derive(Clone, Copy, Debug)]
pub struct Shading {
    pub p: DVec3,
    /// Shading frame: tangent, bitangent, normal (facing the incoming ray).
    pub t: DVec3,
    pub b: DVec3,
    pub n: DVec3,
    pub uv: DVec2,
    pub material: usize,
}

impl Shading {
    /// The frame at `hit` for a ray travelling along `dir`.
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
        // Normals facing away from the viewer are flipped to the side the ray came from.
        if n.dot(ng) < 0.0 {
            n = -n;
        }
        let (uv0, uv1, uv2) = (mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2]);
        let uv = uv0 * w0 + uv1 * hit.b1 + uv2 * hit.b2;
        let (t, b) = tangent_frame(n, dpdu(p1 - p0, p2 - p0, uv1 - uv0, uv2 - uv0));
        Self {
            p,
            t,
            b,
            n,
            uv,
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

/// A triangle's dp/du from its edges `e1`, `e2` and their UV differences `d1`, `d2`
/// (zero where the UVs are degenerate). Shared with the biscale mode's vertex frames.
pub fn dpdu(e1: DVec3, e2: DVec3, d1: DVec2, d2: DVec2) -> DVec3 {
    let det = d1.x * d2.y - d2.x * d1.y;
    if det.abs() > 1e-20 {
        (e1 * d2.y - e2 * d1.y) / det
    } else {
        DVec3::ZERO
    }
}

/// Tangent (along increasing u: `dpdu` made orthogonal to `n`; any perpendicular where
/// it vanishes) and bitangent n x t: the SPMM convention of the shading frame.
pub fn tangent_frame(n: DVec3, dpdu: DVec3) -> (DVec3, DVec3) {
    let t = (dpdu - n * n.dot(dpdu))
        .try_normalize()
        .unwrap_or_else(|| warp::orthonormal_basis(n).0);
    (t, n.cross(t))
}

/// The power heuristic's weight of a strategy with pdf `a` against one with pdf `b`
/// (Veach 1997, ch. 9).
pub fn power_heuristic(a: f64, b: f64) -> f64 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}
