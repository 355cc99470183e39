//! Environment lighting in the spmm mode: per shading point one direction drawn from
//! the map's importance sampler and one from the material (its BRDF sampler for
//! analytic BRDFs and MERL tables; the defensive cosine/uniform mixture for SPMM packs, whose pdf never
//! vanishes where the BTF does not), combined by multiple importance sampling with the
//! power heuristic (Veach 1997, ch. 9), each with a shadow ray through the whole
//! scene. With `mis = false` the map's sampler alone is used (still unbiased: its pdf
//! is positive wherever the map is). Adds to the environment layer for unit strength.

use glam::DVec3;

use super::{Path, SpmmMode};
use meso_render::layers::ENVIRONMENT;
use meso_render::shading::{Shading, power_heuristic};

impl SpmmMode {
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
        let (Some(env), Some(sampler)) = (&self.core.scene.environment, &self.env_sampler) else {
            return;
        };
        let material = self.shaded(s);
        // Strategy 1: the map.
        let turn = env.turn();
        let e = sampler.sample(&env.map, u_map);
        let wi = turn.apply(e.dir);
        if wi.dot(s.n) > 0.0 {
            path.counts.environment += 1;
            if !self.core.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
                let weight = if env.mis {
                    power_heuristic(e.pdf, material.pdf(s, wi, wo))
                } else {
                    1.0
                };
                path.out[ENVIRONMENT] +=
                    throughput * material.response(s, wi, wo) * e.radiance * (weight / e.pdf);
            }
        }
        if !env.mis {
            return;
        }
        // Strategy 2: the material.
        let Some((wi, pdf)) = material.sample(s, wo, u_material) else {
            return;
        };
        if wi.dot(s.n) <= 0.0 {
            return;
        }
        path.counts.environment += 1;
        if self.core.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
            return;
        }
        let (map_pdf, radiance) = sampler.pdf_and_radiance(&env.map, turn.undo(wi));
        let weight = power_heuristic(pdf, map_pdf);
        path.out[ENVIRONMENT] +=
            throughput * material.response(s, wi, wo) * radiance * (weight / pdf);
    }
}
