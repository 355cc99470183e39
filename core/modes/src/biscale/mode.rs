//! The biscale mode behind the `RenderMode` seam. Preparation: BVH, the precomputation
//! (or its cache), the BTF tables, the lighting vector and L* = T L by Algorithm 2.
//! Per frame: one jittered primary ray per pixel; at a hit, L* of the triangle's
//! vertices interpolated barycentrically, the view direction in the spmm mode's
//! shading frame (normal, tangent along +u), and the tabulated BTF row (a `btf`
//! material's BTF at a jittered direction per cell) dotted with L* (eq. 3), into the
//! environment layer, dark without an environment; then the lights and the ambient term traced
//! exactly through the shading core into their own layers. Environment strength
//! re-weights the film; turning or replacing the map is a light change (new L, new
//! L*); the precomputation is redone only for new meshes.

use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;

use super::btf_table::{BtfTable, Tabulation, ViewLookup};
use super::cubemap::CubeLayout;
use super::hemisphere::HemisphereGrid;
use super::precompute::{Precomputed, precompute};
use super::{BiscaleSettings, cpca::Cpca, sh::ShTransfer};
use meso_materials::image::Image;
use meso_materials::rng::SampleStream;
use meso_render::environment::EnvironmentSplit;
use meso_render::environment::rotate_y;
use meso_render::film::{EMPTY_UV_BOX, material_bit};
use meso_render::geometry::Hit;
use meso_render::geometry::SceneBvh;
use meso_render::layers::{self, AMBIENT, ENVIRONMENT, LightTarget};
use meso_render::light_selection::{LightSampling, LightSelection, ShadingPoint};
use meso_render::progressive::{Edited, Progressive};
use meso_render::scene::{Environment, Light, Material, Scene};
use meso_render::shading::{Shaders, Shading, dpdu, tangent_frame, visible_light_point};
use meso_render::{
    Counters, Device, Diagnostic, Diagnostics, EditError, Film, FrameStats, Invalidation,
    ModeError, ModeKind, Pass, PreparationReport, Prepare, Progress, RayCounts, RenderMode,
    SceneEdit, Unsupported,
};

/// Which representation of the transfer gives L* (the report compares them).
#[derive(Clone, Debug)]
pub enum TransferSource {
    /// Algorithm 2 over the biclusters (the mode's own).
    Biclustered,
    /// The uncompressed matrix.
    Dense,
    /// Sloan et al.'s SH bi-scale baseline.
    Sh(Arc<ShTransfer>),
    /// Clustered PCA of the matrix's rows.
    Cpca(Arc<Cpca>),
}

pub struct BiscaleMode {
    /// Scene, BVH, camera, film and layers, counters, moving flag, preparation.
    core: Progressive<Film>,
    settings: BiscaleSettings,
    tab: Tabulation,
    tables: Vec<Option<BtfTable>>,
    pre: Arc<Precomputed>,
    source: TransferSource,
    /// The environment's brightest pixels, traced, and the rest, which the transfer
    /// carries (`None` without an environment).
    split: Option<EnvironmentSplit>,
    /// The cube-map lighting vector of the split's remainder (unit strength).
    light: Vec<[f32; 3]>,
    /// Per vertex, L* laid out [channel][M].
    local: Vec<f32>,
    light_change_ms: f64,
    /// Milliseconds of the last frame (a view change re-renders every pixel).
    frame_ms: f64,
    /// The materials as the shading core shades them, for the lights and the ambient
    /// term, which are traced exactly on top of the precomputed environment.
    shaders: Shaders,
    /// Per light, the film layer its samples go to and their factor.
    light_targets: Vec<LightTarget>,
    /// Above `MANY_LIGHTS` lights, the spmm mode's stochastic selection among them
    /// (`LightSelection::add_chosen_lights`); `None`: every light is sampled.
    light_selection: Option<LightSelection>,
    /// Per pixel, whether the frame under way has its samples already (a preview's
    /// pixels, the rows of a frame an edit stopped); empty between frames.
    done_early: Vec<bool>,
}

/// The precomputation (refinement, visibility, binning, biclustering, or the cache)
/// and each material's table at the cells x views, their stages recorded in `report`:
/// the preparation the CPU and the GPU biscale modes share.
pub(super) fn precompute_and_tabulate(
    scene: &Scene,
    bvh: &SceneBvh,
    settings: &BiscaleSettings,
    prepare: &Prepare,
    report: &mut PreparationReport,
) -> Result<(Precomputed, Tabulation, Vec<Option<BtfTable>>), ModeError> {
    let pre = precompute(&scene.meshes, bvh, settings, prepare)?;
    report.record("refinement", pre.stats.refine_seconds);
    if pre.stats.from_cache {
        report.record("cache", pre.stats.cache_seconds);
    } else {
        report.record("visibility", pre.stats.visibility_seconds);
        report.record("binning", pre.stats.binning_seconds);
        report.record("biclustering", pre.stats.biclustering_seconds);
    }
    let tab = Tabulation {
        local: HemisphereGrid::new(settings.local_res),
        views: HemisphereGrid::new(settings.view_res),
    };
    prepare.report("tables", 0.0)?;
    let start = Instant::now();
    let mut tables = Vec::with_capacity(scene.materials.len());
    for (i, m) in scene.materials.iter().enumerate() {
        prepare.report("tables", i as f32 / scene.materials.len().max(1) as f32)?;
        tables.push(tab.table(m));
    }
    report.record_since("tables", start);
    Ok((pre, tab, tables))
}

/// The spmm mode's selection table when `lights` are too many to sample each.
fn selection(lights: &[Light]) -> Option<LightSelection> {
    if LightSampling::Auto.stochastic(lights.len()) {
        LightSelection::new(lights)
    } else {
        None
    }
}

/// Pixels of a frame rendered between two questions to its `stop` (rows of them).
const TILE_PIXELS: u32 = 16_384;

/// Offset of secondary ray origins along the normal, relative to the hit point's
/// magnitude (as the spmm mode's).
const EPSILON_REL: f64 = 1e-5;

/// L* rows (j = p M + m, RGB) laid out per vertex as [channel][M], the layout a
/// pixel interpolates.
pub(super) fn per_vertex(rows: &[[f32; 3]], mc: usize) -> Vec<f32> {
    let mut local = vec![0.0f32; rows.len() * 3];
    for (j, v) in rows.iter().enumerate() {
        let (p, m) = (j / mc, j % mc);
        for (c, x) in v.iter().enumerate() {
            local[(p * 3 + c) * mc + m] = *x;
        }
    }
    local
}

/// The split of `env` (keeping `kept` if it was made from the same map: a turn keeps
/// it, since it is made in map space) and the cube-map lighting vector of the split's
/// remainder at unit strength (zero without an environment).
pub(super) fn split_lighting(
    settings: &BiscaleSettings,
    env: Option<&Environment>,
    kept: Option<EnvironmentSplit>,
) -> (Option<EnvironmentSplit>, Vec<[f32; 3]>) {
    let cube = CubeLayout::new(settings.cube_n);
    let kept = kept.filter(|s| env.is_some_and(|e| Arc::ptr_eq(&s.source, &e.map)));
    let split =
        env.map(|e| kept.unwrap_or_else(|| EnvironmentSplit::new(&e.map, settings.traced_share)));
    let light = match (env, &split) {
        (Some(e), Some(split)) => cube.lighting(&Environment {
            map: Arc::clone(&split.remainder),
            ..e.clone()
        }),
        _ => vec![[0.0; 3]; cube.len()],
    };
    (split, light)
}

impl BiscaleMode {
    /// What the mode cannot render: nothing the spmm mode renders. Analytic BRDFs,
    /// MERL tables and SPMM packs read their tabulated tables; a `btf` material is
    /// evaluated per pixel at a jittered direction in each local cell (a table per
    /// texel would be texels x views x cells x 3 values); mirrors reflect the ray as in
    /// the spmm mode. Without an environment the precomputed part is dark and the
    /// lights and the ambient term, traced exactly, are the image. It answers like every
    /// mode, so the registry asks them alike.
    pub fn supports(_scene: &Scene) -> Result<(), Unsupported> {
        Ok(())
    }

    /// Prepares the mode with the default settings.
    pub fn new(scene: Scene, width: u32, height: u32, prepare: Prepare) -> Result<Self, ModeError> {
        Self::prepare(scene, width, height, BiscaleSettings::default(), prepare)
    }

    pub fn prepare(
        scene: Scene,
        width: u32,
        height: u32,
        settings: BiscaleSettings,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        if let Some(p) = settings.problem() {
            return Err(ModeError::Size(format!("biscale settings: {p}")));
        }
        let mut core = Progressive::prepare(scene, width, height, &prepare, Self::supports)?;
        let (scene, bvh, report) = (&core.scene, &core.bvh, &mut core.preparation);
        let (pre, tab, tables) = precompute_and_tabulate(scene, bvh, &settings, &prepare, report)?;
        let mut mode = Self {
            settings,
            tab,
            tables,
            pre: Arc::new(pre),
            source: TransferSource::Biclustered,
            split: None,
            light: Vec::new(),
            local: Vec::new(),
            light_change_ms: 0.0,
            frame_ms: 0.0,
            shaders: Shaders::new(&core.scene.materials),
            light_targets: core.layers.light_targets(&core.scene),
            light_selection: selection(&core.scene.lights),
            done_early: Vec::new(),
            core,
        };
        prepare.report("lighting", 0.0)?;
        let start = Instant::now();
        mode.relight();
        mode.core.preparation.record_since("lighting", start);
        Ok(mode)
    }

    /// The precomputation in use (matrices, biclusters, frames, stage times).
    pub fn precomputed(&self) -> &Precomputed {
        &self.pre
    }

    pub fn settings(&self) -> &BiscaleSettings {
        &self.settings
    }

    /// Milliseconds of the last light change (resampling L, the product, the layout).
    pub fn light_change_ms(&self) -> f64 {
        self.light_change_ms
    }

    /// Bytes of the BTF tables.
    pub fn table_bytes(&self) -> usize {
        self.tables.iter().flatten().map(BtfTable::bytes).sum()
    }

    /// Switches how L* is computed (for the reports), and restarts the image.
    pub fn set_transfer_source(&mut self, source: TransferSource) {
        self.source = source;
        self.relight();
        self.restart_all();
    }

    /// The split of the current environment, the lighting vector of its remainder and
    /// L*.
    fn relight(&mut self) {
        let start = Instant::now();
        let env = self.core.scene.environment.as_ref();
        (self.split, self.light) = split_lighting(&self.settings, env, self.split.take());
        let rows = match &self.source {
            TransferSource::Biclustered => self.pre.biclusters.apply(&self.light),
            TransferSource::Dense => self.pre.transfer.apply(&self.light),
            TransferSource::Sh(sh) => sh.apply(&self.light),
            TransferSource::Cpca(c) => c.apply(&self.light),
        };
        self.local = per_vertex(&rows, self.tab.local.len());
        self.light_change_ms = start.elapsed().as_secs_f64() * 1e3;
    }

    /// Replaces the lighting vector directly (tests of the binning rule).
    #[cfg(test)]
    pub(crate) fn relight_with(&mut self, light: Vec<[f32; 3]>) {
        // Only this lighting: nothing of the scene's map is traced.
        self.split = None;
        self.local = per_vertex(&self.pre.biclusters.apply(&light), self.tab.local.len());
        self.light = light;
        self.restart_all();
    }

    /// The next frame's samples of `pixels` only, marked done for the frame under way
    /// (a preview: the frame then completes the other pixels).
    fn render_pixels(&mut self, pixels: &[u32]) -> FrameStats {
        use rayon::prelude::*;
        let start = Instant::now();
        let first = self.core.next_sample;
        let k = u64::from(self.core.samples_per_frame);
        let active = self.core.layers.active(&self.core.scene);
        let (width, layers) = (self.core.film.width(), self.core.film.layers());
        let dropped_before = self.core.film.dropped();
        let lstar_len = 3 * self.tab.local.len();
        let mut totals = Counters::default();
        for index in first..first + k {
            let samples: Vec<(Vec<DVec3>, u64, RayCounts)> = pixels
                .par_iter()
                .map_init(
                    || vec![0.0f32; lstar_len],
                    |lstar, &p| {
                        let mut out = vec![DVec3::ZERO; layers];
                        let (mask, rays) =
                            self.sample((p % width, p / width, index), lstar, &mut out);
                        (out, mask, rays)
                    },
                )
                .collect();
            for (&p, (out, mask, rays)) in pixels.iter().zip(samples) {
                (self.core.film).add_pixel_sample(p, &active, &out, mask, &EMPTY_UV_BOX);
                totals = totals
                    + Counters {
                        samples: 1,
                        shading_points: u64::from(mask != 0),
                        rays,
                    };
            }
        }
        let n = width as usize * self.core.film.height() as usize;
        if self.done_early.len() != n {
            self.done_early = vec![false; n];
        }
        for &p in pixels {
            self.done_early[p as usize] = true;
        }
        FrameStats {
            counters: totals,
            seconds: start.elapsed().as_secs_f64(),
            dropped: self.core.film.dropped() - dropped_before,
        }
    }

    /// One frame, or the rest of one: in a single pass, or in tiles of rows asking
    /// `stop` between them. A stopped frame marks its finished rows done, so the call
    /// that completes it skips them and the samples are an uninterrupted frame's.
    fn render_tiles(&mut self, mut stop: Option<&mut dyn FnMut() -> bool>) -> FrameStats {
        let start = Instant::now();
        let first = self.core.next_sample;
        let k = u64::from(self.core.samples_per_frame);
        let active = self.core.layers.active(&self.core.scene);
        let (width, height) = (self.core.film.width(), self.core.film.height());
        let tile_rows = match stop {
            Some(_) => (TILE_PIXELS / width.max(1)).max(1),
            None => height.max(1),
        };
        let lstar_len = 3 * self.tab.local.len();
        let dropped_before = self.core.film.dropped();
        let mut film = std::mem::replace(&mut self.core.film, Film::new(0, 0, 0));
        let layer_count = film.layers();
        let mut totals = Counters::default();
        // Rows a stopped call finished are skipped without asking `stop` again, so
        // every call that is not stopped at once advances the frame.
        let mut y = (self.done_early.chunks(width.max(1) as usize))
            .take_while(|row| row.iter().all(|&d| d))
            .count() as u32;
        while y < height {
            let rows = y..(y + tile_rows).min(height);
            y = rows.end;
            let tile = film.par_rows_in(rows, |row| {
                let mut lstar = vec![0.0f32; lstar_len];
                let mut out = vec![DVec3::ZERO; layer_count];
                let mut counters = Counters::default();
                for x in 0..width {
                    let pixel = row.y as usize * width as usize + x as usize;
                    if self.done_early.get(pixel).copied().unwrap_or(false) {
                        continue;
                    }
                    counters.samples += k;
                    for index in first..first + k {
                        out.iter_mut().for_each(|v| *v = DVec3::ZERO);
                        let (mask, rays) = self.sample((x, row.y, index), &mut lstar, &mut out);
                        counters.shading_points += u64::from(mask != 0);
                        counters.rays = counters.rays + rays;
                        // Every active layer gets a sample (zero where this one saw nothing).
                        for &l in &active {
                            row.add(x, l, out[l]);
                        }
                        row.touch(x, mask);
                    }
                }
                counters
            });
            totals = tile.into_iter().fold(totals, |a, c| a + c);
            if y < height && stop.as_mut().is_some_and(|s| s()) {
                break;
            }
        }
        self.core.film = film;
        if y < height {
            let n = width as usize * height as usize;
            if self.done_early.len() != n {
                self.done_early = vec![false; n];
            }
            self.done_early[..y as usize * width as usize].fill(true);
        } else {
            self.done_early.clear();
            self.core.next_sample += k;
            self.core.frames += 1;
            self.frame_ms = start.elapsed().as_secs_f64() * 1e3;
        }
        FrameStats {
            counters: totals,
            seconds: start.elapsed().as_secs_f64(),
            dropped: self.core.film.dropped() - dropped_before,
        }
    }

    fn restart_all(&mut self) -> Invalidation {
        self.done_early.clear();
        self.core.film.reset();
        self.core.restart_counters();
        Invalidation::All
    }

    /// One sample of pixel (x, y) into `out`, per layer for unit emission: what an
    /// escaping ray sees, or at a hit the precomputed environment and the lights and
    /// ambient term traced exactly. Returns the material it shaded and the rays.
    fn sample(
        &self,
        (x, y, index): (u32, u32, u64),
        lstar: &mut [f32],
        out: &mut [DVec3],
    ) -> (u64, RayCounts) {
        // The camera's width: the film is out of `self` while a frame renders.
        let pixel = u64::from(y) * u64::from(self.core.camera.width()) + u64::from(x);
        let mut rng = SampleStream::new(&[self.core.scene.render.seed, index, pixel]);
        let mut ray = self.core.camera.ray(x, y, rng.next_2d());
        let mut rays = RayCounts {
            primary: 1,
            ..Default::default()
        };
        // Mirrors reflect the ray, as in the spmm mode, up to the scene's depth; what
        // the path then gathers is scaled by their reflectances.
        let (mut reflectance, mut mask) = (DVec3::ONE, 0u64);
        let hit = loop {
            let Some(hit) = self
                .core
                .bvh
                .closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY)
            else {
                if let Some((layer, radiance)) = layers::escaped(&self.core.scene, ray.dir) {
                    out[layer] += radiance * reflectance;
                }
                return (mask, rays);
            };
            let material = self.core.scene.meshes[hit.mesh].material;
            let Material::Mirror { reflectance: r } = self.core.scene.materials[material] else {
                break hit;
            };
            mask |= material_bit(material);
            if rays.specular >= u64::from(self.core.scene.render.max_specular_depth) {
                return (mask, rays);
            }
            rays.specular += 1;
            reflectance *= r;
            let s = Shading::at(&self.core.scene, &hit, ray.dir);
            let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
            ray = meso_render::geometry::Ray {
                origin: lift,
                dir: ray.dir - 2.0 * ray.dir.dot(s.n) * s.n,
            };
        };
        let mesh = &self.core.scene.meshes[hit.mesh];
        let idx = mesh.indices[hit.triangle].map(|i| i as usize);
        let w = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
        let n = (mesh.normals[idx[0]] * w[0]
            + mesh.normals[idx[1]] * w[1]
            + mesh.normals[idx[2]] * w[2])
            .normalize_or(DVec3::Y);
        let (p0, p1, p2) = (
            mesh.positions[idx[0]],
            mesh.positions[idx[1]],
            mesh.positions[idx[2]],
        );
        let uv_at = |i: usize| mesh.uvs.get(i).copied().unwrap_or_default();
        let (u0, u1, u2) = (uv_at(idx[0]), uv_at(idx[1]), uv_at(idx[2]));
        let uv = u0 * w[0] + u1 * w[1] + u2 * w[2];
        let (t, b) = tangent_frame(n, dpdu(p1 - p0, p2 - p0, u1 - u0, u2 - u0));
        let wo = -ray.dir;
        let wo_local = DVec3::new(wo.dot(t), wo.dot(b), wo.dot(n));
        let stride = lstar.len();
        // L* at the refined vertices around the hit (the triangle's own where it was
        // not refined).
        let base = self.pre.frames.mesh_offsets[hit.mesh];
        let (around, weights) = self
            .pre
            .refinement
            .locate(hit.mesh, hit.triangle, hit.b1, hit.b2);
        lstar.iter_mut().for_each(|v| *v = 0.0);
        for (&vi, &wi) in around.iter().zip(&weights) {
            let src = &self.local[(base + vi) * stride..(base + vi + 1) * stride];
            let wi = wi as f32;
            for (d, s) in lstar.iter_mut().zip(src) {
                *d += wi * s;
            }
        }
        let rgb = match &self.tables[mesh.material] {
            Some(table) => {
                let lookup = if self.core.moving {
                    ViewLookup::Nearest
                } else {
                    ViewLookup::Pick(rng.next())
                };
                table.shade(&self.tab, uv, wo_local, lstar, lookup)
            }
            None => self.shade_untabulated(mesh.material, uv, wo_local, lstar, rng.next_2d()),
        };
        out[ENVIRONMENT] += DVec3::new(rgb[0] as f64, rgb[1] as f64, rgb[2] as f64);
        self.trace_exact(&hit, ray.dir, &mut rng, out, &mut rays);
        // `out` held nothing before this sample (the frame clears it per sample).
        if reflectance != DVec3::ONE {
            out.iter_mut().for_each(|o| *o *= reflectance);
        }
        (mask | material_bit(mesh.material), rays)
    }

    /// Eq. 3 for a material without a table (a `btf` material): each local cell's
    /// BTF average estimated at one direction, at offset `jitter` inside every cell
    /// (uniform in the cell's solid angle, since the grid preserves area), dotted
    /// with L*. Unbiased for the tabulated sum; the film averages the jitter away, and
    /// the exact view direction is used rather than the tabulated views.
    fn shade_untabulated(
        &self,
        material: usize,
        uv: glam::DVec2,
        wo: DVec3,
        lstar: &[f32],
        jitter: glam::DVec2,
    ) -> [f32; 3] {
        if wo.z <= 0.0 {
            return [0.0; 3];
        }
        let shaded = self
            .shaders
            .material(&self.core.scene, material, self.core.moving);
        let mc = self.tab.local.len();
        let mut sum = DVec3::ZERO;
        for m in 0..mc {
            let f = shaded.response_local(uv, self.tab.local.at(m, jitter), wo);
            let l = DVec3::new(
                f64::from(lstar[m]),
                f64::from(lstar[mc + m]),
                f64::from(lstar[2 * mc + m]),
            );
            sum += f * l;
        }
        [sum.x as f32, sum.y as f32, sum.z as f32]
    }

    /// What is traced at `hit` rather than precomputed: the environment's brightest
    /// pixels (one direction drawn from them, `meso_render::environment::EnvironmentSplit`), and the lights and the
    /// ambient term as the spmm mode traces them (one shadow ray to each point light,
    /// `light_samples` to each area light, or above `MANY_LIGHTS` lights the spmm
    /// mode's stochastic selection; one ambient ray), through the shading core.
    fn trace_exact(
        &self,
        hit: &Hit,
        dir: DVec3,
        rng: &mut SampleStream,
        out: &mut [DVec3],
        rays: &mut RayCounts,
    ) {
        let scene = &self.core.scene;
        let peaks = match (&self.split, &scene.environment) {
            (Some(split), Some(env)) => split.sampler.as_ref().map(|s| (split, s, env)),
            _ => None,
        };
        if scene.lights.is_empty() && scene.ambient.is_none() && peaks.is_none() {
            return;
        }
        let s = Shading::at(scene, hit, dir);
        let material = self.shaders.material(scene, s.material, self.core.moving);
        let wo = -dir;
        let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
        if let Some((split, sampler, env)) = peaks {
            let e = sampler.sample(&split.peaks, rng.next_2d());
            let wi = rotate_y(e.dir, env.rotate_y_deg);
            if e.pdf > 0.0 && wi.dot(s.n) > 0.0 {
                rays.shadow += 1;
                if !self.core.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
                    out[ENVIRONMENT] += material.response(&s, wi, wo) * e.radiance / e.pdf;
                }
            }
        }
        let n = scene.render.light_samples;
        if let Some(selection) = &self.light_selection {
            let at = ShadingPoint {
                s: &s,
                wo,
                lift,
                material: &material,
                throughput: DVec3::ONE,
            };
            let bvh = &self.core.bvh;
            selection.add_chosen_lights(
                &at,
                n,
                bvh,
                &self.light_targets,
                rng,
                &mut rays.shadow,
                out,
            );
        } else {
            for (k, light) in scene.lights.iter().enumerate() {
                let points = rng.next_2d_set(n);
                let (count, share) = match light {
                    Light::Point { .. } => (1, 1.0),
                    Light::Area { .. } => (n, 1.0 / f64::from(n)),
                };
                for r in 0..count {
                    let at = (&s, lift);
                    let bvh = &self.core.bvh;
                    if let Some((wi, falloff)) =
                        visible_light_point(bvh, light, points.get(r), at, &mut rays.shadow)
                    {
                        let target = self.light_targets[k];
                        out[target.layer] +=
                            material.response(&s, wi, wo) * (falloff * share) * target.factor;
                    }
                }
            }
        }
        let u = rng.next_2d();
        if let Some(ambient) = &scene.ambient
            && let Some((wi, weight)) = material.ambient_sample(&s, wo, u)
        {
            rays.ambient += 1;
            if !self.core.bvh.occluded(lift, wi, 0.0, ambient.radius) {
                out[AMBIENT] += material.response(&s, wi, wo) * weight;
            }
        }
    }
}

impl BiscaleMode {
    /// The status-bar line: where the precomputation came from, the biclusters and
    /// the view- and light-change times.
    fn summary(&self) -> String {
        let pre = &self.pre;
        let source = match self.source {
            TransferSource::Biclustered => "",
            TransferSource::Dense => " (dense product)",
            TransferSource::Sh(_) => " (SH baseline)",
            TransferSource::Cpca(_) => " (CPCA baseline)",
        };
        let origin = if pre.stats.from_cache {
            "precomputed: from cache".to_string()
        } else {
            format!(
                "precomputed in {:.1} s",
                pre.stats.refine_seconds
                    + pre.stats.visibility_seconds
                    + pre.stats.binning_seconds
                    + pre.stats.biclustering_seconds
            )
        };
        let dark = if self.core.scene.environment.is_none() {
            "no environment: lights and ambient term only · "
        } else {
            ""
        };
        let traced = match &self.split {
            Some(s) if s.traced_power > 0.0 => {
                format!(
                    "traced: {:.0}% of the map's power · ",
                    100.0 * s.traced_power
                )
            }
            _ => String::new(),
        };
        format!(
            "{dark}{traced}{origin} · {} vertices ({} added) · {} biclusters · FLOP ratio {:.3}{source} · view change {:.1} ms · light change {:.1} ms",
            pre.frames.len(),
            pre.stats.refined_vertices,
            pre.biclusters.len(),
            pre.flop_ratio(),
            self.frame_ms,
            self.light_change_ms
        )
    }
}

impl RenderMode for BiscaleMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Biscale
    }

    fn device(&self) -> Device {
        Device::Cpu
    }

    fn scene(&self) -> &Scene {
        &self.core.scene
    }

    fn render(&mut self, pass: Pass, stop: Option<&mut dyn FnMut() -> bool>) -> Option<FrameStats> {
        match pass {
            Pass::Frame => Some(self.render_tiles(stop)),
            Pass::Preview { stride } => {
                // No frame under way, and every pixel short of a sample in some layer
                // (a camera edit, a moved light, an edited material seen everywhere).
                let untouched =
                    !self.done_early.contains(&true) && self.progress().min_samples == 0;
                if stride <= 1 || !untouched {
                    return None;
                }
                let (w, h) = (self.core.film.width(), self.core.film.height());
                Some(self.render_pixels(&meso_render::preview::grid_pixels(w, h, stride)))
            }
        }
    }

    fn image(&self) -> Image {
        self.core
            .film
            .resolve(&self.core.layers.weights(&self.core.scene))
    }

    fn progress(&self) -> Progress {
        self.core
            .film
            .progress(self.core.frames, &self.core.layers.active(&self.core.scene))
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.core.samples_per_frame = samples.max(1);
    }

    fn diagnostics(&self) -> Diagnostics {
        Diagnostics(vec![
            Diagnostic::Preparation(self.core.preparation.clone()),
            Diagnostic::Summary(self.summary()),
        ])
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        let old_env: Option<Environment> = self.core.scene.environment.clone();
        Ok(match self.core.apply(&edit)? {
            Edited::Emitters(invalidation) => {
                let relit = match (&edit, &old_env) {
                    (SceneEdit::Environment(Some(e)), Some(old)) => !old.same_but_strength(e),
                    (SceneEdit::Environment(_), _) => true,
                    _ => false,
                };
                if relit {
                    // A light change (turned, replaced, on or off): a new lighting
                    // vector, a new L*; T is unchanged.
                    self.relight();
                }
                self.light_targets = self.core.layers.light_targets(&self.core.scene);
                self.light_selection = selection(&self.core.scene.lights);
                if invalidation != Invalidation::Nothing {
                    // A restarted layer must get this frame's samples everywhere.
                    self.done_early.clear();
                }
                invalidation
            }
            Edited::Camera | Edited::Resized => self.restart_all(),
            Edited::Meshes => {
                // New geometry: new visibility, so the precomputation runs again.
                self.core.bvh = SceneBvh::build(&self.core.scene.meshes);
                let pre = precompute(
                    &self.core.scene.meshes,
                    &self.core.bvh,
                    &self.settings,
                    &Prepare::quietly(),
                )
                .expect("an uncancellable preparation is never cancelled");
                self.pre = Arc::new(pre);
                if !matches!(
                    self.source,
                    TransferSource::Biclustered | TransferSource::Dense
                ) {
                    self.source = TransferSource::Biclustered;
                }
                self.relight();
                self.restart_all()
            }
            Edited::Material { index, before } => {
                let after = &self.core.scene.materials[index];
                self.shaders.edited(index, Some(&before), after);
                self.tables[index] = self.tab.table_reusing(self.tables[index].as_ref(), after);
                // Restarted pixels must get this frame's samples.
                self.done_early.clear();
                Invalidation::Pixels(self.core.film.reset_touching(material_bit(index)))
            }
            // Samples shaded the fast way and the full way must not mix.
            Edited::Moving => self.restart_all(),
            // Another estimator of the area lights: their sequence starts again.
            Edited::LightSamples => self.restart_all(),
            Edited::Nothing => Invalidation::Nothing,
        })
    }
}
