//! Light sampling in the spmm mode (Silva & Santos 2013, eq. 4-7): each point light
//! with one shadow ray; each area light with one shadow ray to a point drawn uniformly
//! on its area (in the area measure: L_e f cos_i cos_l / r^2 * A); ambient occlusion
//! with one ray limited to the ambient radius (pi L_a V f per cosine-distributed
//! sample). Each adds to its own film layer for unit emission.

use std::f64::consts::PI;

use glam::DVec3;

use super::shading::{Shader, Shading};
use super::{Path, SpmmMode};
use crate::render::layers::{AMBIENT, FIRST_LIGHT};
use crate::scene::Light;

impl SpmmMode {
    /// One shadow ray to each light; `lift` is the ray origin just off the surface.
    pub(super) fn sample_lights(
        &self,
        s: &Shading,
        wo: DVec3,
        lift: DVec3,
        throughput: DVec3,
        path: &mut Path,
    ) {
        for (k, light) in self.scene.lights.iter().enumerate() {
            // Both kinds draw two numbers, so the dimension layout does not depend on
            // which kinds the scene has.
            let u = path.rng.next_2d();
            let (q, geometry) = match *light {
                Light::Point { position, .. } => (position, None),
                Light::Area {
                    corner,
                    edge_u,
                    edge_v,
                    ..
                } => (
                    corner + edge_u * u.x + edge_v * u.y,
                    Some(edge_u.cross(edge_v)),
                ),
            };
            let to = q - s.p;
            let d2 = to.length_squared();
            let wi = to / d2.sqrt();
            let falloff = match geometry {
                None => 1.0 / d2,
                Some(cross) => {
                    // One-sided: the light emits towards edge_u x edge_v.
                    let area = cross.length();
                    let cos_l = -wi.dot(cross / area);
                    if cos_l <= 0.0 {
                        continue;
                    }
                    cos_l * area / d2
                }
            };
            let cos_i = wi.dot(s.n);
            if cos_i.is_nan() || cos_i <= 0.0 {
                continue;
            }
            path.counts.shadow += 1;
            if !self
                .bvh
                .occluded(lift, wi, 0.0, (q - lift).length() * (1.0 - 1e-6))
            {
                path.out[FIRST_LIGHT + k] += throughput * self.response(s, wi, wo) * falloff;
            }
        }
    }

    /// One ambient-occlusion ray (eq. 6-7). Draws its two numbers whether or not the
    /// scene has an ambient term, so toggling it keeps every other sample's numbers.
    pub(super) fn sample_ambient(
        &self,
        s: &Shading,
        wo: DVec3,
        lift: DVec3,
        throughput: DVec3,
        path: &mut Path,
    ) {
        let u = path.rng.next_2d();
        let Some(ambient) = &self.scene.ambient else {
            return;
        };
        let shader = &self.shaders[s.material];
        let (local, pdf) = shader.hemisphere_sample(u);
        if local.z <= 0.0 {
            return;
        }
        // 1 / pdf, written as the cosine case always was (pi / cos) to keep its bits.
        let weight = match shader {
            Shader::Scene => PI / local.z,
            Shader::Spmm { .. } => 1.0 / pdf,
        };
        let wi = s.to_world(local);
        path.counts.ambient += 1;
        if !self.bvh.occluded(lift, wi, 0.0, ambient.radius) {
            path.out[AMBIENT] += throughput * self.response(s, wi, wo) * weight;
        }
    }
}
