//! The frames: which pixels a frame shades and with how many samples (`Plan`), the
//! samples themselves (lights, environment, MIS), the frame loop in yielding tiles and
//! the preview before the first frame.

use super::pass::mip;
use super::*;

/// Which pixels a frame shades: per pixel, 0 (up-sampled) or its sample count.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Per pixel: the level of the leaf block it heads, or `None` if it is up-sampled.
    pub site_level: Vec<Option<u32>>,
    pub samples: Vec<u32>,
}

impl AdaptiveMode {
    /// Which pixels frame `frame` shades and with how many samples.
    pub fn plan_frame(&self, b: &Buffers, frame: u32) -> Plan {
        let (w, h) = (self.width(), self.height());
        let top = self.top_level();
        let drop = frame / self.options.refine_frames;
        let eff: Vec<f64> = b
            .level
            .iter()
            .map(|&l| l.saturating_sub(drop) as f64)
            .collect();
        let min_mip = mip(&eff, w, h, top, f64::min);
        let n = (w * h) as usize;
        let mut site_level = vec![None; n];
        for y in 0..h {
            for x in 0..w {
                // The leaf holding the pixel: the largest k with min over its 2^k block
                // >= k (monotone in k: the block's min falls as k rises).
                let mut leaf = 0;
                for k in (0..=top).rev() {
                    let bw = w.div_ceil(1 << k);
                    if min_mip[k as usize][((y >> k) * bw + (x >> k)) as usize] >= k as f64 {
                        leaf = k;
                        break;
                    }
                }
                let i = (y * w + x) as usize;
                if x % (1 << leaf) == 0 && y % (1 << leaf) == 0 {
                    site_level[i] = Some(leaf);
                } else if upsample::is_edge(x, y, w, h) {
                    // Parents for the pixels near the far edges (`upsample::far_parent`).
                    site_level[i] = Some(0);
                } else {
                    let k = upsample::level_of_pixel(x, y, top);
                    if !upsample::has_parents(&b.guide, x, y, k) {
                        site_level[i] = Some(0);
                    }
                }
            }
        }
        // Samples in proportion to the block's largest predicted standard deviation
        // (`allocation.rs`), `mean_samples` per site on average, at least
        // `min_share` of that, dithered over frames.
        let block_sigma = |i: usize, k: u32| {
            let (x, y) = (i as u32 % w, i as u32 / w);
            let bw = w.div_ceil(1 << k);
            let predicted = b.sigma_mip[k as usize][((y >> k) * bw + (x >> k)) as usize];
            allocation::corrected_sigma(predicted, b.mean[i], &self.moments[i])
        };
        let (mut sum, mut count) = (0.0, 0usize);
        for (i, s) in site_level.iter().enumerate() {
            if let Some(k) = s {
                sum += block_sigma(i, *k);
                count += 1;
            }
        }
        let mean_sigma = if count > 0 { sum / count as f64 } else { 0.0 };
        let spf = f64::from(self.core.samples_per_frame);
        let mean = self.options.mean_samples * spf;
        let max = f64::from(self.options.max_samples) * spf;
        let floor = self.options.min_share * mean;
        let samples = site_level
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let Some(k) = s else { return 0 };
                let rate = if mean_sigma > 0.0 {
                    (mean * block_sigma(i, *k) / mean_sigma).clamp(floor, max)
                } else {
                    mean
                };
                let n = allocation::dithered(rate, frame, allocation::phase(i));
                // A site without a value yet takes one now: its children read it.
                if self.own[i] == 0 { n.max(1) } else { n }
            })
            .collect();
        Plan {
            site_level,
            samples,
        }
    }

    /// One sample of pixel (x, y), `index` of its sequence, with the scene's
    /// emissions applied (what the film's resolve sums): the reports' variance study.
    pub fn sample_value(&self, x: u32, y: u32, index: u64) -> DVec3 {
        let weights = self.core.layers.weights(&self.core.scene);
        let mut out = vec![DVec3::ZERO; self.core.film.layers()];
        let mut counts = RayCounts::default();
        self.sample_into(x, y, index, &mut out, &mut counts);
        out.iter().zip(&weights).map(|(o, w)| *o * *w).sum()
    }

    /// One sample of pixel (x, y), per film layer for unit emission.
    pub(super) fn sample_into(
        &self,
        x: u32,
        y: u32,
        index: u64,
        out: &mut [DVec3],
        counts: &mut RayCounts,
    ) -> u64 {
        let pixel = u64::from(y) * u64::from(self.width()) + u64::from(x);
        // The scene's sampler (Sobol by default), sample `index` of this pixel: each
        // pixel's own samples are consecutive points of its sequence.
        let render = &self.core.scene.render;
        let mut rng = SampleStream::for_sample(render.sampler, render.seed ^ STREAM, index, pixel);
        let mut ray = self.core.camera.ray(x, y, rng.next_2d());
        counts.primary += 1;
        // Mirrors reflect the ray, as in the spmm mode, up to the scene's depth; what
        // the path then gathers is scaled by their reflectances.
        let mut through = (DVec3::ONE, 0u64);
        let mut depth = 0;
        let (s, material) = loop {
            let Some(hit) = self
                .core
                .bvh
                .closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY)
            else {
                if let Some((layer, radiance)) = layers::escaped(&self.core.scene, ray.dir) {
                    out[layer] += radiance;
                }
                return scaled(out, through);
            };
            let s = Shading::at(&self.core.scene, &hit, ray.dir);
            let material = self.shaders.material(&self.core.scene, s.material, false);
            let Some(reflectance) = material.specular() else {
                break (s, material);
            };
            through.1 |= material_bit(s.material);
            if depth >= self.core.scene.render.max_specular_depth {
                return scaled(out, through);
            }
            depth += 1;
            counts.specular += 1;
            through.0 *= reflectance;
            let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
            ray = meso_render::geometry::Ray {
                origin: lift,
                dir: ray.dir - 2.0 * ray.dir.dot(s.n) * s.n,
            };
        };
        let wo = -ray.dir;
        let lo = s.to_local(wo);
        let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
        // MERL lobes can be far narrower than a light: their area lights are sampled by
        // light and table samples with MIS, as the spmm mode does.
        let mis = material.mis_with_area_lights();
        for (k, light) in self.core.scene.lights.iter().enumerate() {
            let u = rng.next_2d();
            let Light::Area {
                corner,
                edge_u,
                edge_v,
                ..
            } = *light
            else {
                continue;
            };
            let q = corner + edge_u * u.x + edge_v * u.y;
            let to = q - s.p;
            let d2 = to.length_squared();
            let wi = to / d2.sqrt();
            let cross = edge_u.cross(edge_v);
            let area = cross.length();
            let cos_l = -wi.dot(cross / area);
            let cos_i = wi.dot(s.n);
            if cos_l <= 0.0 || cos_i.is_nan() || cos_i <= 0.0 {
                continue;
            }
            let falloff = cos_l * area / d2;
            counts.shadow += 1;
            if !self
                .core
                .bvh
                .occluded(lift, wi, 0.0, (q - lift).length() * (1.0 - 1e-6))
            {
                let target = self.light_targets[k];
                let li = s.to_local(wi);
                let weight = if mis {
                    power(1.0 / falloff, material.pdf_local(s.uv, li, lo))
                } else {
                    1.0
                };
                let f = material.response_local(s.uv, li, lo);
                out[target.layer] += f * falloff * weight * target.factor;
            }
        }
        if mis {
            // The table's strategy for each area light, as the spmm mode draws it.
            for (k, light) in self.core.scene.lights.iter().enumerate() {
                let u = rng.next_2d();
                let Light::Area {
                    corner,
                    edge_u,
                    edge_v,
                    ..
                } = *light
                else {
                    continue;
                };
                let Some((li, pdf)) = drawn(&material, s.uv, lo, u) else {
                    continue;
                };
                let wi = s.to_world(li);
                if wi.dot(s.n) <= 0.0 {
                    continue;
                }
                let Some((distance, falloff)) =
                    meso_render::geometry::hit_parallelogram(s.p, wi, corner, edge_u, edge_v)
                else {
                    continue;
                };
                counts.shadow += 1;
                if self
                    .core
                    .bvh
                    .occluded(lift, wi, 0.0, distance * (1.0 - 1e-6))
                {
                    continue;
                }
                let weight = power(pdf, 1.0 / falloff);
                let target = self.light_targets[k];
                out[target.layer] +=
                    material.response_local(s.uv, li, lo) * (weight / pdf) * target.factor;
            }
        }
        self.sample_environment(&s, material, lo, lift, &mut rng, out, counts);
        self.sample_point_lights_and_ambient(&s, material, (wo, lift), &mut rng, out, counts);
        scaled(out, (through.0, through.1 | material_bit(s.material)))
    }

    /// Point lights (one exact shadow ray each) and the ambient term (one direction of
    /// the shading core's ambient sampling, occluded within its radius), as the spmm
    /// mode estimates them.
    fn sample_point_lights_and_ambient(
        &self,
        s: &Shading,
        material: ShadedMaterial<'_>,
        (wo, lift): (DVec3, DVec3),
        rng: &mut SampleStream,
        out: &mut [DVec3],
        counts: &mut RayCounts,
    ) {
        let scene = &self.core.scene;
        for (k, light) in scene.lights.iter().enumerate() {
            if !matches!(light, Light::Point { .. }) {
                continue;
            }
            let at = (s, lift);
            let bvh = &self.core.bvh;
            if let Some((wi, falloff)) =
                visible_light_point(bvh, light, DVec2::ZERO, at, &mut counts.shadow)
            {
                let target = self.light_targets[k];
                out[target.layer] += material.response(s, wi, wo) * falloff * target.factor;
            }
        }
        let Some(ambient) = &scene.ambient else {
            return;
        };
        let u = rng.next_2d();
        if let Some((wi, weight)) = material.ambient_sample(s, wo, u) {
            counts.ambient += 1;
            if !self.core.bvh.occluded(lift, wi, 0.0, ambient.radius) {
                out[AMBIENT] += material.response(s, wi, wo) * weight;
            }
        }
    }

    /// The environment's share: one direction drawn from each part of the map
    /// (`MapPart`: the whole map, or its peaks and its remainder) and one from the
    /// material, with MIS per part; pre-convolved, the same on a filtered level of the
    /// map.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn sample_environment(
        &self,
        s: &Shading,
        material: ShadedMaterial<'_>,
        lo: DVec3,
        lift: DVec3,
        rng: &mut SampleStream,
        out: &mut [DVec3],
        counts: &mut RayCounts,
    ) {
        // The dimensions of the first part and of the material, as the spmm mode draws
        // its map and material samples; a second part's come after them.
        let (u_map, u_material) = (rng.next_2d(), rng.next_2d());
        let Some(env) = &self.core.scene.environment else {
            return;
        };
        // Pre-convolved: the level of the filtered map that the lobe's highest rate for
        // this view needs, with that level's own sampler (section 2.5).
        let (parts, n) = match &self.prefiltered {
            None => match self.map_parts() {
                Some(parts) => parts,
                None => return,
            },
            Some(pre) => {
                let rate = self.materials[s.material]
                    .as_ref()
                    .map_or(0.0, |b| b.peak(lo));
                match pre.map(pre.level_for(rate)) {
                    (map, Some(sampler)) => ([MapPart { sampler, map }; 2], 1),
                    (_, None) => return,
                }
            }
        };
        let parts = &parts[..n];
        let turn = env.turn();
        for (j, part) in parts.iter().enumerate() {
            let u = if j == 0 { u_map } else { rng.next_2d() };
            let e = part.sampler.sample(part.map, u);
            let wi = turn.apply(e.dir);
            if wi.dot(s.n) <= 0.0 {
                continue;
            }
            counts.environment += 1;
            if !self.core.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
                let li = s.to_local(wi);
                let weight = if env.mis {
                    power(e.pdf, material.pdf_local(s.uv, li, lo))
                } else {
                    1.0
                };
                out[ENVIRONMENT] +=
                    material.response_local(s.uv, li, lo) * e.radiance * (weight / e.pdf);
            }
        }
        if !env.mis {
            return;
        }
        let Some((li, pdf)) = drawn(&material, s.uv, lo, u_material) else {
            return;
        };
        let wi = s.to_world(li);
        if wi.dot(s.n) <= 0.0 {
            return;
        }
        counts.environment += 1;
        if self.core.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
            return;
        }
        // The material's direction serves every part, weighted against each part's
        // own strategy.
        let in_map = turn.undo(wi);
        let f = material.response_local(s.uv, li, lo);
        for part in parts {
            let (map_pdf, radiance) = part.sampler.pdf_and_radiance(part.map, in_map);
            out[ENVIRONMENT] += f * radiance * (power(pdf, map_pdf) / pdf);
        }
    }

    /// A frame, in steps of rows when `stop` is given: the rest of the bandwidth pass
    /// if there is no buffer yet, then the shading by the frame's plan; `stop` is asked
    /// between steps and a yes leaves the rest in `unfinished` for the next call.
    pub(super) fn render_tiles(
        &mut self,
        mut stop: Option<&mut dyn FnMut() -> bool>,
    ) -> FrameStats {
        let start = Instant::now();
        let (width, height) = (self.width(), self.height());
        let rows_of = |pixels: u32| match stop {
            Some(_) => (pixels / width.max(1)).max(1),
            None => height.max(1),
        };
        let (tile_rows, pass_rows) = (rows_of(TILE_PIXELS), rows_of(PASS_TILE_PIXELS));
        // Asked before each step but the first, so every call moves the frame on.
        let mut stepped = false;
        let mut stopped = |stepped: bool| stepped && stop.as_mut().is_some_and(|s| s());
        let (plan, mut y) = match self.unfinished.take() {
            Some(Unfinished::Shading { plan, rows_done }) => (plan, rows_done),
            pass => {
                if self.buffers.is_none() {
                    let mut pass = match pass {
                        Some(Unfinished::Pass(p)) => p,
                        _ => {
                            stepped = true;
                            self.begin_pass()
                        }
                    };
                    while (pass.per_pixel.len() as u32) < width * height {
                        if stopped(stepped) {
                            self.unfinished = Some(Unfinished::Pass(pass));
                            return FrameStats {
                                seconds: start.elapsed().as_secs_f64(),
                                ..FrameStats::default()
                            };
                        }
                        self.analyse_rows(&mut pass, pass_rows);
                        stepped = true;
                    }
                    self.buffers = Some(self.finish_pass(pass));
                }
                let b = self.buffers.as_ref().expect("computed above");
                (self.plan_frame(b, self.core.frames), 0)
            }
        };
        let layers = self.core.film.layers();
        let active = self.core.layers.active(&self.core.scene);
        let weights = self.core.layers.weights(&self.core.scene);
        let dropped_before = self.core.film.dropped();
        let mut totals = Counters::default();
        while y < height {
            if stopped(stepped) {
                break;
            }
            stepped = true;
            let rows = y..(y + tile_rows).min(height);
            y = rows.end;
            let own = std::mem::take(&mut self.own);
            let mut film = std::mem::replace(&mut self.core.film, Film::new(0, 0, 0));
            let tile = film.par_rows_in(rows.clone(), |row| {
                let mut counts = RayCounts::default();
                let mut samples = 0u64;
                let mut shading_points = 0u64;
                let mut out = vec![DVec3::ZERO; layers];
                let mut moments = vec![Moments::default(); width as usize];
                for x in 0..width {
                    let i = (row.y * width + x) as usize;
                    let n = plan.samples[i];
                    for k in 0..n {
                        out.iter_mut().for_each(|o| *o = DVec3::ZERO);
                        let index = u64::from(own[i]) + u64::from(k);
                        let mask = self.sample_into(x, row.y, index, &mut out, &mut counts);
                        if mask != 0 {
                            shading_points += 1;
                        }
                        let mut value = DVec3::ZERO;
                        for &l in &active {
                            row.add(x, l, out[l]);
                            value += out[l] * weights[l];
                        }
                        row.touch(x, mask);
                        let luminance = value.dot(LUMINANCE);
                        if luminance.is_finite() {
                            moments[x as usize].add(luminance);
                        }
                    }
                    samples += u64::from(n);
                }
                let counters = Counters {
                    samples,
                    shading_points,
                    rays: counts,
                };
                (counters, moments)
            });
            self.core.film = film;
            self.own = own;
            let pixels = (rows.start * width) as usize..(rows.end * width) as usize;
            for ((o, a), n) in self.own[pixels.clone()]
                .iter_mut()
                .zip(&mut self.added[pixels.clone()])
                .zip(&plan.samples[pixels])
            {
                *a |= *o == 0 && *n > 0 && self.core.frames > 0;
                *o += n;
            }
            for ((counters, moments), r) in tile.into_iter().zip(rows) {
                totals = totals + counters;
                let row = (r * width) as usize..((r + 1) * width) as usize;
                for (m, add) in self.moments[row].iter_mut().zip(moments) {
                    m.merge(&add);
                }
            }
        }
        if y < height {
            self.unfinished = Some(Unfinished::Shading { plan, rows_done: y });
        } else {
            self.plan = Some(plan);
            self.core.frames += 1;
            // The image is the film's from now on.
            self.preview = None;
        }
        FrameStats {
            counters: totals,
            seconds: start.elapsed().as_secs_f64(),
            dropped: self.core.film.dropped() - dropped_before,
        }
    }
}

impl AdaptiveMode {
    /// One sample at each previewed pixel (`preview::grid_pixels`) before the first
    /// frame after a restart, which waits for the bandwidth pass (1.6 s at 512 x 512
    /// on 2 cores). The samples stay out of the film (the frames' plan decides each
    /// pixel's samples), so the film is an uninterrupted render's; they cost about a
    /// 128 x 128 frame.
    pub(super) fn render_preview_pass(&mut self, stride: u32) -> Option<FrameStats> {
        use meso_render::preview;
        use rayon::prelude::*;
        let untouched =
            self.core.frames == 0 && self.unfinished.is_none() && self.preview.is_none();
        if stride <= 1 || !untouched {
            return None;
        }
        let start = Instant::now();
        let (w, h) = (self.width(), self.height());
        let weights = self.core.layers.weights(&self.core.scene);
        let layers = self.core.film.layers();
        let shaded: Vec<(u32, DVec3, Counters)> = preview::grid_pixels(w, h, stride)
            .into_par_iter()
            .map(|i| {
                let mut out = vec![DVec3::ZERO; layers];
                let mut rays = RayCounts::default();
                let mask = self.sample_into(i % w, i / w, 0, &mut out, &mut rays);
                let value = out.iter().zip(&weights).map(|(o, w)| *o * *w).sum();
                let counters = Counters {
                    samples: 1,
                    shading_points: u64::from(mask != 0),
                    rays,
                };
                (i, value, counters)
            })
            .collect();
        let mut image = Image::new(w, h);
        let mut counters = Counters::default();
        for (i, v, c) in shaded {
            image.pixels_mut()[i as usize] = [v.x as f32, v.y as f32, v.z as f32];
            counters = counters + c;
        }
        self.preview = Some(image);
        Some(FrameStats {
            counters,
            seconds: start.elapsed().as_secs_f64(),
            dropped: 0,
        })
    }
}

/// The sample's layers scaled by the reflectance of the mirrors its path met (left as
/// they are on a path without mirrors, keeping their bits), and the materials it
/// reached.
fn scaled(out: &mut [DVec3], (reflectance, mask): (DVec3, u64)) -> u64 {
    if reflectance != DVec3::ONE {
        out.iter_mut().for_each(|o| *o *= reflectance);
    }
    mask
}
