//! Environment lighting in the spmm mode: per shading point one direction drawn from
//! the map's importance sampler and one from the material (its BRDF sampler for
//! analytic BRDFs; the defensive cosine/uniform mixture for SPMM packs, whose pdf never
//! vanishes where the BTF does not), combined by multiple importance sampling with the
//! power heuristic (Veach 1997, ch. 9), each with a shadow ray through the whole
//! scene. With `mis = false` the map's sampler alone is used (still unbiased: its pdf
//! is positive wherever the map is). Adds to the environment layer for unit strength.

use glam::DVec3;

use super::shading::{Shader, Shading};
use super::{Path, SpmmMode};
use crate::environment::rotate_y;
use crate::render::layers::ENVIRONMENT;
use crate::scene::Material;

/// The power heuristic's weight of a strategy with pdf `a` against one with pdf `b`.
fn power_heuristic(a: f64, b: f64) -> f64 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

impl SpmmMode {
    /// The material's sampling pdf of world direction `wi` (0 where it never samples).
    fn material_pdf(&self, s: &Shading, wi: DVec3, wo: DVec3) -> f64 {
        let (li, lo) = (s.to_local(wi), s.to_local(wo));
        match (&self.scene.materials[s.material], &self.shaders[s.material]) {
            (Material::Brdf { brdf, .. }, _) => brdf.pdf(lo, li),
            (_, Shader::Spmm { .. }) => Shader::defensive_pdf(li),
            _ => 0.0,
        }
    }

    /// A direction drawn from the material for `wo`, with its pdf.
    fn material_sample(&self, s: &Shading, wo: DVec3, u: glam::DVec2) -> Option<(DVec3, f64)> {
        match (&self.scene.materials[s.material], &self.shaders[s.material]) {
            (Material::Brdf { brdf, .. }, _) => brdf
                .sample(s.to_local(wo), u)
                .map(|b| (s.to_world(b.wi), b.pdf)),
            (_, shader @ Shader::Spmm { .. }) => {
                let (local, pdf) = shader.hemisphere_sample(u);
                Some((s.to_world(local), pdf))
            }
            _ => None,
        }
    }

    /// Both environment samples of one shading point. Always draws four numbers, so
    /// a scene's other dimensions do not depend on whether it has an environment.
    pub(super) fn sample_environment(
        &self,
        s: &Shading,
        wo: DVec3,
        lift: DVec3,
        throughput: DVec3,
        path: &mut Path,
    ) {
        let (u_map, u_material) = (path.rng.next_2d(), path.rng.next_2d());
        let (Some(env), Some(sampler)) = (&self.scene.environment, &self.env_sampler) else {
            return;
        };
        // Strategy 1: the map.
        let e = sampler.sample(&env.map, u_map);
        let wi = rotate_y(e.dir, env.rotate_y_deg);
        if wi.dot(s.n) > 0.0 {
            path.counts.environment += 1;
            if !self.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
                let weight = if env.mis {
                    power_heuristic(e.pdf, self.material_pdf(s, wi, wo))
                } else {
                    1.0
                };
                path.out[ENVIRONMENT] +=
                    throughput * self.response(s, wi, wo) * e.radiance * (weight / e.pdf);
            }
        }
        if !env.mis {
            return;
        }
        // Strategy 2: the material.
        let Some((wi, pdf)) = self.material_sample(s, wo, u_material) else {
            return;
        };
        if wi.dot(s.n) <= 0.0 {
            return;
        }
        path.counts.environment += 1;
        if self.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
            return;
        }
        let map_pdf = sampler.pdf(rotate_y(wi, -env.rotate_y_deg));
        let weight = power_heuristic(pdf, map_pdf);
        path.out[ENVIRONMENT] +=
            throughput * self.response(s, wi, wo) * env.radiance_unit(wi) * (weight / pdf);
    }
}
