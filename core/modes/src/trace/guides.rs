//! The denoiser's guides in the spmm mode (`render::denoise`): one ray through each
//! pixel's centre, and at its first hit the shading normal, the distance and a colour
//! the surface reflects.

use glam::DVec2;
use rayon::prelude::*;

use super::SpmmMode;
use meso_render::Guides;
use meso_render::shading::Shading;

impl SpmmMode {
    pub(super) fn compute_guides(&self) -> Guides {
        let (w, h) = (self.core.film.width(), self.core.film.height());
        self.guides_of(&(0..w * h).collect::<Vec<_>>(), (w, h))
    }

    /// The guides of `pixels` (row-major indices into the film), as an image of
    /// `size` whose pixels are those, in order.
    pub(super) fn guides_of(&self, pixels: &[u32], (gw, gh): (u32, u32)) -> Guides {
        let w = self.core.film.width();
        let texels: Vec<([f32; 3], f32, [f32; 3])> = pixels
            .par_iter()
            .map(|&p| {
                let ray = self.core.camera.ray(p % w, p / w, DVec2::splat(0.5));
                let Some(hit) = self
                    .core
                    .bvh
                    .closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY)
                else {
                    return ([0.0; 3], f32::INFINITY, [0.0; 3]);
                };
                let s = Shading::at(&self.core.scene, &hit, ray.dir);
                let albedo = self.shaded(&s).albedo(&s);
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
