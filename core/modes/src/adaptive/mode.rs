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
use std::time::Instant;

use glam::{DVec2, DVec3};

use super::allocation::{self, Moments};
use super::bandwidth::{EnvironmentBandwidth, LightBandwidth, LobeIndex, MaterialBandwidth};
use super::gbuffer::GBuffer;
use super::operators::{self, Bandwidth, Bounce};
use super::preconvolved::Prefiltered;
use super::surface::{self, Surface};
use super::upsample::{self, Guide};
use meso_materials::brdf::warp;
use meso_materials::image::Image;
use meso_materials::rng::SampleStream;
use meso_render::environment::{EnvironmentSampler, rotate_y};
use meso_render::film::{material_bit, memory_limit_bytes};
use meso_render::geometry::{PinholeCamera, SceneBvh};
use meso_render::layers::{self, Before, ENVIRONMENT, Layers, LightTarget};
use meso_render::scene::{Light, Material, RenderSettings, Scene};
use meso_render::{
    Counters, Device, Diagnostic, Diagnostics, EditError, Film, FrameStats, Invalidation,
    ModeError, ModeKind, Pass, PreparationReport, Prepare, Progress, RayCounts, RenderMode,
    SceneEdit, Unrenderable, Unsupported,
};

/// Offset of secondary ray origins along the normal, relative to the hit point's
/// magnitude (the spmm mode's rule).
const EPSILON_REL: f64 = 1e-5;
/// Rec. 709 luminance.
const LUMINANCE: DVec3 = DVec3::new(0.2126, 0.7152, 0.0722);
/// Keeps this mode's random numbers apart from other modes' with the same seed.
const STREAM: u64 = 0x4144_4150_5449_5645; // "ADAPTIVE"

/// The power heuristic's weight of a strategy with pdf `a` against one with pdf `b`
/// (Veach 1997, ch. 9).
fn power(a: f64, b: f64) -> f64 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
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
        }
    }
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
    /// Max-filtered `sigma`, per level (level 0 = `sigma`).
    sigma_mip: Vec<Vec<f64>>,
    /// Seconds of the G-buffer (part of `seconds`).
    pub gbuffer_seconds: f64,
    /// Seconds the pass took.
    pub seconds: f64,
}

/// The order in which each strategy other than the table's visits the bandwidth
/// pass's strata (`AdaptiveMode::strata_orders`).
struct StrataOrders {
    map: Vec<u32>,
    /// Per scene light.
    lights: Vec<Vec<u32>>,
}

/// What the bandwidth pass finds at one pixel.
struct PixelAnalysis {
    /// Eq. 5 at the eye.
    nu: Bandwidth,
    /// Eq. 9's sum (eq. 10's for the pre-convolved variant) and eq. 9's.
    eq9: [f64; 2],
    /// The visible share of the lambda weights (the visibility guard).
    visible: f64,
    /// The frames' estimator over the n_b directions.
    moments: allocation::Moments,
}

/// A per-level pyramid of `values` over blocks of 2^k pixels (top-left aligned),
/// reduced by `f`.
fn mip(values: &[f64], w: u32, h: u32, top: u32, f: impl Fn(f64, f64) -> f64) -> Vec<Vec<f64>> {
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

/// True if pixel (x, y)'s visible share differs from a 4-neighbour's by more than
/// `VISIBILITY_STEP`.
fn visibility_edge(visible: &[f64], w: u32, h: u32, x: u32, y: u32) -> bool {
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
fn radiance_edge(mean: &[f64], w: u32, h: u32, x: u32, y: u32, floor: f64) -> bool {
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

/// Which pixels a frame shades: per pixel, 0 (up-sampled) or its sample count.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Per pixel: the level of the leaf block it heads, or `None` if it is up-sampled.
    pub site_level: Vec<Option<u32>>,
    pub samples: Vec<u32>,
}

/// The adaptive mode on the CPU.
pub struct AdaptiveMode {
    scene: Scene,
    bvh: SceneBvh,
    camera: PinholeCamera,
    env_sampler: Option<EnvironmentSampler>,
    env_bandwidth: Option<EnvironmentBandwidth>,
    prefiltered: Option<Prefiltered>,
    light_bandwidth: Vec<Option<LightBandwidth>>,
    materials: Vec<Option<Arc<MaterialBandwidth>>>,
    film: Film,
    layers: Layers,
    light_targets: Vec<LightTarget>,
    options: AdaptiveOptions,
    samples_per_frame: u32,
    frames: u32,
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
    preparation: PreparationReport,
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

/// The bandwidth pass so far.
struct PassProgress {
    g: GBuffer,
    orders: StrataOrders,
    /// Per pixel of the rows analysed so far, row-major.
    per_pixel: Vec<PixelAnalysis>,
    gbuffer_seconds: f64,
    /// Seconds spent on it so far (a yielded pass pauses between rows).
    seconds: f64,
}

impl AdaptiveMode {
    /// What this mode cannot render: materials other than analytic BRDFs and MERL
    /// tables (mirrors, SPMM packs), point lights (a delta's spectrum has no bound)
    /// and the ambient term; each by name.
    pub fn supports(scene: &Scene) -> Result<(), Unsupported> {
        let mut parts: Vec<Unrenderable> = scene
            .materials
            .iter()
            .enumerate()
            .filter_map(|(i, m)| Self::unrenderable_material(scene, i, m))
            .collect();
        parts.extend(
            scene
                .lights
                .iter()
                .enumerate()
                .filter_map(|(i, l)| Self::unrenderable_light(i, l)),
        );
        if scene.ambient.is_some() {
            parts.push(Unrenderable::Ambient);
        }
        Unsupported::check(ModeKind::Adaptive, Device::Cpu, parts)
    }

    fn unrenderable_material(scene: &Scene, index: usize, m: &Material) -> Option<Unrenderable> {
        (!matches!(m, Material::Brdf { .. } | Material::Merl { .. })).then(|| {
            Unrenderable::Material {
                index,
                name: scene
                    .material_names
                    .get(index)
                    .cloned()
                    .unwrap_or_else(|| format!("#{index}")),
                kind: m.kind_name(),
            }
        })
    }

    fn unrenderable_light(index: usize, l: &Light) -> Option<Unrenderable> {
        matches!(l, Light::Point { .. }).then_some(Unrenderable::Light {
            index,
            kind: "point",
        })
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
        if let Some(p) = RenderSettings::size_problem(width, height) {
            return Err(ModeError::Size(p));
        }
        Self::supports(&scene)?;
        let layers = Layers::new(&scene);
        let film = Film::try_new(
            width,
            height,
            layers.layer_count(&scene),
            memory_limit_bytes(),
        )?;
        let mut report = PreparationReport::default();
        let bvh = prepare.bvh(&scene.meshes, &mut report)?;
        let start = Instant::now();
        let mut materials = Vec::with_capacity(scene.materials.len());
        for (i, m) in scene.materials.iter().enumerate() {
            prepare.report(
                "material bandwidth",
                i as f32 / scene.materials.len() as f32,
            )?;
            materials.push(material_bandwidth(m));
        }
        report.record_since("material bandwidth", start);
        prepare.report("environment", 0.0)?;
        let start = Instant::now();
        let mut mode = Self {
            bvh,
            camera: PinholeCamera::new(&scene.camera, width, height),
            env_sampler: None,
            env_bandwidth: None,
            prefiltered: None,
            light_bandwidth: Vec::new(),
            materials,
            film,
            light_targets: layers.light_targets(&scene),
            layers,
            options: AdaptiveOptions {
                n_b: options.n_b.max(1),
                refine_frames: options.refine_frames.max(1),
                max_samples: options.max_samples.max(1),
                ..options
            },
            samples_per_frame: 1,
            frames: 0,
            own: vec![0; (width * height) as usize],
            added: vec![false; (width * height) as usize],
            moments: vec![Moments::default(); (width * height) as usize],
            buffers: None,
            plan: None,
            unfinished: None,
            preview: None,
            preparation: PreparationReport::default(),
            scene,
        };
        mode.refresh_emitters();
        report.record_since("environment", start);
        prepare.report("environment", 1.0)?;
        mode.preparation = report;
        Ok(mode)
    }

    /// The environment's sampler, bandwidth and filtered levels, the lights' bandwidths
    /// and film targets, after an emitter change.
    fn refresh_emitters(&mut self) {
        let env = self.scene.environment.as_ref();
        self.env_sampler = env.and_then(|e| EnvironmentSampler::new(&e.map));
        self.env_bandwidth = env.map(|e| EnvironmentBandwidth::analyse(&e.map));
        self.prefiltered = env
            .filter(|_| self.options.preconvolved)
            .map(|e| Prefiltered::new(&e.map));
        self.light_bandwidth = self
            .scene
            .lights
            .iter()
            .map(LightBandwidth::analyse)
            .collect();
        self.light_targets = self.layers.light_targets(&self.scene);
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
        self.film.width()
    }

    pub fn height(&self) -> u32 {
        self.film.height()
    }

    /// The coarsest pyramid level: min(floor(log2 W), floor(log2 H)).
    pub fn top_level(&self) -> u32 {
        self.width().min(self.height()).max(1).ilog2()
    }

    fn fov(&self) -> (f64, f64) {
        let fy = self.scene.camera.fov_y_deg.to_radians();
        let fx = 2.0 * ((fy * 0.5).tan() * self.width() as f64 / self.height() as f64).atan();
        (fx, fy)
    }

    /// Screen axes in world space (x right, y down), as the pinhole camera builds them.
    fn screen_axes(&self) -> (DVec3, DVec3) {
        let c = &self.scene.camera;
        let forward = (c.look_at - c.position).normalize();
        let right = forward.cross(c.up).normalize();
        let up = right.cross(forward);
        (right, -up)
    }

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
    fn begin_pass(&self) -> PassProgress {
        let start = Instant::now();
        let (w, h) = (self.width(), self.height());
        let g = GBuffer::build(&self.scene, &self.bvh, w, h);
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
    fn analyse_rows(&self, pass: &mut PassProgress, rows: u32) {
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
    fn finish_pass(&self, pass: PassProgress) -> Buffers {
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
        let dark = 1e-3 * mean.iter().map(|m| m.abs()).sum::<f64>() / mean.len().max(1) as f64;
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
    fn strata_orders(&self) -> StrataOrders {
        let n_b = self.options.n_b;
        let order = |strategy: u64| -> Vec<u32> {
            let rng = SampleStream::new(&[self.scene.render.seed, STREAM, 0xBA4D, strategy]);
            let mut order: Vec<u32> = (0..n_b).collect();
            for i in (1..order.len()).rev() {
                let j = (rng.at(i as u64) * (i + 1) as f64) as usize;
                order.swap(i, j.min(i));
            }
            order
        };
        StrataOrders {
            map: order(0),
            lights: (0..self.scene.lights.len())
                .map(|l| order(1 + l as u64))
                .collect(),
        }
    }

    fn pixel_bandwidth(&self, g: &GBuffer, i: u32, orders: &StrataOrders) -> PixelAnalysis {
        let px = &g.pixels[i as usize];
        let mut moments = allocation::Moments::default();
        let Some(s) = &px.surface else {
            // A ray that leaves the scene sees the environment directly (no bounce).
            let nu = match (
                &self.scene.background,
                &self.scene.environment,
                &self.env_bandwidth,
            ) {
                (meso_render::scene::Background::FromEnvironment, Some(e), Some(b)) => {
                    b.rate(e, px.dir)
                }
                _ => 0.0,
            };
            if let Some((layer, radiance)) = layers::escaped(&self.scene, px.dir) {
                let weight = self.layers.weights(&self.scene)[layer];
                moments.add((radiance * weight).dot(LUMINANCE));
            }
            return PixelAnalysis {
                nu: DVec2::new(0.0, nu),
                eq9: [0.0; 2],
                visible: 1.0,
                moments,
            };
        };
        let material = &self.scene.materials[s.material];
        let quiet = PixelAnalysis {
            nu: DVec2::ZERO,
            eq9: [0.0; 2],
            visible: 1.0,
            moments,
        };
        let Some(mat_bw) = &self.materials[s.material] else {
            return quiet;
        };
        let wo = -px.dir;
        let lo = s.to_local(wo);
        if lo.z <= 0.0 {
            return quiet;
        }
        let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
        let n_b = self.options.n_b;
        let side = (n_b as f64).sqrt().ceil() as u32;
        // One shift for every pixel: neighbours see the same strata, so a change of
        // visibility between them is the scene's, not the sampling's.
        let rng = SampleStream::new(&[self.scene.render.seed, STREAM, 0xBA4D]);
        let shift = DVec2::new(rng.at(0), rng.at(1));
        let stratum = |k: u32| {
            let u = DVec2::new(
                ((k % side) as f64 + 0.5) / side as f64,
                ((k / side) as f64 + 0.5) / side as f64,
            ) + shift;
            DVec2::new(u.x.fract(), u.y.fract())
        };
        // The frames' estimator's value per direction k (luminance, emissions applied):
        // its strategies (map, table, light) at the k-th stratum, with its MIS weights.
        let mut value = vec![0.0; n_b as usize];
        // Eq. 5's lambda without the common 1 / n_b (eq. 5 is a ratio).
        let mut paths: Vec<(f64, Bandwidth)> =
            Vec::with_capacity(n_b as usize * (1 + self.scene.lights.len()));
        let mut variance = 0.0;
        let mut variance_full = 0.0;
        let (mut visible, mut guarded) = (0.0, 0.0);
        let preconvolved = self.options.preconvolved;
        let at_lo = LobeIndex::of(lo);
        let mut bounce = |li: DVec3,
                          l_in: Bandwidth,
                          d_light: f64,
                          radiance: f64,
                          weight: f64,
                          seen: Option<bool>| {
            let f = surface::brdf(material, li, lo).dot(LUMINANCE);
            let at_li = LobeIndex::of(li);
            let b = Bounce {
                cos_i: li.z,
                cos_o: lo.z,
                curvature: px.curvature,
                rho: mat_bw.rate_of(at_li, at_lo),
            };
            let nu = operators::one_bounce(l_in, d_light, &b, px.depth);
            let lambda = radiance * f * li.z * weight;
            paths.push((lambda, nu));
            if let Some(seen) = seen {
                guarded += lambda;
                if seen {
                    visible += lambda;
                }
            }
            let incident = operators::transport(l_in, d_light).y.abs();
            let chi = radiance * f;
            let rho_view = mat_bw.rate_of(at_lo, at_li);
            variance += operators::variance_term(incident, rho_view, chi, preconvolved) * weight;
            variance_full += operators::variance_term(incident, rho_view, chi, false) * weight;
            lambda
        };
        // Table-drawn directions (cosine where the material draws none), shared by the
        // environment's bounces and the table strategy of the area lights.
        let drawn: Vec<Option<(DVec3, f64)>> = (0..n_b)
            .map(|k| {
                let u = stratum(k);
                let (li, pdf) = surface::sample(material, lo, u).unwrap_or_else(|| {
                    let li = warp::cosine_hemisphere(u);
                    (li, li.z / std::f64::consts::PI)
                });
                (pdf > 0.0 && li.z > 0.0).then_some((li, pdf))
            })
            .collect();
        let merl = matches!(material, Material::Merl { .. });
        if let (Some(env), Some(env_bw)) = (&self.scene.environment, &self.env_bandwidth) {
            for (k, d) in drawn.iter().enumerate() {
                // BRDF-importance-sampled directions, so a sharp lobe is seen by a few
                // of the n_b directions.
                let Some((li, pdf)) = *d else { continue };
                let wi = s.to_world(li);
                let radiance = env.radiance_unit(wi).dot(LUMINANCE) * env.strength;
                let nu_a = env_bw.rate(env, wi);
                let seen = (k < GUARD_RAYS as usize)
                    .then(|| !self.bvh.occluded(lift, wi, 0.0, f64::INFINITY));
                let lambda = bounce(li, DVec2::new(0.0, nu_a), 0.0, radiance, 1.0 / pdf, seen);
                if env.mis
                    && let Some(sampler) = &self.env_sampler
                {
                    let map_pdf = sampler.pdf(rotate_y(wi, -env.rotate_y_deg));
                    value[k] += lambda * power(pdf, map_pdf);
                }
            }
            for (k, v) in value.iter_mut().enumerate() {
                // The map's strategy, at its own stratum.
                let Some(sampler) = &self.env_sampler else {
                    break;
                };
                let e = sampler.sample(&env.map, stratum(orders.map[k]));
                let wi = rotate_y(e.dir, env.rotate_y_deg);
                let li = s.to_local(wi);
                if li.z <= 0.0 || e.pdf <= 0.0 {
                    continue;
                }
                let weight = if env.mis {
                    power(e.pdf, surface::pdf(material, lo, li))
                } else {
                    1.0
                };
                let f = surface::brdf(material, li, lo).dot(LUMINANCE);
                *v += f * li.z * e.radiance.dot(LUMINANCE) * env.strength * weight / e.pdf;
            }
        }
        for (index, (light, bw)) in self
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
            for k in 0..n_b {
                let u = stratum(orders.lights[index][k as usize]);
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
                        .bvh
                        .occluded(lift, wi, 0.0, (q - lift).length() * (1.0 - 1e-6))
                });
                let lambda = bounce(
                    li,
                    DVec2::new(bw.rate(u.x, u.y), 0.0),
                    d,
                    emitted,
                    falloff,
                    seen,
                );
                let weight = if merl {
                    power(1.0 / falloff, surface::pdf(material, lo, li))
                } else {
                    1.0
                };
                value[k as usize] += lambda * weight;
            }
            if merl {
                // The table's strategy for the light, as the frames draw it.
                for (k, d) in drawn.iter().enumerate() {
                    let Some((li, pdf)) = *d else { continue };
                    let wi = s.to_world(li);
                    if let Some((_, falloff)) =
                        meso_render::geometry::hit_parallelogram(s.p, wi, corner, edge_u, edge_v)
                    {
                        let f = surface::brdf(material, li, lo).dot(LUMINANCE);
                        value[k] += emitted * f * li.z / pdf * power(pdf, 1.0 / falloff);
                    }
                }
            }
        }
        variance /= n_b as f64;
        variance_full /= n_b as f64;
        for v in value {
            moments.add(v);
        }
        let share = if guarded > 0.0 {
            visible / guarded
        } else {
            1.0
        };
        PixelAnalysis {
            nu: operators::weighted(&paths),
            eq9: [variance, variance_full],
            visible: share,
            moments,
        }
    }

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
            allocation::corrected_sigma(predicted, &self.moments[i])
        };
        let (mut sum, mut count) = (0.0, 0usize);
        for (i, s) in site_level.iter().enumerate() {
            if let Some(k) = s {
                sum += block_sigma(i, *k);
                count += 1;
            }
        }
        let mean_sigma = if count > 0 { sum / count as f64 } else { 0.0 };
        let spf = f64::from(self.samples_per_frame);
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
        let weights = self.layers.weights(&self.scene);
        let mut out = vec![DVec3::ZERO; self.film.layers()];
        let mut counts = RayCounts::default();
        self.sample_into(x, y, index, &mut out, &mut counts);
        out.iter().zip(&weights).map(|(o, w)| *o * *w).sum()
    }

    /// One sample of pixel (x, y), per film layer for unit emission.
    fn sample_into(
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
        let render = &self.scene.render;
        let mut rng = SampleStream::for_sample(render.sampler, render.seed ^ STREAM, index, pixel);
        let ray = self.camera.ray(x, y, rng.next_2d());
        counts.primary += 1;
        let Some(hit) = self
            .bvh
            .closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY)
        else {
            if let Some((layer, radiance)) = layers::escaped(&self.scene, ray.dir) {
                out[layer] += radiance;
            }
            return 0;
        };
        let s = Surface::at(&self.scene, &hit, ray.dir);
        let material = &self.scene.materials[s.material];
        let wo = -ray.dir;
        let lo = s.to_local(wo);
        let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
        // MERL lobes can be far narrower than a light: their area lights are sampled by
        // light and table samples with MIS, as the spmm mode does.
        let mis = matches!(material, Material::Merl { .. });
        for (k, light) in self.scene.lights.iter().enumerate() {
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
                .bvh
                .occluded(lift, wi, 0.0, (q - lift).length() * (1.0 - 1e-6))
            {
                let target = self.light_targets[k];
                let li = s.to_local(wi);
                let weight = if mis {
                    power(1.0 / falloff, surface::pdf(material, lo, li))
                } else {
                    1.0
                };
                let f = surface::brdf(material, li, lo);
                out[target.layer] += f * cos_i * falloff * weight * target.factor;
            }
        }
        if mis {
            // The table's strategy for each area light, as the spmm mode draws it.
            for (k, light) in self.scene.lights.iter().enumerate() {
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
                let Some((li, pdf)) = surface::sample(material, lo, u) else {
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
                if self.bvh.occluded(lift, wi, 0.0, distance * (1.0 - 1e-6)) {
                    continue;
                }
                let weight = power(pdf, 1.0 / falloff);
                let target = self.light_targets[k];
                out[target.layer] +=
                    surface::brdf(material, li, lo) * li.z * (weight / pdf) * target.factor;
            }
        }
        self.sample_environment(&s, material, lo, lift, &mut rng, out, counts);
        material_bit(s.material)
    }

    /// The environment's share: map and BRDF samples with MIS (the spmm mode's
    /// estimator); pre-convolved, the same on a filtered level of the map.
    #[allow(clippy::too_many_arguments)]
    fn sample_environment(
        &self,
        s: &Surface,
        material: &Material,
        lo: DVec3,
        lift: DVec3,
        rng: &mut SampleStream,
        out: &mut [DVec3],
        counts: &mut RayCounts,
    ) {
        let (u_map, u_material) = (rng.next_2d(), rng.next_2d());
        let (Some(env), Some(sampler)) = (&self.scene.environment, &self.env_sampler) else {
            return;
        };
        // Pre-convolved: the level of the filtered map that the lobe's highest rate for
        // this view needs, with that level's own sampler (section 2.5).
        let (map, sampler) = match &self.prefiltered {
            None => (&*env.map, sampler),
            Some(pre) => {
                let rate = self.materials[s.material]
                    .as_ref()
                    .map_or(0.0, |b| b.peak(lo));
                match pre.map(pre.level_for(rate)) {
                    (map, Some(sampler)) => (map, sampler),
                    (_, None) => return,
                }
            }
        };
        let radiance_of = |wi: DVec3| {
            let d = rotate_y(wi, -env.rotate_y_deg);
            let (x, y) = meso_render::environment::pixel_of(map.width(), map.height(), d);
            let p = map.get(x, y);
            DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
        };
        let e = sampler.sample(map, u_map);
        let wi = rotate_y(e.dir, env.rotate_y_deg);
        if wi.dot(s.n) > 0.0 {
            counts.environment += 1;
            if !self.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
                let li = s.to_local(wi);
                let weight = if env.mis {
                    power(e.pdf, surface::pdf(material, lo, li))
                } else {
                    1.0
                };
                out[ENVIRONMENT] +=
                    surface::brdf(material, li, lo) * li.z.max(0.0) * e.radiance * (weight / e.pdf);
            }
        }
        if !env.mis {
            return;
        }
        let Some((li, pdf)) = surface::sample(material, lo, u_material) else {
            return;
        };
        let wi = s.to_world(li);
        if wi.dot(s.n) <= 0.0 {
            return;
        }
        counts.environment += 1;
        if self.bvh.occluded(lift, wi, 0.0, f64::INFINITY) {
            return;
        }
        let map_pdf = sampler.pdf(rotate_y(wi, -env.rotate_y_deg));
        let weight = power(pdf, map_pdf);
        out[ENVIRONMENT] +=
            surface::brdf(material, li, lo) * li.z.max(0.0) * radiance_of(wi) * (weight / pdf);
    }

    /// A frame, in steps of rows when `stop` is given: the rest of the bandwidth pass
    /// if there is no buffer yet, then the shading by the frame's plan; `stop` is asked
    /// between steps and a yes leaves the rest in `unfinished` for the next call.
    fn render_tiles(&mut self, mut stop: Option<&mut dyn FnMut() -> bool>) -> FrameStats {
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
                (self.plan_frame(b, self.frames), 0)
            }
        };
        let layers = self.film.layers();
        let active = self.layers.active(&self.scene);
        let weights = self.layers.weights(&self.scene);
        let dropped_before = self.film.dropped();
        let mut totals = Counters::default();
        while y < height {
            if stopped(stepped) {
                break;
            }
            stepped = true;
            let rows = y..(y + tile_rows).min(height);
            y = rows.end;
            let own = std::mem::take(&mut self.own);
            let mut film = std::mem::replace(&mut self.film, Film::new(0, 0, 0));
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
            self.film = film;
            self.own = own;
            let pixels = (rows.start * width) as usize..(rows.end * width) as usize;
            for ((o, a), n) in self.own[pixels.clone()]
                .iter_mut()
                .zip(&mut self.added[pixels.clone()])
                .zip(&plan.samples[pixels])
            {
                *a |= *o == 0 && *n > 0 && self.frames > 0;
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
            self.frames += 1;
            // The image is the film's from now on.
            self.preview = None;
        }
        FrameStats {
            counters: totals,
            seconds: start.elapsed().as_secs_f64(),
            dropped: self.film.dropped() - dropped_before,
        }
    }

    /// Forgets every sample and the bandwidth buffer.
    fn restart_all(&mut self) -> Invalidation {
        self.film.reset();
        self.own.iter_mut().for_each(|c| *c = 0);
        self.added.iter_mut().for_each(|a| *a = false);
        self.moments
            .iter_mut()
            .for_each(|m| *m = Moments::default());
        self.frames = 0;
        self.buffers = None;
        self.plan = None;
        self.unfinished = None;
        self.preview = None;
        Invalidation::All
    }

    /// The pixels' own means, before up-sampling.
    fn own_means(&self) -> Vec<DVec3> {
        let img = self.film.resolve(&self.layers.weights(&self.scene));
        img.pixels()
            .iter()
            .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect()
    }

    /// Refuses an edit that brings what the mode cannot render.
    fn check_edit(&self, edit: &SceneEdit) -> Result<(), Unsupported> {
        let part = match edit {
            SceneEdit::Material { index, material } => {
                Self::unrenderable_material(&self.scene, *index, material)
            }
            SceneEdit::Light { index, light } => Self::unrenderable_light(*index, light),
            SceneEdit::AddLight(light) => Self::unrenderable_light(self.scene.lights.len(), light),
            SceneEdit::Ambient(Some(_)) => Some(Unrenderable::Ambient),
            _ => None,
        };
        Unsupported::check(ModeKind::Adaptive, Device::Cpu, part.into_iter().collect())
    }
}

impl AdaptiveMode {
    /// One sample at each previewed pixel (`preview::grid_pixels`) before the first
    /// frame after a restart, which waits for the bandwidth pass (1.6 s at 512 x 512
    /// on 2 cores). The samples stay out of the film (the frames' plan decides each
    /// pixel's samples), so the film is an uninterrupted render's; they cost about a
    /// 128 x 128 frame.
    fn render_preview_pass(&mut self, stride: u32) -> Option<FrameStats> {
        use meso_render::preview;
        use rayon::prelude::*;
        let untouched = self.frames == 0 && self.unfinished.is_none() && self.preview.is_none();
        if stride <= 1 || !untouched {
            return None;
        }
        let start = Instant::now();
        let (w, h) = (self.width(), self.height());
        let weights = self.layers.weights(&self.scene);
        let layers = self.film.layers();
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

impl RenderMode for AdaptiveMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Adaptive
    }

    fn device(&self) -> Device {
        Device::Cpu
    }

    fn scene(&self) -> &Scene {
        &self.scene
    }

    fn render(&mut self, pass: Pass, stop: Option<&mut dyn FnMut() -> bool>) -> Option<FrameStats> {
        match pass {
            Pass::Frame => Some(self.render_tiles(stop)),
            Pass::Preview { stride } => self.render_preview_pass(stride),
        }
    }

    fn image(&self) -> Image {
        if self.frames == 0
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
            frames: self.frames,
            min_samples: self.own.iter().copied().min().unwrap_or(0),
            dropped: self.film.dropped(),
            width: self.width(),
            height: self.height(),
            film_bytes: self.film.bytes(),
            // After a frame every pixel has its own samples or up-sampled ones.
            shows_every_pixel: self.frames > 0,
        }
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        self.check_edit(&edit)?;
        if let SceneEdit::Resize { width, height } = edit {
            Film::check(
                width,
                height,
                self.film.layers(),
                memory_limit_bytes() + self.film.bytes(),
            )?;
        }
        let before = Before::of(&self.scene, &edit);
        edit.apply_to(&mut self.scene)?;
        if let Some(invalidation) = self
            .layers
            .apply(&mut self.film, &before, &edit, &self.scene)
        {
            self.light_targets = self.layers.light_targets(&self.scene);
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
            return Ok(self.restart_all());
        }
        Ok(match edit {
            SceneEdit::Camera(camera) => {
                self.camera = PinholeCamera::new(&camera, self.width(), self.height());
                self.restart_all()
            }
            SceneEdit::Resize { width, height } => {
                self.camera = PinholeCamera::new(&self.scene.camera, width, height);
                self.film.resize(width, height);
                self.own = vec![0; (width * height) as usize];
                self.added = vec![false; (width * height) as usize];
                self.moments = vec![Moments::default(); (width * height) as usize];
                self.restart_all()
            }
            SceneEdit::Meshes(_) => {
                self.bvh.update(&self.scene.meshes);
                self.restart_all()
            }
            SceneEdit::Material { index, .. } => {
                self.materials[index] = material_bandwidth(&self.scene.materials[index]);
                self.restart_all()
            }
            // The mode picks its own light samples per pixel.
            SceneEdit::Moving(_) | SceneEdit::LightSamples(_) => Invalidation::Nothing,
            SceneEdit::Light { .. }
            | SceneEdit::AddLight(_)
            | SceneEdit::RemoveLight(_)
            | SceneEdit::Ambient(_)
            | SceneEdit::Environment(_)
            | SceneEdit::Background(_) => unreachable!("emitter edits are the layers' to handle"),
        })
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.samples_per_frame = samples.max(1);
    }

    fn diagnostics(&self) -> Diagnostics {
        let overlays = super::overlay::overlays(self)
            .into_iter()
            .map(|(name, image)| Diagnostic::Overlay { name, image });
        Diagnostics(
            std::iter::once(Diagnostic::Preparation(self.preparation.clone()))
                .chain(overlays)
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_render::RenderModeExt;

    #[test]
    fn a_visibility_step_between_neighbours_marks_both_sides_and_noise_below_it_does_not() {
        // A shadow edge between columns 1 and 2 of a 4 x 2 map; a 0.05 wobble elsewhere.
        let visible = [1.0, 0.95, 0.2, 0.25, 1.0, 0.95, 0.2, 0.25];
        let edge: Vec<bool> = (0..8)
            .map(|i| visibility_edge(&visible, 4, 2, i % 4, i / 4))
            .collect();
        assert_eq!(edge, [false, true, true, false, false, true, true, false]);
    }

    #[test]
    fn a_radiance_step_marks_both_sides_and_a_smooth_ramp_or_dark_noise_does_not() {
        // A highlight edge between columns 1 and 2 (1 -> 3); a 10% ramp elsewhere.
        let mean = [1.0, 1.1, 3.0, 3.3];
        let edge: Vec<bool> = (0..4)
            .map(|x| radiance_edge(&mean, 4, 1, x, 0, 0.0))
            .collect();
        assert_eq!(edge, [false, true, true, false]);
        // Steps of 1e-4 between near-black pixels stay below a floor of 1e-3.
        let dark = [0.0, 1e-4, 0.0];
        assert!((0..3).all(|x| !radiance_edge(&dark, 3, 1, x, 0, 1e-3)));
    }

    #[test]
    fn a_pixel_whose_samples_vary_more_than_predicted_takes_more_samples() {
        let scene = super::super::tests::merl_test_scene();
        let mut mode = AdaptiveMode::prepare(scene, 32, 32, Prepare::quietly()).expect("adaptive");
        // Past the last refinement every pixel is a site of level 0.
        for _ in 0..2 * (mode.top_level() + 1) {
            mode.render_frame();
        }
        assert!(mode.moments.iter().all(|m| m.count() > 0));
        let frames = mode.frames..mode.frames + 16;
        let taken = |mode: &AdaptiveMode, i: usize| -> u32 {
            let b = mode.buffers.as_ref().expect("pass done");
            frames
                .clone()
                .map(|f| mode.plan_frame(b, f).samples[i])
                .sum()
        };
        // The pixel predicted quietest among those the mode gives more than the floor.
        let b = mode.buffers.as_ref().expect("pass done");
        let i = (0..b.sigma.len())
            .filter(|&i| b.sigma[i] > 0.0)
            .min_by(|&a, &c| b.sigma[a].total_cmp(&b.sigma[c]))
            .expect("a lit pixel");
        let predicted = b.sigma[i];
        let before = taken(&mode, i);
        // Its samples turn out to vary with ten times the predicted deviation.
        let mut noisy = Moments::default();
        for k in 0..64 {
            noisy.add(if k % 2 == 0 { 0.0 } else { 20.0 * predicted });
        }
        mode.moments[i] = noisy;
        let after = taken(&mode, i);
        assert!(after > 3 * before.max(1), "{before} -> {after} samples");
        // A restart forgets what the samples measured, as it forgets the samples.
        let camera = mode.scene().camera;
        mode.apply(SceneEdit::Camera(camera)).expect("camera edit");
        assert!(mode.moments.iter().all(|m| m.count() == 0));
    }

    #[test]
    fn mip_reduces_blocks_of_odd_images_by_min_and_max() {
        let v = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0, 5.0];
        let min = mip(&v, 3, 3, 1, f64::min);
        assert_eq!(min[1], vec![1.0, 4.0, 2.0, 5.0]);
        let max = mip(&v, 3, 3, 1, f64::max);
        assert_eq!(max[1], vec![5.0, 9.0, 6.0, 5.0]);
    }
}
