//! `GpuSpmmMode`: the spmm mode with its per-pixel work on a wgpu device. Each frame
//! dispatches `shaders/integrator.wgsl` once per sample (one invocation per pixel)
//! and adds the sample to the film on the device (`film.rs`, the CPU film's rules:
//! layers per light, edits that keep samples, the moving flag, per-pixel
//! invalidation); a frame reads back only its counters. Geometry (BVH nodes and
//! triangles), the prepared SPMM data, BRDFs, materials and lights live on the device.

mod adaptive;
mod biscale;
mod denoising;

#[cfg(test)]
pub(crate) use adaptive::ADAPTIVE_CHUNK;
mod edit;
mod limits;
mod resources;
mod scene_data;

use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use glam::DVec3;

use super::data::{BtfWords, DataBytes, Words};
use super::display::DeviceImage;
use super::environment;
use super::film::{self, DeviceFilm, MAX_LAYERS};
use super::geometry::GeometryBuffers;
use super::kernel::{self, Kernel, Slot};
use super::reach::{Reach, reachable_clusters};
use super::shaders;
use super::{GpuContext, GpuError, Sharing};
use biscale::env_words;
use limits::{ENVIRONMENT_WORDS, MATERIAL_WORDS_NAME, device_size_problem, words_size_problem};
use meso_materials::image::Image;
use meso_materials::rng::Sampler;
use meso_materials::spmm::PrepareRequest;
use meso_render::film::{LayeredFilm, material_bit};
use meso_render::geometry::SceneBvh;
use meso_render::layers::{Layers, MANY_LIGHTS};
use meso_render::light_selection::{LightSampling, LightSelection};
use meso_render::progressive::{Edited, Progressive, ProgressiveFilm};
use meso_render::reach::EditedTexels;
use meso_render::scene::{Light, Material, RenderSettings, Scene};
use meso_render::{
    Counters, Device, Diagnostic, Diagnostics, EditError, FrameStats, ImageOnDevice, Invalidation,
    ModeError, ModeKind, Pass, PreparationReport, Prepare, Progress, RayCounts, RenderMode,
    SceneEdit, Unrenderable, Unsupported,
};
use resources::Resources;
use scene_data::{LIGHT_WORDS, SceneData, light_capacity, light_table};

/// Counter slots of `shaders/integrator.wgsl` (two traversal overflows, then rays;
/// the environment's, `shaders/environment.wgsl`; the adaptive mode's dropped
/// samples, `shaders/adaptive_render.wgsl`).
const COUNTERS: usize = 9;

/// Device memory by kind, in bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DeviceBytes {
    pub bvh: u64,
    pub triangles: u64,
    pub spmm_bases: u64,
    /// Per-texel weights, basis indices and texel clusters.
    pub spmm_weights: u64,
    pub residual_tables: u64,
    /// BRDF records, the material and light tables.
    pub materials: u64,
    /// The environment map with its sampling tables, and the background image.
    pub environment: u64,
    /// MERL tables and their sampling tables.
    pub merl_tables: u64,
    /// `btf` materials' values and direction tables.
    pub btf_tables: u64,
    /// The film (f32 sums per layer, per-pixel marks, the resolved image) and one
    /// sample's layers.
    pub film: u64,
}

impl DeviceBytes {
    pub fn total(&self) -> u64 {
        self.bvh
            + self.triangles
            + self.spmm_bases
            + self.spmm_weights
            + self.residual_tables
            + self.materials
            + self.environment
            + self.merl_tables
            + self.btf_tables
            + self.film
    }
}

/// The uniform block of `shaders/integrator.wgsl` (`Params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct Params {
    width: u32,
    height: u32,
    layers: u32,
    seed: u32,
    sample_lo: u32,
    sample_hi: u32,
    max_depth: u32,
    moving: u32,
    lights: u32,
    light_table: u32,
    material_table: u32,
    background: u32,
    ambient_radius: f32,
    materials: u32,
    /// 1: lights chosen stochastically (more than `MANY_LIGHTS`, as the CPU).
    stochastic: u32,
    /// Points per area light per shading point (`[render] light_samples`).
    light_samples: u32,
    /// `[render] sampler`: 0 Sobol, 1 independent (`shaders/sampler.wgsl`).
    sampler: u32,
    /// Where the biscale words start in `env` (`shaders/biscale.wgsl`; 0 otherwise).
    biscale: u32,
    /// Words per pixel of the film's `aux` buffer.
    aux_words: u32,
    pad: u32,
    cam_origin: [f32; 4],
    cam_forward: [f32; 4],
    cam_right: [f32; 4],
    cam_up: [f32; 4],
    /// Each layer's weight (the adaptive mode's luminance moments).
    weights: [[f32; 4]; MAX_LAYERS],
}

/// The `spmm` mode on a wgpu device.
pub struct GpuSpmmMode {
    ctx: GpuContext,
    /// Scene, BVH, camera, device film and layers, counters, moving flag,
    /// preparation.
    core: Progressive<DeviceFilm>,
    kernel: Kernel,
    res: Resources,
    scene_data: SceneData,
    /// The viewport denoiser's guides and filter on the device.
    denoising: denoising::SharedDenoising,
    /// The environment map's importance samplers: the whole map's, or its parts'.
    env_sampling: environment::MapSampling,
    /// The `env` words (`environment::words`).
    env_words: Vec<u32>,
    /// Traversals that overflowed the stack or the step bound (should stay zero).
    overflows: [u64; 2],
    /// Set once the device fails: the mode renders nothing more.
    failure: Option<GpuError>,
    /// Every cluster of every pack on the device, not just the reachable ones.
    all_clusters: bool,
    /// The biscale mode's words (`mode/biscale.rs`), appended to `env_words`.
    biscale: Option<super::biscale::BiscaleBlock>,
    /// The adaptive mode's plan and state (`mode/adaptive.rs`).
    adaptive: Option<super::adaptive::AdaptiveDevice>,
}

/// Which frames a device mode renders.
enum Frames {
    Spmm,
    /// The biscale mode's: its BVH (built by the CPU's preparation) and words.
    Biscale(Box<(SceneBvh, super::biscale::BiscaleBlock)>),
    Adaptive(super::adaptive::AdaptiveKnobs),
}

/// The integrator's bindings (`shaders/integrator.wgsl`), which every kernel of its
/// module binds: eight storage buffers, the most a device must allow a kernel.
pub(super) const SLOTS: [Slot; 9] = [
    Slot::Uniform,
    Slot::Read,
    Slot::Read,
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::Read,
];

/// Material `index` of `scene` (`m`) as a part the device cannot shade, if it is one.
/// Exhaustive, so a new material kind cannot be added without saying here whether the
/// device shades it. A BTF read out of core (larger than its memory bound) would have
/// to be held whole to go up: refused, saying how to hold it whole.
pub(crate) fn unshaded(scene: &Scene, index: usize, m: &Material) -> Option<Unrenderable> {
    let shaded = match m {
        Material::Brdf { .. }
        | Material::Merl { .. }
        | Material::Spmm { .. }
        | Material::Mirror { .. } => true,
        Material::Btf { table, .. } => table.is_resident(),
    };
    (!shaded).then(|| Unrenderable::Material {
        index,
        name: scene.material_name(index),
        kind: match m {
            Material::Btf { .. } => {
                "btf larger than --max-memory, read from disk; a bound above its values uploads it whole"
            }
            _ => m.kind_name(),
        },
    })
}

impl GpuSpmmMode {
    /// What this mode cannot render in `scene`, each by name: nothing the CPU mode
    /// renders (what would not fit on the adapter is refused by size instead).
    pub fn supports(scene: &Scene) -> Result<(), Unsupported> {
        let parts = scene
            .materials
            .iter()
            .enumerate()
            .filter_map(|(index, m)| unshaded(scene, index, m))
            .collect();
        Unsupported::check(ModeKind::Spmm, Device::Gpu, parts)
    }

    /// Prepares `scene` on the device `ctx` at `width` x `height`: the BVH, the
    /// materials and lights, the device buffers, each a reported, cancellable stage.
    pub fn prepare(
        ctx: GpuContext,
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        Self::prepare_with(ctx, scene, (width, height), prepare, false, Frames::Spmm)
    }

    /// `prepare`, with every cluster of every pack uploaded when `all_clusters` (the
    /// tests' reference for the reachable set).
    #[cfg(test)]
    pub(super) fn prepare_uploading(
        ctx: GpuContext,
        scene: Scene,
        size: (u32, u32),
        prepare: Prepare,
        all_clusters: bool,
    ) -> Result<Self, ModeError> {
        Self::prepare_with(ctx, scene, size, prepare, all_clusters, Frames::Spmm)
    }

    /// `prepare_uploading`, rendering `frames`.
    fn prepare_with(
        ctx: GpuContext,
        scene: Scene,
        (width, height): (u32, u32),
        prepare: Prepare,
        all_clusters: bool,
        frames: Frames,
    ) -> Result<Self, ModeError> {
        if let Some(p) = RenderSettings::size_problem(width, height) {
            return Err(ModeError::Size(p));
        }
        Self::supports(&scene)?;
        let layers = Layers::new(&scene);
        let layer_count = layers.layer_count(&scene);
        debug_assert!(
            layer_count <= MAX_LAYERS,
            "render::layers bounds the layers"
        );
        let aux_words = match frames {
            Frames::Adaptive(_) => film::ADAPTIVE_AUX_WORDS,
            Frames::Spmm | Frames::Biscale(_) => film::AUX_WORDS,
        };
        if let Some(p) = device_size_problem(&ctx, (width, height), layer_count, aux_words) {
            return Err(ModeError::Size(p));
        }
        let mut report = PreparationReport::default();
        let (bvh, biscale, knobs) = match frames {
            Frames::Biscale(b) => {
                let (bvh, block) = *b;
                (bvh, Some(block), None)
            }
            Frames::Spmm => (prepare.bvh(&scene.meshes, &mut report)?, None, None),
            Frames::Adaptive(knobs) => {
                (prepare.bvh(&scene.meshes, &mut report)?, None, Some(knobs))
            }
        };
        prepare.report("materials", 0.0)?;
        let start = Instant::now();
        let scene_data = SceneData::build(&scene, &layers, all_clusters);
        if let Some(p) = words_size_problem(&ctx, MATERIAL_WORDS_NAME, scene_data.words.words.len())
        {
            return Err(ModeError::Size(p));
        }
        report.record_since("materials", start);
        prepare.report("environment", 0.0)?;
        let start = Instant::now();
        let split = knobs.is_some_and(|k| k.split_environment);
        let env_sampling = environment::MapSampling::new(scene.environment.as_ref(), split);
        let env_words = env_words(&scene, &env_sampling, biscale.as_ref());
        if let Some(p) = words_size_problem(&ctx, ENVIRONMENT_WORDS, env_words.len()) {
            return Err(ModeError::Size(p));
        }
        report.record_since("environment", start);
        prepare.report("device", 0.0)?;
        let start = Instant::now();
        let kernel = match (&biscale, knobs) {
            (Some(_), _) => Kernel::new(&ctx, &shaders::biscale(), "render_biscale", &SLOTS),
            (None, Some(_)) => Kernel::new(&ctx, &shaders::adaptive(), "render_adaptive", &SLOTS),
            (None, None) => Kernel::new(&ctx, &shaders::integrator(), "render", &SLOTS),
        };
        let film = DeviceFilm::with_aux(&ctx, (width, height), layer_count, aux_words);
        let adaptive =
            knobs.map(|k| super::adaptive::AdaptiveDevice::new(&ctx, (width, height), k));
        let res = Resources::upload(
            &ctx,
            &kernel,
            &bvh,
            &scene,
            (&scene_data, &env_words),
            &film,
        );
        report.record_since("device", start);
        if let Some(e) = ctx.failure() {
            return Err(ModeError::DeviceFailed(e.to_string()));
        }
        prepare.report("device", 1.0)?;
        Ok(Self {
            ctx,
            core: Progressive::new(scene, bvh, film, layers, report),
            kernel,
            res,
            scene_data,
            env_sampling,
            env_words,
            overflows: [0; 2],
            failure: None,
            all_clusters,
            denoising: Default::default(),
            biscale,
            adaptive,
        })
    }

    /// Device memory by kind.
    pub fn device_bytes(&self) -> DeviceBytes {
        let d = self.res.data_bytes;
        DeviceBytes {
            bvh: self.res.geometry.bvh_bytes,
            triangles: self.res.geometry.triangle_bytes,
            spmm_bases: d.spmm_bases,
            spmm_weights: d.spmm_weights,
            residual_tables: d.residual_tables,
            materials: d.materials,
            environment: self.res.env.size(),
            merl_tables: d.merl_tables,
            btf_tables: d.btf_tables,
            film: self.core.film.bytes() + self.adaptive.as_ref().map_or(0, |a| a.bytes()),
        }
    }

    /// Traversals that ran out of stack, and out of steps, since the mode was made.
    /// Either would be a wrong image, so tests require zero.
    pub fn overflows(&self) -> (u64, u64) {
        (self.overflows[0], self.overflows[1])
    }

    /// The film's layers (one per emitter, or a bounded film's).
    pub fn film_layers(&self) -> usize {
        self.core.film.layers()
    }

    fn params(&self, sample: u64) -> Params {
        let cam = &self.core.scene.camera;
        let (w, h) = (self.core.film.width(), self.core.film.height());
        let forward = (cam.look_at - cam.position).normalize();
        let right = forward.cross(cam.up).normalize();
        let up = right.cross(forward);
        let half_h = (cam.fov_y_deg.to_radians() * 0.5).tan();
        let half_w = half_h * w as f64 / h as f64;
        let v4 = |v: DVec3, w: f64| [v.x as f32, v.y as f32, v.z as f32, w as f32];
        Params {
            width: w,
            height: h,
            layers: self.core.film.layers() as u32,
            seed: self.core.scene.render.seed as u32,
            sample_lo: sample as u32,
            sample_hi: (sample >> 32) as u32,
            max_depth: self.core.scene.render.max_specular_depth,
            moving: u32::from(self.core.moving),
            lights: self.core.scene.lights.len() as u32,
            light_table: self.scene_data.light_table,
            material_table: self.scene_data.material_table,
            background: environment::escape(&self.core.scene),
            ambient_radius: self
                .core
                .scene
                .ambient
                .map_or(-1.0, |a| a.radius.min(3.0e38) as f32),
            materials: self.core.scene.materials.len() as u32,
            // The adaptive mode takes every light once per sample, as its CPU mode.
            stochastic: u32::from(
                self.adaptive.is_none()
                    && LightSampling::Auto.stochastic(self.core.scene.lights.len()),
            ),
            light_samples: self.core.scene.render.light_samples,
            sampler: match self.core.scene.render.sampler {
                Sampler::Sobol => 0,
                Sampler::Independent => 1,
            },
            biscale: self.biscale_at(),
            aux_words: self.core.film.aux_words() as u32,
            pad: 0,
            cam_origin: v4(cam.position, 0.0),
            cam_forward: v4(forward, half_w),
            cam_right: v4(right, half_h),
            cam_up: v4(up, 0.0),
            weights: self.layer_weights(),
        }
    }

    /// Each active layer's weight (its emission) as f32, zero for the others; only the
    /// adaptive samples read them (all zero for the other frame kinds).
    fn layer_weights(&self) -> [[f32; 4]; MAX_LAYERS] {
        let mut out = [[0.0; 4]; MAX_LAYERS];
        if self.adaptive.is_none() {
            return out;
        }
        let scene = &self.core.scene;
        let weights = self.core.layers.weights(scene);
        let max = f64::from(f32::MAX);
        for l in self.core.layers.active(scene) {
            if let (Some(w), Some(o)) = (weights.get(l), out.get_mut(l)) {
                let w = w.clamp(DVec3::splat(-max), DVec3::splat(max));
                *o = [w.x as f32, w.y as f32, w.z as f32, 0.0];
            }
        }
        out
    }

    /// `count` samples per pixel from sample index `first`: per sample a dispatch of
    /// the integrator and one of the film's accumulation, then one read-back of the
    /// frame's counters (no image). A failed device adds nothing more.
    fn render_samples(&mut self, first: u64, count: u32) -> Result<Counters, GpuError> {
        let ctx = &self.ctx;
        let active = self.core.layers.active(&self.core.scene);
        let (w, h) = (self.core.film.width(), self.core.film.height());
        let mut enc = kernel::encoder(ctx);
        enc.clear_buffer(&self.res.counters, 0, None);
        ctx.queue.submit([enc.finish()]);
        // The film's parameters (the active layers) are the same for every sample.
        self.core.film.set_params(&active, false, &[]);
        for i in 0..u64::from(count) {
            // Written before the submission that reads them (the queue keeps order).
            ctx.queue.write_buffer(
                &self.res.params,
                0,
                bytemuck::bytes_of(&self.params(first + i)),
            );
            let mut enc = kernel::encoder(ctx);
            self.kernel.record(&mut enc, &self.res.bind, w * h);
            self.core.film.record_accumulate(&mut enc);
            if i + 1 == u64::from(count) {
                self.core.film.record_min_samples(&mut enc);
            }
            ctx.queue.submit([enc.finish()]);
        }
        let counters = self.read_counters()?;
        Ok(Counters {
            samples: u64::from(w) * u64::from(h) * u64::from(count),
            ..counters
        })
    }

    /// Reads back the frame's counters and the film's counts: the rays by kind (the
    /// samples are the caller's to count) and the overflows, which it adds up.
    fn read_counters(&mut self) -> Result<Counters, GpuError> {
        let ctx = &self.ctx;
        let bytes = kernel::submit_and_read(
            ctx,
            kernel::encoder(ctx),
            &[
                (&self.res.counters, COUNTERS as u64 * 4),
                (self.core.film.stats(), 8),
            ],
        )?;
        let counters: &[u32] = bytemuck::cast_slice(&bytes[0]);
        self.core.film.refresh(bytemuck::cast_slice(&bytes[1]));
        self.overflows[0] += u64::from(counters[0]);
        self.overflows[1] += u64::from(counters[1]);
        if let Some(a) = &mut self.adaptive {
            a.dropped += u64::from(counters[8]);
        }
        Ok(Counters {
            samples: 0,
            shading_points: u64::from(counters[6]),
            rays: RayCounts {
                primary: u64::from(counters[2]),
                shadow: u64::from(counters[3]),
                ambient: u64::from(counters[4]),
                environment: u64::from(counters[7]),
                specular: u64::from(counters[5]),
            },
        })
    }

    /// The materials whose evaluation changes with the moving flag.
    fn moving_mask(&self) -> u64 {
        self.scene_data
            .moving_changes
            .iter()
            .enumerate()
            .filter(|(_, r)| **r)
            .fold(0, |m, (i, _)| m | material_bit(i))
    }

    /// The film resolved on the device (`None` once the device failed); the adaptive
    /// mode's up-sampled from its sites.
    fn device_image(&self) -> Option<DeviceImage> {
        if self.failure.is_some() {
            return None;
        }
        let image = self.core.film.resolve(
            &self.core.layers.active(&self.core.scene),
            &self.core.layers.weights(&self.core.scene),
        );
        if let Some(a) = &self.adaptive
            && a.has_pass
            && self.core.frames > 0
        {
            a.upsample(&image, &self.core.film.aux);
        }
        Some(image)
    }

    /// The pixels an edit restarted; a device that failed while they were found
    /// restarts nothing more (the mode reports the failure).
    fn restarted(&mut self, pixels: Result<Vec<u32>, GpuError>) -> Invalidation {
        match pixels {
            Ok(p) => Invalidation::Pixels(p.len()),
            Err(e) => {
                self.failure = Some(e);
                Invalidation::All
            }
        }
    }

    fn restart_all(&mut self) -> Invalidation {
        self.core.film.reset();
        self.core.restart_counters();
        if let Some(a) = &self.adaptive {
            a.restart_samples();
        }
        Invalidation::All
    }

    /// The data words (materials, lights) of the scene as it is, or why they would
    /// not fit in one buffer of the device.
    fn rebuild_data(&self) -> Result<SceneData, EditError> {
        let data = SceneData::build(&self.core.scene, &self.core.layers, self.all_clusters);
        match words_size_problem(&self.ctx, MATERIAL_WORDS_NAME, data.words.words.len()) {
            Some(p) => Err(EditError::Size(p)),
            None => Ok(data),
        }
    }

    /// A device whose buffers are limited to `bytes` (the tests' way to meet the
    /// limit without allocating it).
    #[cfg(test)]
    pub(super) fn limit_buffers(&mut self, bytes: u64) {
        self.ctx = self.ctx.with_buffer_limit(bytes);
    }

    /// The bytes of the data words now on the device.
    #[cfg(test)]
    pub(super) fn data_words_bytes(&self) -> u64 {
        self.scene_data.words.words.len() as u64 * 4
    }

    fn rebind(&mut self) {
        self.res = Resources::upload(
            &self.ctx,
            &self.kernel,
            &self.core.bvh,
            &self.core.scene,
            (&self.scene_data, &self.env_words),
            &self.core.film,
        );
    }

    /// Rebuilds the environment and background words (and the map's sampler when
    /// `new_map`) and rebinds.
    fn reupload_environment(&mut self, new_map: bool) {
        if new_map {
            self.env_sampling = environment::MapSampling::new(
                self.core.scene.environment.as_ref(),
                self.env_sampling.split,
            );
        }
        self.env_words = env_words(&self.core.scene, &self.env_sampling, self.biscale.as_ref());
        self.rebind();
    }

    /// Rewrites the light table after a light edit: in place while it has room (every
    /// other buffer kept), else grown at the end of the data words; true if the data
    /// buffer must be uploaded again (`rebind`).
    fn write_lights(&mut self) -> bool {
        let table = light_table(&self.core.scene, &self.core.layers);
        let at = self.scene_data.light_table as usize;
        let n = self.core.scene.lights.len();
        let grow = n > self.scene_data.light_capacity;
        if grow {
            let capacity = light_capacity(n);
            let words = &mut self.scene_data.words;
            let before = words.words.len();
            words.words.resize(at + capacity * LIGHT_WORDS, 0);
            words.bytes.materials += 4 * (words.words.len() - before) as u64;
            self.scene_data.light_capacity = capacity;
        }
        let words = &mut self.scene_data.words.words;
        words[at..at + table.len()].copy_from_slice(&table);
        // Records past the last light: zero (not read; kept clean).
        words[at + table.len()..].fill(0);
        if !grow {
            self.ctx.queue.write_buffer(
                &self.res.data,
                at as u64 * 4,
                bytemuck::cast_slice(&words[at..]),
            );
        }
        grow
    }
}

impl GpuSpmmMode {
    /// The status-bar line: the adapter, the bytes on it, traversal overflows.
    fn summary(&self) -> String {
        let (stack, steps) = self.overflows();
        let mut s = format!(
            "{} · {:.1} MB on the device",
            self.ctx.adapter_name(),
            self.device_bytes().total() as f64 / 1e6
        );
        match self.ctx.sharing() {
            Sharing::Own => {}
            Sharing::Shared => s.push_str(" · shared with the window"),
            Sharing::OwnBecause(why) => s.push_str(&format!(" · own device ({why})")),
        }
        if stack + steps > 0 {
            s.push_str(&format!(" · {stack} stack and {steps} step overflows"));
        }
        s
    }
}

impl RenderMode for GpuSpmmMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Spmm
    }

    fn device(&self) -> Device {
        Device::Gpu
    }

    fn scene(&self) -> &Scene {
        &self.core.scene
    }

    fn render(
        &mut self,
        pass: Pass,
        _stop: Option<&mut dyn FnMut() -> bool>,
    ) -> Option<FrameStats> {
        // No preview; a frame is one dispatch per sample (it does not stop).
        if pass != Pass::Frame {
            return None;
        }
        let start = Instant::now();
        let dropped_before = self.core.film.dropped();
        if self.failure.is_some() {
            return Some(FrameStats::default());
        }
        let rendered = match self.adaptive {
            Some(_) => self.render_adaptive_frame(),
            None => self.render_samples(self.core.next_sample, self.core.samples_per_frame),
        };
        let counters = match rendered {
            Ok(c) => c,
            Err(e) => {
                self.failure = Some(e);
                Counters::default()
            }
        };
        self.core.next_sample += u64::from(self.core.samples_per_frame);
        self.core.frames += 1;
        Some(FrameStats {
            counters,
            seconds: start.elapsed().as_secs_f64(),
            dropped: self.core.film.dropped() - dropped_before,
        })
    }

    /// The film resolved on the device and read back; black once the device failed
    /// (its film is gone with it: `failure` says why).
    fn image(&self) -> Image {
        self.device_image().and_then(|d| d.read().ok()).map_or_else(
            || Image::new(self.core.film.width(), self.core.film.height()),
            |img| (*img).clone(),
        )
    }

    fn image_on_device(&self) -> Option<std::sync::Arc<dyn ImageOnDevice>> {
        self.device_image().map(|d| std::sync::Arc::new(d) as _)
    }

    fn guides(&self, pass: Pass) -> Option<meso_render::Guides> {
        // No preview, so no preview's guides.
        (pass == Pass::Frame).then(|| self.host_guides()).flatten()
    }

    fn denoised_on_device(
        &self,
        image: &dyn ImageOnDevice,
        denoiser: &meso_render::Denoiser,
        strength: f32,
    ) -> Option<std::sync::Arc<dyn ImageOnDevice>> {
        self.denoise_on_device(image, denoiser, strength)
    }

    fn prepare_denoiser(&self) {
        self.make_denoiser_kernels();
    }

    fn progress(&self) -> Progress {
        Progress {
            frames: self.core.frames,
            min_samples: self.core.film.min_samples(),
            dropped: self.core.film.dropped() + self.adaptive_dropped(),
            width: self.core.film.width(),
            height: self.core.film.height(),
            film_bytes: self.core.film.bytes(),
            shows_every_pixel: self.core.film.min_samples() > 0,
        }
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.core.samples_per_frame = samples.max(1);
    }

    fn diagnostics(&self) -> Diagnostics {
        let b = self.device_bytes();
        let memory = vec![
            ("bvh", b.bvh),
            ("triangles", b.triangles),
            ("spmm_bases", b.spmm_bases),
            ("spmm_weights", b.spmm_weights),
            ("residual_tables", b.residual_tables),
            ("materials", b.materials),
            ("environment", b.environment),
            ("merl_tables", b.merl_tables),
            ("btf_tables", b.btf_tables),
            ("film", b.film),
        ];
        Diagnostics(vec![
            Diagnostic::Preparation(self.core.preparation.clone()),
            Diagnostic::DeviceMemory(memory),
            Diagnostic::Adapter(self.ctx.adapter_name()),
            Diagnostic::TraversalOverflows(self.overflows[0] + self.overflows[1]),
            Diagnostic::Summary(self.summary()),
        ])
    }

    fn failure(&self) -> Option<ModeError> {
        self.failure
            .as_ref()
            .map(|e| ModeError::DeviceFailed(e.to_string()))
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        // The guides are traced again when next asked for (one ray per pixel).
        if edit.changes_guides()
            && let Ok(d) = self.denoising.get_mut()
        {
            d.forget_guides();
        }
        let result = self.apply_edit(edit);
        // The film's fewest samples as the edit left them (one small read-back).
        if result.is_ok()
            && self.failure.is_none()
            && let Err(e) = self
                .core
                .film
                .recount(&self.core.layers.active(&self.core.scene))
        {
            self.failure = Some(e);
        }
        result
    }
}
