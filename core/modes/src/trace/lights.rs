//! Light sampling in the spmm mode (Silva & Santos 2013, eq. 4-7): up to `MANY_LIGHTS`
//! lights, each point light with one shadow ray and each area light with one shadow ray
//! to each of `light_samples` points drawn uniformly on its area (in the area measure:
//! A L_e f cos_i cos_l / r^2, each weighted 1 / light_samples); above, `LIGHT_SAMPLES x
//! light_samples` lights per shading point chosen by resampling
//! (`light_selection.rs`, shared with the biscale mode). Ambient occlusion: one ray limited to the ambient radius
//! (pi L_a V f per cosine-distributed sample). Each adds to its light's film layer.
//! On MERL materials each area light also gets a material sample, and the two are
//! combined by MIS (power heuristic) on the per-light path; the many-light path keeps
//! light samples alone.

use glam::DVec3;

use super::{Path, SpmmMode};
use meso_render::geometry::hit_parallelogram;
use meso_render::layers::AMBIENT;
use meso_render::light_selection::{LightSelection, ShadingPoint};
use meso_render::scene::Light;
use meso_render::shading::{Shading, power_heuristic, visible_light_point};

impl SpmmMode {
    /// One shadow ray to each point light and `light_samples` to each area light, or
    /// `LIGHT_SAMPLES x light_samples` chosen lights above `MANY_LIGHTS`; `lift` is
    /// the ray origin just off the surface.
    pub(super) fn sample_lights(
        &self,
        s: &Shading,
        wo: DVec3,
        lift: DVec3,
        throughput: DVec3,
        path: &mut Path,
    ) {
        if let Some(selection) = &self.light_selection {
            self.sample_chosen_lights(selection, s, wo, lift, throughput, path);
            return;
        }
        let n = self.core.scene.render.light_samples;
        for (k, light) in self.core.scene.lights.iter().enumerate() {
            // Both kinds draw the same numbers, so the dimension layout does not depend
            // on which kinds the scene has.
            let points = path.rng.next_2d_set(n);
            // Light samples of an area light meet a material sample by MIS where the
            // material's lobe can be narrower than the light (`ShadedMaterial::mis_with_area_lights`).
            let mis = matches!(light, Light::Area { .. }) && self.shaded(s).mis_with_area_lights();
            let directions = mis.then(|| path.rng.next_2d_set(n));
            // A point light is one exact sample; an area light's `n` share its weight
            // (times one for one sample, which keeps that image's bits).
            let (count, share) = match light {
                Light::Point { .. } => (1, throughput),
                Light::Area { .. } => (n, throughput * (1.0 / f64::from(n))),
            };
            for r in 0..count {
                if let Some(directions) = &directions {
                    self.sample_area_light_by_material(
                        k,
                        s,
                        wo,
                        lift,
                        share,
                        directions.get(r),
                        path,
                    );
                }
                self.sample_light_point(k, points.get(r), mis, s, wo, lift, share, path);
            }
        }
    }

    /// One shadow ray to light `k`: its position, or the point `u` on its area.
    #[allow(clippy::too_many_arguments)]
    fn sample_light_point(
        &self,
        k: usize,
        u: glam::DVec2,
        mis: bool,
        s: &Shading,
        wo: DVec3,
        lift: DVec3,
        throughput: DVec3,
        path: &mut Path,
    ) {
        let light = &self.core.scene.lights[k];
        let at = (s, lift);
        let Some((wi, falloff)) =
            visible_light_point(&self.core.bvh, light, u, at, &mut path.counts.shadow)
        else {
            return;
        };
        let target = self.light_targets[k];
        // Solid-angle pdf of this point: 1 / falloff.
        let weight = if mis {
            power_heuristic(1.0 / falloff, self.shaded(s).pdf(s, wi, wo))
        } else {
            1.0
        };
        // The factor is exactly one outside a bounded film's shared layer, so the
        // per-light path keeps its bits.
        path.out[target.layer] +=
            throughput * self.shaded(s).response(s, wi, wo) * (falloff * weight) * target.factor;
    }

    /// The material's strategy for area light `k`: a direction drawn from the BRDF,
    /// kept if it meets the light's front face unshadowed, weighted by the power
    /// heuristic against the light's solid-angle pdf (Veach 1997, ch. 9), from the
    /// pair `u`.
    #[allow(clippy::too_many_arguments)]
    fn sample_area_light_by_material(
        &self,
        k: usize,
        s: &Shading,
        wo: DVec3,
        lift: DVec3,
        throughput: DVec3,
        u: glam::DVec2,
        path: &mut Path,
    ) {
        let Light::Area {
            corner,
            edge_u,
            edge_v,
            ..
        } = self.core.scene.lights[k]
        else {
            return;
        };
        let Some((wi, pdf)) = self.shaded(s).sample(s, wo, u) else {
            return;
        };
        if wi.dot(s.n) <= 0.0 || pdf <= 0.0 {
            return;
        }
        let Some((distance, falloff)) = hit_parallelogram(s.p, wi, corner, edge_u, edge_v) else {
            return;
        };
        path.counts.shadow += 1;
        if self
            .core
            .bvh
            .occluded(lift, wi, 0.0, distance * (1.0 - 1e-6))
        {
            return;
        }
        let weight = power_heuristic(pdf, 1.0 / falloff);
        let target = self.light_targets[k];
        path.out[target.layer] +=
            throughput * self.shaded(s).response(s, wi, wo) * (weight / pdf) * target.factor;
    }

    /// `LIGHT_SAMPLES x light_samples` lights chosen by resampling
    /// (`LightSelection::add_chosen_lights`, shared with the biscale mode).
    fn sample_chosen_lights(
        &self,
        sel: &LightSelection,
        s: &Shading,
        wo: DVec3,
        lift: DVec3,
        throughput: DVec3,
        path: &mut Path,
    ) {
        let material = self.shaded(s);
        let at = ShadingPoint {
            s,
            wo,
            lift,
            material: &material,
            throughput,
        };
        sel.add_chosen_lights(
            &at,
            self.core.scene.render.light_samples,
            &self.core.bvh,
            &self.light_targets,
            path.rng,
            &mut path.counts.shadow,
            path.out,
        );
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
        let Some(ambient) = &self.core.scene.ambient else {
            return;
        };
        // Cosine-distributed, or drawn from a pack's texel (and a defensive share).
        let Some((wi, weight)) = self.shaded(s).ambient_sample(s, wo, u) else {
            return;
        };
        path.counts.ambient += 1;
        if !self.core.bvh.occluded(lift, wi, 0.0, ambient.radius) {
            path.out[AMBIENT] += throughput * self.shaded(s).response(s, wi, wo) * weight;
        }
    }
}
