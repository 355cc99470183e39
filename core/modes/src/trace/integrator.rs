//! The `spmm` mode's integrator (Silva & Santos 2013, section 4): per pixel and frame
//! one jittered primary ray, then at the first non-mirror surface the lights
//! (`lights.rs`), ambient occlusion and the environment (`environment.rs`); perfect
//! mirror reflection up to the scene's depth. It owns its scene, BVH, prepared
//! materials and layered film, and restarts only what an edit invalidates.

use std::time::Instant;

use glam::DVec3;

use meso_materials::image::Image;
use meso_materials::rng::SampleStream;
use meso_render::environment::EnvironmentSampler;
use meso_render::film::{EMPTY_UV_BOX, UvBox, extend_uv_box, material_bit};
use meso_render::geometry::{PinholeCamera, SceneBvh};
use meso_render::layers::{self, Layers, LightTarget};
use meso_render::light_selection::{LightSampling, LightSelection};
use meso_render::progressive::{Edited, Progressive};
use meso_render::reach::EditedTexels;
use meso_render::scene::{Material, Scene};
use meso_render::shading::{PackSampling, ShadedMaterial, Shaders, Shading};
use meso_render::{
    Counters, Device, Diagnostic, Diagnostics, EditError, Film, FrameStats, Invalidation,
    MaterialBytes, ModeError, ModeKind, Pass, Prepare, Progress, RayCounts, RenderMode, SceneEdit,
    Unrenderable, Unsupported,
};

/// Offset of secondary ray origins along the normal, relative to the hit point's
/// magnitude: well above the f32 rounding of the BVH's triangles (6e-8 relative).
const EPSILON_REL: f64 = 1e-5;

/// The `spmm` mode on the CPU.
pub struct SpmmMode {
    /// Scene, BVH, camera, film and layers, counters, moving flag, preparation.
    pub(super) core: Progressive<Film>,
    /// The materials as shaded here, with how packs are sampled.
    shaders: Shaders,
    /// The environment map's importance sampler (`None`: no environment, or black).
    pub(super) env_sampler: Option<EnvironmentSampler>,
    /// Per light, the film layer its samples go to and their factor.
    pub(super) light_targets: Vec<LightTarget>,
    light_sampling: LightSampling,
    /// The light selection while lights are chosen stochastically
    /// (`light_selection.rs`); `None` on the exact per-light path.
    pub(super) light_selection: Option<LightSelection>,
    /// Pixels a material edit restarted, traced alone by the next `render_frame` so
    /// the edit shows after a few hundred samples rather than a whole frame (a brush
    /// stroke): the first part of the next frame, done early.
    catch_up: Vec<u32>,
    /// Per pixel, whether the next frame's samples were already taken early (empty:
    /// none); the frame that completes skips them, so every pixel gets exactly the
    /// samples a frame without the early part would give it.
    done_early: Vec<bool>,
    /// Whether edits queue `catch_up` (off: the next frame is a whole frame, as before).
    restarted_first: bool,
}

/// Pixels per tile of a frame that yields (`render_frame_yielding`): a few
/// milliseconds of work on two cores, the longest an edit waits for the frame in flight.
const TILE_PIXELS: u32 = 16_384;

/// The per-sample state threaded through a path.
pub(super) struct Path<'a> {
    pub out: &'a mut [DVec3],
    pub mask: &'a mut u64,
    /// The texture coordinates of the SPMM points shaded (finer edit invalidation).
    pub reached: &'a mut UvBox,
    pub counts: &'a mut RayCounts,
    pub shading_points: &'a mut u64,
    pub rng: &'a mut SampleStream,
}

/// The selection table when `sampling` chooses lights stochastically for `lights`.
fn selection(
    sampling: LightSampling,
    lights: &[meso_render::scene::Light],
) -> Option<LightSelection> {
    if sampling.stochastic(lights.len()) {
        LightSelection::new(lights)
    } else {
        None
    }
}

impl SpmmMode {
    /// What this mode cannot render in `scene`: every material other than analytic
    /// BRDFs, MERL tables, SPMM packs and mirrors.
    pub fn supports(scene: &Scene) -> Result<(), Unsupported> {
        let parts = scene
            .materials
            .iter()
            .enumerate()
            .filter_map(|(index, m)| Self::unrenderable(scene, index, m))
            .collect();
        Unsupported::check(ModeKind::Spmm, Device::Cpu, parts)
    }

    /// `Some` if material `m`, in slot `index` of `scene`, cannot be shaded here.
    fn unrenderable(scene: &Scene, index: usize, m: &Material) -> Option<Unrenderable> {
        let shaded = matches!(
            m,
            Material::Brdf { .. }
                | Material::Merl { .. }
                | Material::Spmm { .. }
                | Material::Btf { .. }
                | Material::Mirror { .. }
        );
        (!shaded).then(|| Unrenderable::Material {
            index,
            name: scene
                .material_names
                .get(index)
                .cloned()
                .unwrap_or_else(|| format!("#{index}")),
            kind: m.kind_name(),
        })
    }

    /// Prepares `scene` at `width` x `height`: the BVH, the SPMM packs in use, the
    /// environment's sampler, each a reported stage that can be cancelled.
    pub fn prepare(
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        let mut core = Progressive::prepare(scene, width, height, &prepare, Self::supports)?;
        let start = Instant::now();
        let (scene, report) = (&core.scene, &mut core.preparation);
        let shaders = Shaders::new(&scene.materials);
        // What a pixel's centre ray sees is prepared now (packs, and the residual tables
        // of the clusters under those rays; MERL sampling tables), so the first frame
        // does not stall on it; anything else is prepared when a ray first reaches it (a
        // mirror's reflection, a jittered ray at a silhouette) and never if none does.
        let seen = surfaces_seen(&core.bvh, scene, &core.camera, (width, height));
        let total = seen.len().max(1) as f32;
        for (i, (material, uv)) in seen.iter().enumerate() {
            if i % 4096 == 0 {
                prepare.report("materials", i as f32 / total)?;
            }
            shaders.make_resident_at(&scene.materials, *material, *uv);
        }
        report.record_since("materials", start);
        prepare.report("environment", 0.0)?;
        let start = Instant::now();
        let env_sampler = scene
            .environment
            .as_ref()
            .and_then(|e| EnvironmentSampler::new(&e.map));
        report.record_since("environment", start);
        prepare.report("environment", 1.0)?;
        Ok(Self {
            shaders,
            env_sampler,
            light_targets: core.layers.light_targets(&core.scene),
            light_selection: selection(LightSampling::Auto, &core.scene.lights),
            light_sampling: LightSampling::Auto,
            catch_up: Vec::new(),
            done_early: Vec::new(),
            restarted_first: true,
            core,
        })
    }

    /// `prepare` without progress or cancel.
    pub fn new(scene: Scene, width: u32, height: u32) -> Result<Self, ModeError> {
        Self::prepare(scene, width, height, Prepare::quietly())
    }

    /// Prepares every material now, reached or not (what rendering held before
    /// preparation on demand; tests compare the two).
    pub fn prepare_every_material(&self) {
        self.shaders.make_all_resident(&self.core.scene.materials);
    }

    pub fn bvh(&self) -> &SceneBvh {
        &self.core.bvh
    }

    /// Whether the frame after a material edit traces only the pixels it restarted
    /// (on by default; off gives the previous behaviour, for comparisons).
    pub fn set_restarted_first(&mut self, on: bool) {
        self.restarted_first = on;
        if !on {
            self.drop_catch_up();
        }
    }

    /// Pixels queued for the next frame to trace alone.
    pub fn pending_restarted(&self) -> usize {
        self.catch_up.len()
    }

    /// Forgets the queued pixels: the next frame renders them with the others.
    fn drop_catch_up(&mut self) {
        for p in std::mem::take(&mut self.catch_up) {
            if let Some(d) = self.done_early.get_mut(p as usize) {
                *d = false;
            }
        }
    }

    /// The next frame's samples of `pixels` (row-major) only, the rest of the image
    /// untouched: the early part of the frame after a material edit. The frame count
    /// and the sample index move on when the frame completes.
    fn render_pixels(&mut self, pixels: &[u32]) -> FrameStats {
        use rayon::prelude::*;
        let start = Instant::now();
        let first = self.core.next_sample;
        let k = u64::from(self.core.samples_per_frame);
        let layers = self.core.film.layers();
        let active = self.core.layers.active(&self.core.scene);
        let width = self.core.film.width();
        let dropped_before = self.core.film.dropped();
        let mut totals = Counters::default();
        for index in first..first + k {
            let samples: Vec<(Vec<DVec3>, u64, UvBox, RayCounts, u64)> = pixels
                .par_iter()
                .map(|&p| {
                    let (x, y) = (p % width, p / width);
                    let mut out = vec![DVec3::ZERO; layers];
                    let (mut mask, mut reached) = (0, EMPTY_UV_BOX);
                    let (mut counts, mut shading_points) = (RayCounts::default(), 0);
                    self.sample_into(
                        (x, y, width),
                        index,
                        &mut out,
                        (&mut mask, &mut reached),
                        &mut counts,
                        &mut shading_points,
                    );
                    (out, mask, reached, counts, shading_points)
                })
                .collect();
            for (&p, (out, mask, reached, counts, shading_points)) in pixels.iter().zip(samples) {
                self.core
                    .film
                    .add_pixel_sample(p, &active, &out, mask, &reached);
                totals = totals
                    + Counters {
                        samples: 1,
                        shading_points,
                        rays: counts,
                    };
            }
        }
        let n = self.core.film.width() as usize * self.core.film.height() as usize;
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
    /// `stop` between them. A stopped frame marks its finished rows done early, so the
    /// call that completes it skips them and the samples are an uninterrupted frame's.
    fn render_tiles(&mut self, mut stop: Option<&mut dyn FnMut() -> bool>) -> FrameStats {
        // Half the image or more: the whole frame costs little more.
        if self.catch_up.len() * 2
            > self.core.film.width() as usize * self.core.film.height() as usize
        {
            self.drop_catch_up();
        }
        let pixels = std::mem::take(&mut self.catch_up);
        if !pixels.is_empty() {
            return self.render_pixels(&pixels);
        }
        let start = Instant::now();
        let first = self.core.next_sample;
        let k = u64::from(self.core.samples_per_frame);
        let layers = self.core.film.layers();
        let active = self.core.layers.active(&self.core.scene);
        let (width, height) = (self.core.film.width(), self.core.film.height());
        let tile_rows = match stop {
            Some(_) => (TILE_PIXELS / width.max(1)).max(1),
            None => height.max(1),
        };
        let dropped_before = self.core.film.dropped();
        // The film is moved out while rows borrow it mutably and `self` immutably.
        let mut film = std::mem::replace(&mut self.core.film, Film::new(0, 0, 0));
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
                let mut counts = RayCounts::default();
                let mut shading_points = 0;
                let mut out = vec![DVec3::ZERO; layers];
                let mut taken = 0;
                for x in 0..width {
                    let pixel = row.y as usize * width as usize + x as usize;
                    if self.done_early.get(pixel).copied().unwrap_or(false) {
                        continue;
                    }
                    taken += k;
                    for index in first..first + k {
                        out.iter_mut().for_each(|o| *o = DVec3::ZERO);
                        let mut mask = 0;
                        let mut reached = EMPTY_UV_BOX;
                        self.sample_into(
                            (x, row.y, width),
                            index,
                            &mut out,
                            (&mut mask, &mut reached),
                            &mut counts,
                            &mut shading_points,
                        );
                        for &l in &active {
                            row.add(x, l, out[l]);
                        }
                        row.touch(x, mask);
                        row.reach_box(x, &reached);
                    }
                }
                Counters {
                    samples: taken,
                    shading_points,
                    rays: counts,
                }
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
        }
        FrameStats {
            counters: totals,
            seconds: start.elapsed().as_secs_f64(),
            dropped: self.core.film.dropped() - dropped_before,
        }
    }

    /// The weight of each film layer: the current emissions.
    pub fn layer_weights(&self) -> Vec<DVec3> {
        self.core.layers.weights(&self.core.scene)
    }

    /// The film (its layers and bytes).
    pub fn film(&self) -> &Film {
        &self.core.film
    }

    /// Which layers lights own (`None`: one per light).
    pub fn light_layers(&self) -> &Layers {
        &self.core.layers
    }

    /// How lights are sampled; a change restarts every sample.
    pub fn set_light_sampling(&mut self, sampling: LightSampling) {
        self.light_sampling = sampling;
        self.refresh_lights();
        self.restart_all();
    }

    /// How directions are drawn at SPMM packs; a change restarts every sample.
    pub fn set_pack_sampling(&mut self, sampling: PackSampling) {
        self.shaders.set_pack_sampling(sampling);
        self.restart_all();
    }

    /// The material at `s` as shaded now (the moving flag chooses a pack's settings).
    pub(super) fn shaded(&self, s: &Shading) -> ShadedMaterial<'_> {
        self.shaders
            .material(&self.core.scene, s.material, self.core.moving)
    }

    /// The per-light state read by a frame, after a light edit.
    fn refresh_lights(&mut self) {
        self.light_targets = self.core.layers.light_targets(&self.core.scene);
        self.light_selection = selection(self.light_sampling, &self.core.scene.lights);
    }

    /// One sample of pixel (x, y) with sample index `index`, per layer for unit
    /// emission, the materials it shaded and the rays it traced. Replayable: a bad
    /// pixel can be re-rendered alone.
    pub fn sample(&self, x: u32, y: u32, index: u64) -> (Vec<DVec3>, u64, RayCounts) {
        let mut out = vec![DVec3::ZERO; self.core.film.layers()];
        let mut mask = 0;
        let mut counts = RayCounts::default();
        let mut shading_points = 0;
        let mut reached = EMPTY_UV_BOX;
        self.sample_into(
            (x, y, self.core.film.width()),
            index,
            &mut out,
            (&mut mask, &mut reached),
            &mut counts,
            &mut shading_points,
        );
        (out, mask, counts)
    }

    /// `(x, y, width)`: the image's width (the film may be borrowed out while a frame
    /// renders).
    fn sample_into(
        &self,
        (x, y, width): (u32, u32, u32),
        index: u64,
        out: &mut [DVec3],
        (mask, reached): (&mut u64, &mut UvBox),
        counts: &mut RayCounts,
        shading_points: &mut u64,
    ) {
        let pixel = u64::from(y) * u64::from(width) + u64::from(x);
        let render = &self.core.scene.render;
        let mut rng = SampleStream::for_sample(render.sampler, render.seed, index, pixel);
        let ray = self.core.camera.ray(x, y, rng.next_2d());
        counts.primary += 1;
        let mut path = Path {
            out,
            mask,
            reached,
            counts,
            shading_points,
            rng: &mut rng,
        };
        self.trace(ray.origin, ray.dir, 0, DVec3::ONE, &mut path);
    }

    /// Follows the ray and adds `throughput` times what it finds to the layers.
    fn trace(&self, origin: DVec3, dir: DVec3, depth: u32, throughput: DVec3, path: &mut Path) {
        let Some(hit) = self.core.bvh.closest_hit(origin, dir, 0.0, f64::INFINITY) else {
            if let Some((layer, radiance)) = layers::escaped(&self.core.scene, dir) {
                path.out[layer] += throughput * radiance;
            }
            return;
        };
        let s = Shading::at(&self.core.scene, &hit, dir);
        *path.mask |= material_bit(s.material);
        if matches!(self.core.scene.materials[s.material], Material::Spmm { .. }) {
            extend_uv_box(path.reached, s.uv);
        }
        let wo = -dir;
        // Secondary rays start just off the surface; light geometry uses the true point.
        let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
        if let Some(reflectance) = self.shaded(&s).specular() {
            if depth >= self.core.scene.render.max_specular_depth {
                return;
            }
            path.counts.specular += 1;
            let r = dir - 2.0 * dir.dot(s.n) * s.n;
            self.trace(lift, r, depth + 1, throughput * reflectance, path);
            return;
        }
        *path.shading_points += 1;
        self.sample_lights(&s, wo, lift, throughput, path);
        self.sample_ambient(&s, wo, lift, throughput, path);
        self.sample_environment(&s, wo, lift, throughput, path);
    }

    /// The materials whose evaluation changes with the moving flag.
    fn moving_mask(&self) -> u64 {
        (0..self.core.scene.materials.len())
            .filter(|&i| self.shaders.changes_when_moving(i))
            .fold(0, |m, i| m | material_bit(i))
    }

    /// Forgets every sample and starts the sample indices again, so the image from
    /// here on equals a fresh render of the edited scene, bit for bit.
    fn restart_all(&mut self) -> Invalidation {
        self.catch_up.clear();
        self.done_early.clear();
        self.core.film.reset();
        self.core.restart_counters();
        Invalidation::All
    }
}

impl RenderMode for SpmmMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Spmm
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
                // No frame under way, and every pixel short of a sample in some layer:
                // a camera edit restarted everything, or a light moved (its layer).
                let untouched = self.catch_up.is_empty()
                    && !self.done_early.contains(&true)
                    && (self.core.next_sample == 0 || self.progress().min_samples == 0);
                if stride <= 1 || !untouched {
                    return None;
                }
                let (w, h) = (self.core.film.width(), self.core.film.height());
                Some(self.render_pixels(&meso_render::preview::grid_pixels(w, h, stride)))
            }
        }
    }

    fn image(&self) -> Image {
        self.core.film.resolve(&self.layer_weights())
    }

    fn progress(&self) -> Progress {
        self.core
            .film
            .progress(self.core.frames, &self.core.layers.active(&self.core.scene))
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.core.samples_per_frame = samples.max(1);
    }

    fn guides(&self, pass: Pass) -> Option<meso_render::Guides> {
        use meso_render::preview;
        Some(match pass {
            Pass::Frame => self.compute_guides(),
            Pass::Preview { stride } => {
                let (w, h) = (self.core.film.width(), self.core.film.height());
                let grid = preview::grid_pixels(w, h, stride);
                self.guides_of(&grid, preview::grid_size(w, h, stride))
            }
        })
    }

    fn diagnostics(&self) -> Diagnostics {
        let (resident, full) = self.shaders.bytes(&self.core.scene.materials);
        Diagnostics(vec![
            Diagnostic::Preparation(self.core.preparation.clone()),
            Diagnostic::MaterialBytes(MaterialBytes { resident, full }),
        ])
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        if let SceneEdit::Material { index, material } = &edit
            && let Some(part) = Self::unrenderable(&self.core.scene, *index, material)
        {
            return Err(Unsupported {
                mode: ModeKind::Spmm,
                device: Device::Cpu,
                parts: vec![part],
            }
            .into());
        }
        Ok(match self.core.apply(&edit)? {
            Edited::Emitters(invalidation) => {
                if invalidation != Invalidation::Nothing {
                    // A restarted layer must get this frame's samples everywhere (at
                    // worst a pixel done early takes its sample twice).
                    self.done_early.clear();
                }
                if let SceneEdit::Environment(Some(e)) = &edit
                    && invalidation != Invalidation::Nothing
                {
                    self.env_sampler = EnvironmentSampler::new(&e.map);
                }
                if matches!(
                    edit,
                    SceneEdit::Light { .. } | SceneEdit::AddLight(_) | SceneEdit::RemoveLight(_)
                ) {
                    self.refresh_lights();
                }
                invalidation
            }
            Edited::Camera | Edited::Resized => self.restart_all(),
            Edited::Meshes => {
                self.core.bvh.update(&self.core.scene.meshes);
                self.restart_all()
            }
            Edited::Material { index, before } => {
                let after = &self.core.scene.materials[index];
                self.shaders.edited(index, Some(&before), after);
                // Only pixels whose shading reached a changed texel restart; the next
                // frame traces them first.
                let bit = material_bit(index);
                let film = &mut self.core.film;
                let pixels = match EditedTexels::between(&before, after) {
                    Some(texels) => film.reset_reaching_pixels(bit, |b| texels.reaches(b)),
                    None => film.reset_reaching_pixels(bit, |_| true),
                };
                let n = pixels.len();
                if self.restarted_first {
                    self.catch_up.extend(pixels);
                    self.catch_up.sort_unstable();
                    self.catch_up.dedup();
                }
                Invalidation::Pixels(n)
            }
            Edited::Moving => match self.moving_mask() {
                // No material shades differently while moving: every sample stands.
                0 => Invalidation::Nothing,
                mask => {
                    self.done_early.clear();
                    // Samples with and without the later components must not mix.
                    Invalidation::Pixels(self.core.film.reset_touching(mask))
                }
            },
            Edited::Nothing => Invalidation::Nothing,
            // Another estimator of the light: its sequence starts again with it.
            Edited::LightSamples => self.restart_all(),
        })
    }
}

/// The material and texture position that each pixel's centre ray hits first (one
/// entry per pixel that hits something).
fn surfaces_seen(
    bvh: &SceneBvh,
    scene: &Scene,
    camera: &PinholeCamera,
    (w, h): (u32, u32),
) -> Vec<(usize, glam::DVec2)> {
    use rayon::prelude::*;
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).filter_map(move |x| {
                let ray = camera.ray(x, y, glam::DVec2::splat(0.5));
                bvh.closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY)
                    .map(|hit| {
                        let s = Shading::at(scene, &hit, ray.dir);
                        (s.material, s.uv)
                    })
            })
        })
        .filter(|(m, _)| *m < scene.materials.len())
        .collect()
}
