//! The `adaptive` mode (Bagher et al. 2013, sections 2-3): after each restart a
//! bandwidth pass (G-buffer, eq. 3-6 and 9 per pixel over n_b light directions, eq. 11
//! levels, min/max mip-maps) decides where to shade and how many samples to take; each
//! frame shades the pixels the bandwidth buffer assigns to it (a quadtree of blocks
//! whose min level reaches the block's level) with N_p samples (in proportion to the
//! predicted standard deviation, corrected by what the pixel's own samples show:
//! `allocation.rs`), and the image is up-sampled from them coarse to fine
//! (`upsample.rs`). Progressive: every `refine_frames` frames each level drops by one,
//! so every pixel is eventually shaded and the image converges to the per-pixel
//! integral the spmm mode computes.

use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

use glam::{DVec2, DVec3};

use super::allocation::{self, Moments};
use super::bandwidth::{EnvironmentBandwidth, LightBandwidth, LobeIndex, MaterialBandwidth};
use super::gbuffer::GBuffer;
use super::operators::{self, Bandwidth, Bounce};
use super::preconvolved::Prefiltered;
use super::upsample::{self, Guide};
use meso_materials::brdf::warp;
use meso_materials::image::Image;
use meso_materials::rng::SampleStream;
use meso_render::environment::{EnvironmentSampler, sampled_parts};
use meso_render::film::material_bit;
use meso_render::layers::{self, AMBIENT, ENVIRONMENT, LightTarget};
use meso_render::progressive::{Edited, Progressive};
use meso_render::scene::{Light, Material, Scene};
use meso_render::shading::{
    PointOnLight, ShadedMaterial, Shaders, Shading, point_on_light, power_heuristic as power,
    visible_light_point,
};
use meso_render::{
    Counters, Device, Diagnostic, Diagnostics, EditError, Film, FrameStats, Invalidation,
    ModeError, ModeKind, Pass, Prepare, Progress, RayCounts, RenderMode, SceneEdit, Unsupported,
};

/// Offset of secondary ray origins along the normal, relative to the hit point's
/// magnitude (the spmm mode's rule).
const EPSILON_REL: f64 = 1e-5;
/// Rec. 709 luminance.
const LUMINANCE: DVec3 = DVec3::new(0.2126, 0.7152, 0.0722);
/// Keeps this mode's random numbers apart from other modes' with the same seed.
const STREAM: u64 = 0x4144_4150_5449_5645; // "ADAPTIVE"

/// A direction the material draws for local `lo` at `uv`, kept only with a positive,
/// finite pdf.
fn drawn(material: &ShadedMaterial, uv: DVec2, lo: DVec3, u: DVec2) -> Option<(DVec3, f64)> {
    material
        .sample_local(uv, lo, u)
        .filter(|&(_, pdf)| pdf > 0.0 && pdf.is_finite())
}

/// The mode's knobs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveOptions {
    /// Light directions per emitter in the bandwidth pass (n_b of eq. 5 and 9).
    pub n_b: u32,
    /// The pre-convolved variant (ASFPCS, eq. 10): environment light from a low-passed
    /// map at the material's bandwidth, by BRDF sampling alone. Biased.
    pub preconvolved: bool,
    /// Mean samples per shaded pixel per frame (times `samples_per_frame`).
    pub mean_samples: f64,
    /// Most samples one pixel takes in a frame (times `samples_per_frame`).
    pub max_samples: u32,
    /// Frames between two refinements (every level drops by one).
    pub refine_frames: u32,
    /// The lowest rate a shaded pixel takes, as a share of `mean_samples` (every
    /// pixel keeps converging however quiet it is predicted to be).
    pub min_share: f64,
    /// Draw the environment map's peaks and its remainder each with a sampler of its
    /// own (`map_parts`), rather than the whole map with one.
    pub split_environment: bool,
}

impl Default for AdaptiveOptions {
    fn default() -> Self {
        Self {
            n_b: 16,
            preconvolved: false,
            mean_samples: 4.0,
            max_samples: 256,
            refine_frames: 2,
            min_share: 0.125,
            split_environment: true,
        }
    }
}

/// The environment map as the adaptive mode samples it: the whole map by one sampler
/// (the spmm mode's estimator), or, with `split`, its peaks and its remainder each by
/// its own (`sampled_parts`), so that a small sun holding half of a sky's power is in
/// every sample instead of in about every other one. A map without peaks stays whole;
/// a black one has no parts.
fn map_parts(map: &Arc<Image>, split: bool) -> Vec<(EnvironmentSampler, Arc<Image>)> {
    if let Some(parts) = split.then(|| sampled_parts(map)).flatten() {
        return parts.into();
    }
    EnvironmentSampler::new(map)
        .map(|sampler| (sampler, Arc::clone(map)))
        .into_iter()
        .collect()
}

/// One part of the environment map and its sampler, as a sample draws it.
#[derive(Clone, Copy)]
pub(super) struct MapPart<'a> {
    sampler: &'a EnvironmentSampler,
    map: &'a Image,
}

/// Material bandwidths analysed in this process, by table (a MERL material is
/// analysed once however often a mode is made for it).
fn material_bandwidth(m: &Material) -> Option<Arc<MaterialBandwidth>> {
    use std::collections::HashMap;
    use std::sync::{Mutex, OnceLock, Weak};
    type Cache =
        Mutex<HashMap<usize, (Weak<meso_materials::merl::MerlBrdf>, Arc<MaterialBandwidth>)>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let Material::Merl { brdf, .. } = m else {
        return MaterialBandwidth::of_material(m).map(Arc::new);
    };
    let key = Arc::as_ptr(brdf) as usize;
    let cache = CACHE.get_or_init(Default::default);
    if let Some((weak, bw)) = cache.lock().expect("not poisoned").get(&key)
        && weak.upgrade().is_some_and(|b| Arc::ptr_eq(&b, brdf))
    {
        return Some(bw.clone());
    }
    let bw = Arc::new(MaterialBandwidth::of_material(m)?);
    let mut c = cache.lock().expect("not poisoned");
    c.retain(|_, (w, _)| w.strong_count() > 0);
    c.insert(key, (Arc::downgrade(brdf), bw.clone()));
    Some(bw)
}

mod frame;
#[cfg(feature = "gpu")]
mod gpu;
mod pass;
#[cfg(test)]
mod tests;

pub use frame::Plan;
#[cfg(feature = "gpu")]
pub use gpu::GpuAdaptiveMode;
pub use pass::Buffers;
use pass::PassProgress;

/// The adaptive mode on the CPU.
pub struct AdaptiveMode {
    /// Scene, BVH, camera, film and layers, counters, preparation.
    core: Progressive<Film>,
    /// The environment map's parts as the frames and the pass draw them: the whole
    /// map, or its peaks and its remainder (`AdaptiveOptions::split_environment`);
    /// empty without an environment or with a black map.
    env_parts: Vec<(EnvironmentSampler, Arc<Image>)>,
    env_bandwidth: Option<EnvironmentBandwidth>,
    prefiltered: Option<Prefiltered>,
    light_bandwidth: Vec<Option<LightBandwidth>>,
    materials: Vec<Option<Arc<MaterialBandwidth>>>,
    /// Edited materials whose bandwidth is being analysed on a thread of its own (a
    /// second or more for a pack), by material index: taken up by the next frame.
    analysing: Vec<Analysis>,
    /// The materials as the shading core shades them.
    shaders: Shaders,
    light_targets: Vec<LightTarget>,
    options: AdaptiveOptions,
    /// Samples each pixel took itself since the last restart.
    own: Vec<u32>,
    /// Pixels that became sites after the first frame since the last restart (a
    /// refinement added them): their own means stand once mature (`upsample::trusted`).
    added: Vec<bool>,
    /// Each pixel's own samples' luminance moments since the last restart or emission
    /// edit: their variance corrects the pass's prediction (`plan_frame`).
    moments: Vec<Moments>,
    buffers: Option<Buffers>,
    plan: Option<Plan>,
    /// Work a yielding call left for the next call (`render_frame_yielding`).
    unfinished: Option<Unfinished>,
    /// The preview shown until the first frame is done (`render_preview`): one sample
    /// at each previewed pixel, kept apart from the film.
    preview: Option<Image>,
}

/// A material's bandwidth analysed on a thread of its own, at most one per material:
/// an edit made while it runs marks it `stale`, and a new one of the material as it
/// then is starts when it ends (a slider drag analyses its latest step, not every one).
struct Analysis {
    index: usize,
    thread: JoinHandle<Option<Arc<MaterialBandwidth>>>,
    stale: bool,
}

/// `material_bandwidth` of `m` on a thread with a one-thread pool of its own (in the
/// shared pool its rows would queue ahead of the frames'); `None` if no thread starts.
fn analyse_beside(m: Material) -> Option<JoinHandle<Option<Arc<MaterialBandwidth>>>> {
    std::thread::Builder::new()
        .name("meso-bandwidth".into())
        .spawn(
            move || match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
                Ok(pool) => pool.install(|| material_bandwidth(&m)),
                Err(_) => material_bandwidth(&m),
            },
        )
        .ok()
}

/// Pixels per step of a yielding frame's shading (rows of about this many pixels): a
/// step costs about what the spmm mode's 16K-pixel tiles do, since only some pixels
/// of a frame are shaded.
const TILE_PIXELS: u32 = 8_192;
/// Pixels per step of a yielding bandwidth pass: its analysis costs 12-20 us a pixel on
/// one core (100-160 ms at 128 x 128 and 1.6 s at 512 x 512 on 2 cores), so a step
/// takes 12-20 ms on 2 cores.
const PASS_TILE_PIXELS: u32 = 2_048;

/// A frame left unfinished by `render_frame_yielding`, resumed by the next call of
/// either `render_frame` kind, so the film ends as an uninterrupted frame's.
enum Unfinished {
    /// The bandwidth pass: the G-buffer and the analyses of the first rows.
    Pass(PassProgress),
    /// The frame's shading by `plan`: rows below `rows_done` are shaded.
    Shading { plan: Plan, rows_done: u32 },
}

impl AdaptiveMode {
    /// What this mode cannot render: nothing the spmm mode renders. Analytic BRDFs,
    /// MERL tables, SPMM packs and `btf` tables are shaded by the shading core, their
    /// bandwidths from their lobes (`MaterialBandwidth::of_material`); mirrors reflect
    /// the ray as in the spmm mode, their pixels shaded at level 0; point lights and the
    /// ambient term are taken as the spmm mode takes them, the pass guarding their
    /// shadows. It answers like every mode, so the registry asks them alike.
    pub fn supports(_scene: &Scene) -> Result<(), Unsupported> {
        Ok(())
    }

    pub fn prepare(
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        Self::prepare_with(scene, width, height, prepare, AdaptiveOptions::default())
    }

    /// `prepare` with other knobs (the reports' variants).
    pub fn prepare_with(
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
        options: AdaptiveOptions,
    ) -> Result<Self, ModeError> {
        let mut core = Progressive::prepare(scene, width, height, &prepare, Self::supports)?;
        let scene = &core.scene;
        let start = Instant::now();
        let mut materials = Vec::with_capacity(scene.materials.len());
        for (i, m) in scene.materials.iter().enumerate() {
            prepare.report(
                "material bandwidth",
                i as f32 / scene.materials.len() as f32,
            )?;
            materials.push(material_bandwidth(m));
        }
        core.preparation.record_since("material bandwidth", start);
        prepare.report("environment", 0.0)?;
        let start = Instant::now();
        let mut mode = Self {
            env_parts: Vec::new(),
            env_bandwidth: None,
            prefiltered: None,
            light_bandwidth: Vec::new(),
            materials,
            analysing: Vec::new(),
            shaders: Shaders::new(&core.scene.materials),
            light_targets: core.layers.light_targets(&core.scene),
            options: AdaptiveOptions {
                n_b: options.n_b.max(1),
                refine_frames: options.refine_frames.max(1),
                max_samples: options.max_samples.max(1),
                ..options
            },
            own: vec![0; (width * height) as usize],
            added: vec![false; (width * height) as usize],
            moments: vec![Moments::default(); (width * height) as usize],
            buffers: None,
            plan: None,
            unfinished: None,
            preview: None,
            core,
        };
        mode.refresh_emitters();
        mode.core.preparation.record_since("environment", start);
        prepare.report("environment", 1.0)?;
        Ok(mode)
    }

    /// The environment's sampler, bandwidth and filtered levels, the lights' bandwidths
    /// and film targets, after an emitter change.
    fn refresh_emitters(&mut self) {
        let env = self.core.scene.environment.as_ref();
        self.env_parts = env.map_or_else(Vec::new, |e| {
            map_parts(
                &e.map,
                self.options.split_environment && !self.options.preconvolved,
            )
        });
        self.env_bandwidth = env.map(|e| EnvironmentBandwidth::analyse(&e.map));
        self.prefiltered = env
            .filter(|_| self.options.preconvolved)
            .map(|e| Prefiltered::new(&e.map));
        self.light_bandwidth = self
            .core
            .scene
            .lights
            .iter()
            .map(LightBandwidth::analyse)
            .collect();
        self.light_targets = self.core.layers.light_targets(&self.core.scene);
    }

    /// The parts of the environment map a sample draws (at most two, the count
    /// after them); `None` without one.
    fn map_parts(&self) -> Option<([MapPart<'_>; 2], usize)> {
        fn part((sampler, map): &(EnvironmentSampler, Arc<Image>)) -> MapPart<'_> {
            MapPart { sampler, map }
        }
        let first = part(self.env_parts.first()?);
        let second = self.env_parts.get(1).map_or(first, part);
        Some(([first, second], self.env_parts.len()))
    }

    pub fn options(&self) -> AdaptiveOptions {
        self.options
    }

    /// The bandwidth buffer of the current view (after the first frame).
    pub fn buffers(&self) -> Option<&Buffers> {
        self.buffers.as_ref()
    }

    /// The last frame's plan: which pixels it shaded, with how many samples.
    pub fn plan(&self) -> Option<&Plan> {
        self.plan.as_ref()
    }

    /// Samples each pixel took itself since the last restart.
    pub fn own_samples(&self) -> &[u32] {
        &self.own
    }

    pub fn width(&self) -> u32 {
        self.core.film.width()
    }

    pub fn height(&self) -> u32 {
        self.core.film.height()
    }

    /// The coarsest pyramid level: min(floor(log2 W), floor(log2 H)).
    pub fn top_level(&self) -> u32 {
        self.width().min(self.height()).max(1).ilog2()
    }

    fn fov(&self) -> (f64, f64) {
        let fy = self.core.scene.camera.fov_y_deg.to_radians();
        let fx = 2.0 * ((fy * 0.5).tan() * self.width() as f64 / self.height() as f64).atan();
        (fx, fy)
    }

    /// Screen axes in world space (x right, y down), as the pinhole camera builds them.
    fn screen_axes(&self) -> (DVec3, DVec3) {
        let c = &self.core.scene.camera;
        let forward = (c.look_at - c.position).normalize();
        let right = forward.cross(c.up).normalize();
        let up = right.cross(forward);
        (right, -up)
    }
    /// Forgets every sample and the bandwidth buffer.
    fn restart_all(&mut self) -> Invalidation {
        self.buffers = None;
        self.restart_samples()
    }

    /// Forgets every sample but keeps the bandwidth pass's buffers (the view and the
    /// lighting they were made for are unchanged).
    fn restart_samples(&mut self) -> Invalidation {
        self.core.film.reset();
        self.core.restart_counters();
        self.own.iter_mut().for_each(|c| *c = 0);
        self.added.iter_mut().for_each(|a| *a = false);
        self.moments
            .iter_mut()
            .for_each(|m| *m = Moments::default());
        self.plan = None;
        self.unfinished = None;
        self.preview = None;
        Invalidation::All
    }

    /// Takes up the bandwidths of edited materials analysed since the last call. A
    /// material whose lobes became markedly sharper (its mean peak rate up by more
    /// than a quarter) restarts the pass, so its detail is not up-sampled from sites
    /// placed for the softer one; otherwise the buffers stand until the next pass.
    /// True if the pass should run again (the GPU mode's cue: it keeps its own).
    pub(super) fn take_analyses(&mut self) -> bool {
        let mut sharper = false;
        for a in std::mem::take(&mut self.analysing) {
            if !a.thread.is_finished() {
                self.analysing.push(a);
                continue;
            }
            let index = a.index;
            match a.thread.join() {
                Ok(_) if a.stale => self.analyse(index),
                Ok(bandwidth) => {
                    let peak =
                        |b: &Option<Arc<MaterialBandwidth>>| b.as_ref().map(|b| b.mean_peak());
                    sharper |= match (peak(&self.materials[index]), peak(&bandwidth)) {
                        (Some(old), Some(new)) => new > 1.25 * old,
                        (old, new) => old.is_some() != new.is_some(),
                    };
                    self.materials[index] = bandwidth;
                }
                // The thread died: analyse here.
                Err(_) => {
                    self.materials[index] = material_bandwidth(&self.core.scene.materials[index]);
                }
            }
        }
        if sharper && self.buffers.is_some() {
            self.restart_all();
        }
        sharper
    }

    /// Starts analysing material `index` as the scene has it now, or marks the
    /// analysis under way stale; analyses here if no thread starts.
    fn analyse(&mut self, index: usize) {
        if let Some(a) = self.analysing.iter_mut().find(|a| a.index == index) {
            a.stale = true;
            return;
        }
        let m = self.core.scene.materials[index].clone();
        match analyse_beside(m) {
            Some(thread) => self.analysing.push(Analysis {
                index,
                thread,
                stale: false,
            }),
            None => self.materials[index] = material_bandwidth(&self.core.scene.materials[index]),
        }
    }

    /// The pixels' own means, before up-sampling.
    fn own_means(&self) -> Vec<DVec3> {
        let img = self
            .core
            .film
            .resolve(&self.core.layers.weights(&self.core.scene));
        img.pixels()
            .iter()
            .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect()
    }
}
impl RenderMode for AdaptiveMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Adaptive
    }

    fn device(&self) -> Device {
        Device::Cpu
    }

    fn scene(&self) -> &Scene {
        &self.core.scene
    }

    fn render(&mut self, pass: Pass, stop: Option<&mut dyn FnMut() -> bool>) -> Option<FrameStats> {
        match pass {
            Pass::Frame => {
                // A pass that starts before an analysis is done uses the lobes before
                // the edit; a markedly sharper result restarts it when it arrives.
                self.take_analyses();
                Some(self.render_tiles(stop))
            }
            Pass::Preview { stride } => self.render_preview_pass(stride),
        }
    }

    fn image(&self) -> Image {
        if self.core.frames == 0
            && let Some(preview) = &self.preview
        {
            return preview.clone();
        }
        let (w, h) = (self.width(), self.height());
        let mut values = self.own_means();
        if let Some(b) = &self.buffers {
            let has = upsample::trusted(&b.guide, &self.own, &self.added, self.top_level());
            upsample::upsample(&b.guide, &has, &mut values, self.top_level());
        }
        let mut img = Image::new(w, h);
        for (p, v) in img.pixels_mut().iter_mut().zip(values) {
            *p = [v.x as f32, v.y as f32, v.z as f32];
        }
        img
    }
    fn progress(&self) -> Progress {
        Progress {
            frames: self.core.frames,
            min_samples: self.own.iter().copied().min().unwrap_or(0),
            dropped: self.core.film.dropped(),
            width: self.width(),
            height: self.height(),
            film_bytes: self.core.film.bytes(),
            // After a frame every pixel has its own samples or up-sampled ones.
            shows_every_pixel: self.core.frames > 0,
        }
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        Ok(match self.core.apply(&edit)? {
            Edited::Emitters(invalidation) => {
                self.light_targets = self.core.layers.light_targets(&self.core.scene);
                if invalidation == Invalidation::Nothing {
                    // Emission edits re-weight the layers; the buffer's N_p keeps the old
                    // emissions' proportions until the next restart, and the measured
                    // variances, of the old weights, start again.
                    self.moments
                        .iter_mut()
                        .for_each(|m| *m = Moments::default());
                    return Ok(Invalidation::Nothing);
                }
                // Up-sampled pixels mix every layer: anything else restarts all.
                self.refresh_emitters();
                self.restart_all()
            }
            Edited::Camera => self.restart_all(),
            Edited::Resized => {
                let pixels = (self.width() * self.height()) as usize;
                self.own = vec![0; pixels];
                self.added = vec![false; pixels];
                self.moments = vec![Moments::default(); pixels];
                self.restart_all()
            }
            Edited::Meshes => {
                self.core.bvh.update(&self.core.scene.meshes);
                self.restart_all()
            }
            Edited::Material { index, before } => {
                let after = &self.core.scene.materials[index];
                self.shaders.edited(index, Some(&before), after);
                // The material's bandwidth only steers where samples go: the analysis
                // (over a second for a pack) runs on a thread of its own, and the frames
                // go on with the pass's buffers meanwhile (`take_analyses`). The film
                // restarts: every sample shaded the old material or was up-sampled
                // from samples that did.
                self.analyse(index);
                self.restart_samples()
            }
            // The mode shades the same still or moving (its frames are already cheap)
            // and picks its own light samples per pixel.
            Edited::Moving | Edited::Nothing | Edited::LightSamples => Invalidation::Nothing,
        })
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.core.samples_per_frame = samples.max(1);
    }

    fn diagnostics(&self) -> Diagnostics {
        let overlays = super::overlay::overlays(self)
            .into_iter()
            .map(|(name, image)| Diagnostic::Overlay { name, image });
        Diagnostics(
            std::iter::once(Diagnostic::Preparation(self.core.preparation.clone()))
                .chain(overlays)
                .collect(),
        )
    }
}
