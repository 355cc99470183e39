//! The bandwidth pass after each restart (sections 2-3): the G-buffer, then per pixel
//! eq. 3-6 and 9 over n_b light directions, the visibility and radiance guards, eq. 11's
//! levels and their min/max mip-maps. It runs in steps of rows so a frame can yield.

use super::*;
use crate::adaptive::gbuffer::GPixel;

/// The bandwidth buffer and what the frames read of the G-buffer.
pub struct Buffers {
    pub g: GBuffer,
    pub guide: Guide,
    /// Eq. 11 level per pixel.
    pub level: Vec<u32>,
    /// Eq. 9's sum per pixel (the bound of the paper, times N_p / 4 pi^2; eq. 10's
    /// for the pre-convolved variant): the overlays and the report's study.
    pub variance: Vec<f64>,
    /// The predicted standard deviation of one sample of the frames' estimator
    /// (luminance; `allocation.rs`), which sets N_p.
    pub sigma: Vec<f64>,
    /// Eq. 6 per pixel (samples per pixel).
    pub rate: Vec<f64>,
    /// The mean of the frames' estimator over the pass's directions per pixel
    /// (luminance, emissions applied; visibility left out but for the guard rays):
    /// what a pixel's first sample is measured against (`allocation::corrected_sigma`).
    pub mean: Vec<f64>,
    /// Max-filtered `sigma`, per level (level 0 = `sigma`).
    pub(super) sigma_mip: Vec<Vec<f64>>,
    /// Seconds of the G-buffer (part of `seconds`).
    pub gbuffer_seconds: f64,
    /// Seconds the pass took.
    pub seconds: f64,
}

/// The order in which each strategy other than the table's visits the bandwidth
/// pass's strata (`AdaptiveMode::strata_orders`).
pub(super) struct StrataOrders {
    pub(super) map: Vec<u32>,
    /// The second part of a split map (`map_parts`).
    pub(super) remainder: Vec<u32>,
    /// Per scene light.
    pub(super) lights: Vec<Vec<u32>>,
}

/// What the bandwidth pass finds at one pixel.
pub(super) struct PixelAnalysis {
    /// Eq. 5 at the eye.
    pub(super) nu: Bandwidth,
    /// Eq. 9's sum (eq. 10's for the pre-convolved variant) and eq. 9's.
    pub(super) eq9: [f64; 2],
    /// The visible share of the lambda weights (the visibility guard).
    pub(super) visible: f64,
    /// The frames' estimator over the n_b directions.
    pub(super) moments: allocation::Moments,
}

/// A per-level pyramid of `values` over blocks of 2^k pixels (top-left aligned),
/// reduced by `f`.
pub(super) fn mip(
    values: &[f64],
    w: u32,
    h: u32,
    top: u32,
    f: impl Fn(f64, f64) -> f64,
) -> Vec<Vec<f64>> {
    let mut out = vec![values.to_vec()];
    for k in 1..=top {
        let (pw, ph) = (w.div_ceil(1 << (k - 1)), h.div_ceil(1 << (k - 1)));
        let (nw, nh) = (w.div_ceil(1 << k), h.div_ceil(1 << k));
        let prev = &out[k as usize - 1];
        let mut next = vec![0.0; (nw * nh) as usize];
        for y in 0..nh {
            for x in 0..nw {
                let mut v: Option<f64> = None;
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (sx, sy) = (2 * x + dx, 2 * y + dy);
                    if sx < pw && sy < ph {
                        let p = prev[(sy * pw + sx) as usize];
                        v = Some(v.map_or(p, |a| f(a, p)));
                    }
                }
                next[(y * nw + x) as usize] = v.expect("a block has a first child");
            }
        }
        out.push(next);
    }
    out
}

/// The visibility guard, our addition to the paper (which ignores visibility): the
/// bandwidth pass traces a shadow ray along the first `GUARD_RAYS` of its n_b
/// directions per emitter (one stratum pattern for every pixel), and a pixel whose
/// visible share of the lambda weights differs from a neighbour's by more than
/// this is on a shadow or occluder edge that no bandwidth predicts; it is shaded at
/// level 0.
pub const VISIBILITY_STEP: f64 = 0.1;
/// Shadow rays per emitter and pixel of the visibility guard.
pub const GUARD_RAYS: u32 = 4;

/// The rate given to the pixels of mirrors and of the environment seen directly: far
/// above any pixel's, so eq. 11 puts them at level 0 (a finite number, so the buffers
/// stay finite).
const FULL_RATE: f64 = 1e12;

/// The radiance guard's floor: this share of the image's mean |radiance| (dark pixels'
/// relative steps are noise).
const DARK_SHARE: f64 = 1e-3;

/// True if pixel (x, y)'s visible share differs from a 4-neighbour's by more than
/// `VISIBILITY_STEP`.
pub(super) fn visibility_edge(visible: &[f64], w: u32, h: u32, x: u32, y: u32) -> bool {
    let v = visible[(y * w + x) as usize];
    [
        (x + 1, y),
        (x, y + 1),
        (x.wrapping_sub(1), y),
        (x, y.wrapping_sub(1)),
    ]
    .into_iter()
    .filter(|&(nx, ny)| nx < w && ny < h)
    .any(|(nx, ny)| (visible[(ny * w + nx) as usize] - v).abs() > VISIBILITY_STEP)
}

/// The relative step of the pass's mean radiance between 4-neighbours above which a
/// pixel is shaded at level 0 (our up-sampling guard: a highlight or reflection edge
/// that the bandwidth's 95th percentile averaged away, whose interpolation would cost
/// more squared error than the samples it saves).
pub const RADIANCE_STEP: f64 = 0.25;

/// True if pixel (x, y)'s mean radiance differs from a 4-neighbour's by more than
/// `RADIANCE_STEP` of the larger of the two (or of `floor`, for dark pixels).
pub(super) fn radiance_edge(mean: &[f64], w: u32, h: u32, x: u32, y: u32, floor: f64) -> bool {
    let v = mean[(y * w + x) as usize];
    [
        (x + 1, y),
        (x, y + 1),
        (x.wrapping_sub(1), y),
        (x, y.wrapping_sub(1)),
    ]
    .into_iter()
    .filter(|&(nx, ny)| nx < w && ny < h)
    .any(|(nx, ny)| {
        let n = mean[(ny * w + nx) as usize];
        (n - v).abs() > RADIANCE_STEP * n.abs().max(v.abs()).max(floor)
    })
}

/// The bandwidth pass so far.
pub(super) struct PassProgress {
    pub(super) g: GBuffer,
    pub(super) orders: StrataOrders,
    /// Per pixel of the rows analysed so far, row-major.
    pub(super) per_pixel: Vec<PixelAnalysis>,
    pub(super) gbuffer_seconds: f64,
    /// Seconds spent on it so far (a yielded pass pauses between rows).
    pub(super) seconds: f64,
}

impl AdaptiveMode {
    /// The bandwidth pass: G-buffer, then per pixel eq. 3-6 and 9 over n_b directions
    /// per emitter (visibility ignored, as in the paper), and eq. 11. The environment's
    /// directions are drawn by the material's importance sampling and the lights' by
    /// area, each weighted by 1 / pdf so that eq. 5's lambda and eq. 9's sum are
    /// estimates of integrals over the hemisphere. The same directions, with the
    /// frames' estimator's MIS weights, estimate the per-sample variance that the
    /// frames' allocation reads (`allocation.rs`).
    pub fn bandwidth_pass(&self) -> Buffers {
        let mut pass = self.begin_pass();
        self.analyse_rows(&mut pass, self.height());
        self.finish_pass(pass)
    }

    /// The pass's first step: the G-buffer and the strata.
    pub(super) fn begin_pass(&self) -> PassProgress {
        let start = Instant::now();
        let (w, h) = (self.width(), self.height());
        let g = GBuffer::build(&self.core.scene, &self.core.bvh, w, h);
        let gbuffer_seconds = start.elapsed().as_secs_f64();
        PassProgress {
            g,
            orders: self.strata_orders(),
            per_pixel: Vec::with_capacity((w * h) as usize),
            gbuffer_seconds,
            seconds: start.elapsed().as_secs_f64(),
        }
    }

    /// Analyses up to `rows` more rows of the pass. Every pixel is analysed: sharing
    /// one analysis per 2 x 2 block (as this pass once did) left the block's pixels
    /// one mean and one variance, which hid the footprint's steps inside blocks and
    /// cost most of the allocation's gain (on the dragon 3.3x with every pixel
    /// against 1.7x; docs/reports/adaptive).
    pub(super) fn analyse_rows(&self, pass: &mut PassProgress, rows: u32) {
        use rayon::prelude::*;
        let start = Instant::now();
        let w = self.width();
        let first = pass.per_pixel.len() as u32;
        let end = (first + rows.saturating_mul(w)).min(w * self.height());
        let (g, orders) = (&pass.g, &pass.orders);
        pass.per_pixel.par_extend(
            (first..end)
                .into_par_iter()
                .map(|i| self.pixel_bandwidth(g, i, orders)),
        );
        pass.seconds += start.elapsed().as_secs_f64();
    }

    /// The pass's last step, once every row is analysed: eq. 6 and 11 per pixel, the
    /// guards, the predicted deviations and their mip-map.
    pub(super) fn finish_pass(&self, pass: PassProgress) -> Buffers {
        let start = Instant::now();
        let (w, h) = (self.width(), self.height());
        let PassProgress {
            g,
            per_pixel,
            gbuffer_seconds,
            seconds,
            ..
        } = pass;
        debug_assert_eq!(per_pixel.len(), (w * h) as usize, "every row analysed");
        let (right, down) = self.screen_axes();
        let guide = g.guide(right, down);
        let (fx, fy) = self.fov();
        let rate: Vec<f64> = per_pixel
            .iter()
            .map(|p| operators::screen_rate(p.nu.y, fx, fy, w, h))
            .collect();
        let variance: Vec<f64> = per_pixel.iter().map(|p| p.eq9[0]).collect();
        let visible: Vec<f64> = per_pixel.iter().map(|p| p.visible).collect();
        let mean: Vec<f64> = per_pixel.iter().map(|p| p.moments.mean()).collect();
        let footprint = allocation::footprint_variance(&mean, w, h);
        // The pre-convolved variant takes the full variant's prediction: eq. 10's
        // smaller sum assumes an environment convolved with the whole lobe, and
        // scaling by it (a Lambertian's eq. 10 is 0) starved diffuse pixels that the
        // ladder, filtered at most to the lobe's rate, still leaves noisy.
        let sigma: Vec<f64> = per_pixel
            .iter()
            .zip(&footprint)
            .map(|(p, f)| (p.moments.variance() + f).sqrt())
            .collect();
        let dark =
            DARK_SHARE * mean.iter().map(|m| m.abs()).sum::<f64>() / mean.len().max(1) as f64;
        let level = rate
            .iter()
            .enumerate()
            .map(|(i, &b)| {
                let (x, y) = (i as u32 % w, i as u32 / w);
                if visibility_edge(&visible, w, h, x, y) || radiance_edge(&mean, w, h, x, y, dark) {
                    0
                } else {
                    operators::level(b, w, h)
                }
            })
            .collect();
        let top = self.top_level();
        let sigma_mip = mip(&sigma, w, h, top, f64::max);
        Buffers {
            g,
            guide,
            level,
            variance,
            sigma,
            rate,
            mean,
            sigma_mip,
            gbuffer_seconds,
            seconds: seconds + start.elapsed().as_secs_f64(),
        }
    }

    /// Eq. 5's bandwidth at the eye, eq. 9's sums, the visible share of the lambda
    /// weights (our visibility guard, `bandwidth_pass`) and the moments of the frames'
    /// estimator over the n_b directions, for pixel `i`.
    /// The order in which the environment map's strategy and each light's visit the
    /// pass's strata (the table's strategy visits them in order): permutations drawn
    /// once, the same for every pixel. The frames draw the strategies independently;
    /// pairing them at one stratum would add their correlation to the variance the
    /// allocation predicts.
    pub(super) fn strata_orders(&self) -> StrataOrders {
        let n_b = self.options.n_b;
        let order = |strategy: u64| -> Vec<u32> {
            let rng = SampleStream::new(&[self.core.scene.render.seed, STREAM, 0xBA4D, strategy]);
            let mut order: Vec<u32> = (0..n_b).collect();
            for i in (1..order.len()).rev() {
                let j = (rng.at(i as u64) * (i + 1) as f64) as usize;
                order.swap(i, j.min(i));
            }
            order
        };
        let lights = self.core.scene.lights.len() as u64;
        StrataOrders {
            map: order(0),
            remainder: order(1 + lights),
            lights: (0..self.core.scene.lights.len())
                .map(|l| order(1 + l as u64))
                .collect(),
        }
    }

    pub(super) fn pixel_bandwidth(
        &self,
        g: &GBuffer,
        i: u32,
        orders: &StrataOrders,
    ) -> PixelAnalysis {
        let px = &g.pixels[i as usize];
        let Some(s) = &px.surface else {
            return self.escaped(px);
        };
        let material = self.shaders.material(&self.core.scene, s.material, false);
        let quiet = PixelAnalysis {
            nu: DVec2::ZERO,
            eq9: [0.0; 2],
            visible: 1.0,
            moments: allocation::Moments::default(),
        };
        if material.specular().is_some() {
            // A mirror shows what it reflects, at any frequency: shaded at every pixel.
            return PixelAnalysis {
                nu: DVec2::new(0.0, FULL_RATE),
                ..quiet
            };
        }
        let Some(rates) = &self.materials[s.material] else {
            return quiet;
        };
        let wo = -px.dir;
        let lo = s.to_local(wo);
        if lo.z <= 0.0 {
            return quiet;
        }
        let n_b = self.options.n_b;
        let at = SurfacePoint {
            s,
            lift: s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0)),
            strata: Strata::new(self.core.scene.render.seed, n_b),
        };
        let mut paths = Paths {
            material,
            uv: s.uv,
            rates,
            lo,
            at_lo: LobeIndex::of(lo),
            curvature: px.curvature,
            depth: px.depth,
            preconvolved: self.options.preconvolved,
            paths: Vec::with_capacity(n_b as usize * (1 + self.core.scene.lights.len())),
            variance: 0.0,
            variance_full: 0.0,
            visible: 0.0,
            guarded: 0.0,
        };
        // The frames' estimator's value per direction k (luminance, emissions applied):
        // its strategies (map, table, light) at the k-th stratum, with its MIS weights.
        let mut value = vec![0.0; n_b as usize];
        // Table-drawn directions (cosine where the material draws none), shared by the
        // environment's bounces and the table strategy of the area lights.
        let drawn: Vec<Option<(DVec3, f64)>> = (0..n_b)
            .map(|k| {
                let u = at.strata.at(k);
                let (li, pdf) = drawn(&material, s.uv, lo, u).unwrap_or_else(|| {
                    let li = warp::cosine_hemisphere(u);
                    (li, li.z / std::f64::consts::PI)
                });
                (pdf > 0.0 && li.z > 0.0).then_some((li, pdf))
            })
            .collect();
        self.environment_paths(&at, &drawn, orders, &mut paths, &mut value);
        self.light_paths(&at, &drawn, orders, &mut paths, &mut value);
        self.point_light_paths(&at, &mut paths, &mut value);
        self.ambient_paths(&at, wo, &mut paths, &mut value);
        paths.variance /= n_b as f64;
        paths.variance_full /= n_b as f64;
        let mut moments = allocation::Moments::default();
        for v in value {
            moments.add(v);
        }
        let share = if paths.guarded > 0.0 {
            paths.visible / paths.guarded
        } else {
            1.0
        };
        PixelAnalysis {
            nu: operators::weighted(&paths.paths),
            eq9: [paths.variance, paths.variance_full],
            visible: share,
            moments,
        }
    }

    /// A ray that leaves the scene sees the environment directly (no bounce): such a
    /// pixel is shaded at level 0 (a sample is one ray), since up-sampling the sky from
    /// coarse sites smeared its bright parts (the teapot's first frames stalled at the
    /// image's edge). A constant background is up-sampled.
    fn escaped(&self, px: &GPixel) -> PixelAnalysis {
        let mut moments = allocation::Moments::default();
        let nu = match (&self.core.scene.background, &self.core.scene.environment) {
            (meso_render::scene::Background::FromEnvironment, Some(_)) => FULL_RATE,
            _ => 0.0,
        };
        if let Some((layer, radiance)) = layers::escaped(&self.core.scene, px.dir) {
            let weight = self.core.layers.weights(&self.core.scene)[layer];
            moments.add((radiance * weight).dot(LUMINANCE));
        }
        PixelAnalysis {
            nu: DVec2::new(0.0, nu),
            eq9: [0.0; 2],
            visible: 1.0,
            moments,
        }
    }

    /// The environment's paths: BRDF-importance-sampled directions (so a sharp lobe is
    /// seen by a few of the n_b directions), and the estimator's strategy for each part
    /// of the map at its own strata.
    fn environment_paths(
        &self,
        at: &SurfacePoint,
        drawn: &[Option<(DVec3, f64)>],
        orders: &StrataOrders,
        paths: &mut Paths,
        value: &mut [f64],
    ) {
        let (Some(env), Some(env_bw)) = (&self.core.scene.environment, &self.env_bandwidth) else {
            return;
        };
        let (s, material, lo) = (at.s, paths.material, paths.lo);
        let turn = env.turn();
        let map_parts = self.map_parts();
        let parts: &[MapPart] = match &map_parts {
            Some((parts, n)) => &parts[..*n],
            None => &[],
        };
        for (k, d) in drawn.iter().enumerate() {
            let Some((li, pdf)) = *d else { continue };
            let wi = s.to_world(li);
            // One turn into the map, and one pixel lookup per part for both its
            // radiance and its pdf.
            let in_map = turn.undo(wi);
            let mut lookups = [(0.0, DVec3::ZERO); 2];
            for (lookup, part) in lookups.iter_mut().zip(parts) {
                *lookup = part.sampler.pdf_and_radiance(part.map, in_map);
            }
            let lookups = &lookups[..parts.len()];
            let full = if parts.is_empty() {
                env.radiance_unit(wi)
            } else {
                lookups.iter().map(|l| l.1).sum()
            };
            let luminance = full.dot(LUMINANCE);
            let radiance = luminance * env.strength;
            let nu_a = env_bw.rate_in_map(in_map);
            let seen = (k < GUARD_RAYS as usize)
                .then(|| !self.core.bvh.occluded(at.lift, wi, 0.0, f64::INFINITY));
            let lambda = paths.bounce(li, DVec2::new(0.0, nu_a), 0.0, radiance, 1.0 / pdf, seen);
            if env.mis && luminance > 0.0 {
                // Each part's share of lambda, weighted against its own strategy.
                value[k] += lookups
                    .iter()
                    .map(|&(map_pdf, r)| {
                        lambda * (r.dot(LUMINANCE) / luminance) * power(pdf, map_pdf)
                    })
                    .sum::<f64>();
            }
        }
        for (j, part) in parts.iter().enumerate() {
            let order = if j == 0 {
                &orders.map
            } else {
                &orders.remainder
            };
            for (k, v) in value.iter_mut().enumerate() {
                let e = part.sampler.sample(part.map, at.strata.at(order[k]));
                let wi = turn.apply(e.dir);
                let li = s.to_local(wi);
                if li.z <= 0.0 || e.pdf <= 0.0 {
                    continue;
                }
                let weight = if env.mis {
                    power(e.pdf, material.pdf_local(s.uv, li, lo))
                } else {
                    1.0
                };
                let f = material.response_local(s.uv, li, lo).dot(LUMINANCE);
                let lambda = f * e.radiance.dot(LUMINANCE) * env.strength * weight / e.pdf;
                *v += lambda;
                // Guards along the map's own directions too: they find the sun where
                // the frames' map samples find it, so its shadow's edge on a diffuse
                // floor (which the material's directions rarely reach) is not
                // up-sampled over.
                if k < GUARD_RAYS as usize {
                    paths.guarded += lambda;
                    if !self.core.bvh.occluded(at.lift, wi, 0.0, f64::INFINITY) {
                        paths.visible += lambda;
                    }
                }
            }
        }
    }

    /// The area lights' paths: points on each light at the strata of its order, and
    /// for MERL materials the table's strategy for the light, as the frames draw it.
    fn light_paths(
        &self,
        at: &SurfacePoint,
        drawn: &[Option<(DVec3, f64)>],
        orders: &StrataOrders,
        paths: &mut Paths,
        value: &mut [f64],
    ) {
        let (s, material, lo) = (at.s, paths.material, paths.lo);
        let merl = material.mis_with_area_lights();
        for (index, (light, bw)) in self
            .core
            .scene
            .lights
            .iter()
            .zip(&self.light_bandwidth)
            .enumerate()
        {
            let (
                Light::Area {
                    corner,
                    edge_u,
                    edge_v,
                    radiance,
                },
                Some(bw),
            ) = (*light, bw)
            else {
                continue;
            };
            let cross = edge_u.cross(edge_v);
            let area = cross.length();
            let emitted = radiance.dot(LUMINANCE);
            for k in 0..self.options.n_b {
                let u = at.strata.at(orders.lights[index][k as usize]);
                let q = corner + edge_u * u.x + edge_v * u.y;
                let to = q - s.p;
                let d2 = to.length_squared();
                let d = d2.sqrt();
                let wi = to / d;
                let cos_l = -wi.dot(cross / area);
                let li = s.to_local(wi);
                if cos_l <= 0.0 || li.z <= 0.0 {
                    continue;
                }
                let falloff = cos_l * area / d2;
                let seen = (k < GUARD_RAYS).then(|| {
                    !self
                        .core
                        .bvh
                        .occluded(at.lift, wi, 0.0, (q - at.lift).length() * (1.0 - 1e-6))
                });
                let lambda = paths.bounce(
                    li,
                    DVec2::new(bw.rate(u.x, u.y), 0.0),
                    d,
                    emitted,
                    falloff,
                    seen,
                );
                let weight = if merl {
                    power(1.0 / falloff, material.pdf_local(s.uv, li, lo))
                } else {
                    1.0
                };
                value[k as usize] += lambda * weight;
            }
            if merl {
                for (k, d) in drawn.iter().enumerate() {
                    let Some((li, pdf)) = *d else { continue };
                    let wi = s.to_world(li);
                    if let Some((_, falloff)) =
                        meso_render::geometry::hit_parallelogram(s.p, wi, corner, edge_u, edge_v)
                    {
                        let f = material.response_local(s.uv, li, lo).dot(LUMINANCE);
                        value[k] += emitted * f / pdf * power(pdf, 1.0 / falloff);
                    }
                }
            }
        }
    }
}

impl AdaptiveMode {
    /// The point lights' paths: one exact direction each, always guarded (its shadow
    /// is the only thing that can change between neighbours), with no variance (the
    /// frames take it exactly) and no incident bandwidth of its own (a delta's
    /// spectrum has no bound; its edges are the visibility and radiance guards').
    fn point_light_paths(&self, at: &SurfacePoint, paths: &mut Paths, value: &mut [f64]) {
        let s = at.s;
        for light in &self.core.scene.lights {
            let Light::Point { intensity, .. } = *light else {
                continue;
            };
            let Some(PointOnLight { q, wi, falloff }) = point_on_light(light, DVec2::ZERO, s.p)
            else {
                continue;
            };
            let li = s.to_local(wi);
            if li.z <= 0.0 {
                continue;
            }
            let d = (q - s.p).length();
            let seen =
                !self
                    .core
                    .bvh
                    .occluded(at.lift, wi, 0.0, (q - at.lift).length() * (1.0 - 1e-6));
            let emitted = intensity.dot(LUMINANCE);
            let lambda = paths.exact(li, d, emitted, falloff, seen);
            if seen {
                value.iter_mut().for_each(|v| *v += lambda);
            }
        }
    }

    /// The ambient term's paths: the frames' ambient directions at the n_b strata,
    /// each occluded or not within the radius (the first `GUARD_RAYS` guarded), of
    /// constant radiance.
    fn ambient_paths(&self, at: &SurfacePoint, wo: DVec3, paths: &mut Paths, value: &mut [f64]) {
        let Some(ambient) = &self.core.scene.ambient else {
            return;
        };
        let s = at.s;
        let radiance = ambient.radiance.dot(LUMINANCE);
        for (k, v) in value.iter_mut().enumerate() {
            let Some((wi, weight)) = paths.material.ambient_sample(s, wo, at.strata.at(k as u32))
            else {
                continue;
            };
            let open = !self.core.bvh.occluded(at.lift, wi, 0.0, ambient.radius);
            let seen = (k < GUARD_RAYS as usize).then_some(open);
            let lambda = paths.bounce(s.to_local(wi), DVec2::ZERO, 0.0, radiance, weight, seen);
            if open {
                *v += lambda;
            }
        }
    }
}

#[cfg(feature = "gpu")]
impl AdaptiveMode {
    /// What the device's bandwidth pass reads besides the scene: this pass's rules,
    /// strata (`orders` from `strata_orders`) and the rate tables of the materials,
    /// the environment and the lights.
    pub(super) fn pass_tables<'a>(&'a self, orders: &'a StrataOrders) -> meso_gpu::PassTables<'a> {
        let n_b = self.options.n_b;
        let shift = Strata::new(self.core.scene.render.seed, n_b).shift;
        let (fx, fy) = self.fov();
        meso_gpu::PassTables {
            n_b,
            strata_shift: [shift.x, shift.y],
            fov: [fx, fy],
            rules: meso_gpu::PassRules {
                guard_rays: GUARD_RAYS,
                visibility_step: VISIBILITY_STEP,
                radiance_step: RADIANCE_STEP,
                full_rate: FULL_RATE,
                min_cos: operators::MIN_COS,
                depth_sigma: crate::adaptive::upsample::DEPTH_SIGMA,
                dark_share: DARK_SHARE,
                grid: crate::adaptive::bandwidth::GRID as u32,
                light_res: crate::adaptive::bandwidth::LIGHT_RES as u32,
            },
            map_order: &orders.map,
            remainder_order: &orders.remainder,
            light_orders: orders.lights.iter().map(Vec::as_slice).collect(),
            material_rates: self
                .materials
                .iter()
                .map(|m| m.as_deref().map(MaterialBandwidth::rates))
                .collect(),
            environment_rates: self
                .env_bandwidth
                .as_ref()
                .filter(|_| self.core.scene.environment.is_some())
                .map(EnvironmentBandwidth::table),
            light_rates: self
                .light_bandwidth
                .iter()
                .map(|b| b.as_ref().map(LightBandwidth::rates))
                .collect(),
        }
    }
}

/// The surface point one pixel's paths leave from.
struct SurfacePoint<'a> {
    s: &'a Shading,
    /// The point lifted off the surface for shadow rays.
    lift: DVec3,
    strata: Strata,
}

/// The n_b strata of the unit square, shifted by one offset for every pixel:
/// neighbours see the same strata, so a change of visibility between them is the
/// scene's, not the sampling's.
struct Strata {
    side: u32,
    shift: DVec2,
}

impl Strata {
    fn new(seed: u64, n_b: u32) -> Self {
        let rng = SampleStream::new(&[seed, STREAM, 0xBA4D]);
        Self {
            side: (n_b as f64).sqrt().ceil() as u32,
            shift: DVec2::new(rng.at(0), rng.at(1)),
        }
    }

    /// The centre of stratum `k`, shifted.
    fn at(&self, k: u32) -> DVec2 {
        let side = self.side;
        let u = DVec2::new(
            ((k % side) as f64 + 0.5) / side as f64,
            ((k / side) as f64 + 0.5) / side as f64,
        ) + self.shift;
        DVec2::new(u.x.fract(), u.y.fract())
    }
}

/// The paths the pass follows from one surface point and what they add up to: eq. 5's
/// weighted bandwidths, eq. 9's variance (with and without the preconvolved
/// environment) and the share of the guarded paths that is visible.
struct Paths<'a> {
    material: ShadedMaterial<'a>,
    /// The texture position of the surface point.
    uv: DVec2,
    rates: &'a MaterialBandwidth,
    lo: DVec3,
    at_lo: LobeIndex,
    curvature: f64,
    depth: f64,
    preconvolved: bool,
    /// Eq. 5's lambda (without the common 1 / n_b: eq. 5 is a ratio) and bandwidth
    /// of each path.
    paths: Vec<(f64, Bandwidth)>,
    variance: f64,
    variance_full: f64,
    visible: f64,
    guarded: f64,
}

impl Paths<'_> {
    /// A path the frames take exactly (a point light): its lambda and bandwidth, and
    /// its guard, but no share of eq. 9's variance.
    fn exact(&mut self, li: DVec3, d_light: f64, radiance: f64, weight: f64, seen: bool) -> f64 {
        let lo = self.lo;
        let f = self.material.response_local(self.uv, li, lo).dot(LUMINANCE);
        let b = Bounce {
            cos_i: li.z,
            cos_o: lo.z,
            curvature: self.curvature,
            rho: self.rates.rate_of(LobeIndex::of(li), self.at_lo),
        };
        let nu = operators::one_bounce(DVec2::ZERO, d_light, &b, self.depth);
        let lambda = radiance * f * weight;
        self.paths.push((lambda, nu));
        self.guarded += lambda;
        if seen {
            self.visible += lambda;
        }
        lambda
    }

    /// One path from a light direction `li` (local) with incident bandwidth `l_in` at
    /// distance `d_light`, bounced to the eye; returns its lambda. `seen`: whether a
    /// guard ray found it unoccluded (`None`: not a guard path).
    fn bounce(
        &mut self,
        li: DVec3,
        l_in: Bandwidth,
        d_light: f64,
        radiance: f64,
        weight: f64,
        seen: Option<bool>,
    ) -> f64 {
        let lo = self.lo;
        let f = self.material.response_local(self.uv, li, lo).dot(LUMINANCE);
        let at_li = LobeIndex::of(li);
        let b = Bounce {
            cos_i: li.z,
            cos_o: lo.z,
            curvature: self.curvature,
            rho: self.rates.rate_of(at_li, self.at_lo),
        };
        let nu = operators::one_bounce(l_in, d_light, &b, self.depth);
        let lambda = radiance * f * weight;
        self.paths.push((lambda, nu));
        if let Some(seen) = seen {
            self.guarded += lambda;
            if seen {
                self.visible += lambda;
            }
        }
        let incident = operators::transport(l_in, d_light).y.abs();
        let chi = radiance * f;
        let rho_view = self.rates.rate_of(self.at_lo, at_li);
        self.variance +=
            operators::variance_term(incident, rho_view, chi, self.preconvolved) * weight;
        self.variance_full += operators::variance_term(incident, rho_view, chi, false) * weight;
        lambda
    }
}
