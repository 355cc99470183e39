//! The G-buffer of the adaptive mode (Bagher et al. 2013, section 3): one primary ray
//! through each pixel centre gives the surface (position, frame, material), its depth,
//! and its screen-space curvature (the normal's change per metre between neighbouring
//! pixels of the same mesh and depth), plus the screen-space terms of the up-sampling
//! weights (projected normal and cos theta_x).

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::upsample::{DEPTH_SIGMA, Guide};
use meso_render::geometry::{PinholeCamera, SceneBvh};
use meso_render::scene::Scene;
use meso_render::shading::Shading;

#[derive(Clone, Debug)]
pub struct GPixel {
    pub surface: Option<Shading>,
    pub mesh: usize,
    /// Direction of the centre ray (world).
    pub dir: DVec3,
    pub depth: f64,
    /// 1/m; 0 on planes and off surfaces.
    pub curvature: f64,
}

#[derive(Clone, Debug)]
pub struct GBuffer {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<GPixel>,
}

impl GBuffer {
    pub fn build(scene: &Scene, bvh: &SceneBvh, width: u32, height: u32) -> Self {
        let camera = PinholeCamera::new(&scene.camera, width, height);
        let mut pixels: Vec<GPixel> = (0..width * height)
            .into_par_iter()
            .map(|i| {
                let ray = camera.ray(i % width, i / width, DVec2::splat(0.5));
                match bvh.closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY) {
                    Some(hit) => GPixel {
                        surface: Some(Shading::at(scene, &hit, ray.dir)),
                        mesh: hit.mesh,
                        dir: ray.dir,
                        depth: hit.t,
                        curvature: 0.0,
                    },
                    None => GPixel {
                        surface: None,
                        mesh: usize::MAX,
                        dir: ray.dir,
                        depth: f64::INFINITY,
                        curvature: 0.0,
                    },
                }
            })
            .collect();
        let curvature: Vec<f64> = (0..width * height)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % width, i / width);
                let me = &pixels[i as usize];
                let Some(s) = &me.surface else { return 0.0 };
                let mut c: f64 = 0.0;
                for (nx, ny) in [
                    (x + 1, y),
                    (x, y + 1),
                    (x.wrapping_sub(1), y),
                    (x, y.wrapping_sub(1)),
                ] {
                    if nx >= width || ny >= height {
                        continue;
                    }
                    let o = &pixels[(ny * width + nx) as usize];
                    let Some(t) = &o.surface else { continue };
                    if o.mesh != me.mesh || (o.depth - me.depth).abs() > DEPTH_SIGMA * me.depth {
                        continue;
                    }
                    let dp = (t.p - s.p).length();
                    if dp > 0.0 {
                        c = c.max((t.n - s.n).length() / dp);
                    }
                }
                c
            })
            .collect();
        for (p, c) in pixels.iter_mut().zip(curvature) {
            p.curvature = c;
        }
        Self {
            width,
            height,
            pixels,
        }
    }

    /// The up-sampling weights' view of this buffer; `right` and `down` are the
    /// camera's screen axes in world space.
    pub fn guide(&self, right: DVec3, down: DVec3) -> Guide {
        let mut normal_dir = Vec::with_capacity(self.pixels.len());
        let mut cos_x = Vec::with_capacity(self.pixels.len());
        for p in &self.pixels {
            match &p.surface {
                Some(s) => {
                    let d = DVec2::new(s.n.dot(right), s.n.dot(down));
                    normal_dir.push(d.try_normalize().unwrap_or(DVec2::ZERO));
                    cos_x.push(s.n.dot(-p.dir).abs());
                }
                None => {
                    normal_dir.push(DVec2::ZERO);
                    cos_x.push(1.0);
                }
            }
        }
        Guide {
            width: self.width,
            height: self.height,
            depth: self.pixels.iter().map(|p| p.depth).collect(),
            normal_dir,
            cos_x,
        }
    }
}
