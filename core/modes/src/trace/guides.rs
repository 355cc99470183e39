//! The denoiser's guides in the spmm mode (`render::denoise`): one ray through each
//! pixel's centre, and at its first hit the shading normal, the distance and a colour
//! the surface reflects.

use std::f64::consts::PI;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::SpmmMode;
use super::shading::Shader;
use meso_render::Guides;
use meso_render::scene::Material;

impl SpmmMode {
    /// A colour material `index` reflects, for guiding the denoiser only: the albedo
    /// of an analytic BRDF, a MERL table's albedo at normal view times its tint, a
    /// mirror's reflectance; `None` for packs and BTFs, whose colour varies per texel.
    fn uniform_albedo(&self, index: usize) -> Option<DVec3> {
        match &self.scene.materials[index] {
            Material::Brdf { albedo, .. } => Some(*albedo),
            Material::Merl { brdf, tint } => Some(*tint * brdf.albedo_at_normal()),
            Material::Mirror { reflectance } => Some(*reflectance),
            Material::Spmm { .. } | Material::Btf { .. } => None,
        }
    }

    pub(super) fn compute_guides(&self) -> Guides {
        let (w, h) = (self.film.width(), self.film.height());
        self.guides_of(&(0..w * h).collect::<Vec<_>>(), (w, h))
    }

    /// The guides of `pixels` (row-major indices into the film), as an image of
    /// `size` whose pixels are those, in order.
    pub(super) fn guides_of(&self, pixels: &[u32], (gw, gh): (u32, u32)) -> Guides {
        let w = self.film.width();
        let albedos: Vec<Option<DVec3>> = (0..self.scene.materials.len())
            .map(|i| self.uniform_albedo(i))
            .collect();
        let texels: Vec<([f32; 3], f32, [f32; 3])> = pixels
            .par_iter()
            .map(|&p| {
                let ray = self.camera.ray(p % w, p / w, DVec2::splat(0.5));
                let Some(hit) = self
                    .bvh
                    .closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY)
                else {
                    return ([0.0; 3], f32::INFINITY, [0.0; 3]);
                };
                let s = self.shading(&hit, ray.dir);
                let albedo =
                    albedos[s.material].unwrap_or_else(|| match &self.shaders[s.material] {
                        // The pack's texel seen and lit along the normal: pi x BTF(n, n).
                        Shader::Spmm { .. } | Shader::Table => self.response(&s, s.n, s.n) * PI,
                        Shader::Scene => DVec3::ZERO,
                    });
                (
                    s.n.as_vec3().to_array(),
                    hit.t as f32,
                    albedo.as_vec3().to_array(),
                )
            })
            .collect();
        Guides {
            width: gw,
            height: gh,
            normal: texels.iter().map(|t| t.0).collect(),
            depth: texels.iter().map(|t| t.1).collect(),
            albedo: texels.iter().map(|t| t.2).collect(),
        }
    }
}
