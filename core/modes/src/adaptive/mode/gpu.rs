//! `GpuAdaptiveMode`: the adaptive mode on a wgpu device. After each restart that
//! needs one, the bandwidth pass runs on the device (`meso_gpu::GpuSpmmMode`'s
//! `begin_adaptive_pass`, `shaders/adaptive_pass.wgsl`: G-buffer, per-pixel analysis,
//! guards, levels, predicted deviations and guides), reading the rate tables that
//! the CPU mode's material, environment and light analyses made (`pass_tables`); then
//! every frame stays on the device too (`shaders/adaptive.wgsl`): the pyramids, the
//! plan (sites, the mean of their corrected deviations, dithered sample counts), the
//! samples, the pixels' own counts and moments, and the up-sampling of the image.
//! This lives here rather than in `meso-gpu` because the pass's rules and the
//! materials' bandwidths are this crate's.
//!
//! Differences from the CPU mode, by design: a sample is the GPU spmm mode's estimator
//! (`spmm_sample`, every light taken once as here, `light_samples` points per area
//! light), with the CPU adaptive mode's expectation; the pass's and the plan's
//! arithmetic is f32 (a level or a dithered count can differ where a value sits on an
//! edge); eq. 9's sum, which only the CPU mode's overlays show, is not computed.

use std::time::Instant;

#[cfg(test)]
use meso_gpu::PassPixel;
use meso_gpu::{AdaptiveKnobs, GpuContext, GpuSpmmMode, PassTables};
use meso_render::scene::Scene;
use meso_render::{
    Diagnostic, Diagnostics, EditError, FrameStats, Invalidation, ModeError, ModeKind, Pass,
    Prepare, Progress, RenderMode, SceneEdit, Unsupported,
};

#[cfg(test)]
use super::Buffers;
use super::{AdaptiveMode, AdaptiveOptions, PASS_TILE_PIXELS};

pub struct GpuAdaptiveMode {
    /// The device half: skeleton, device film, geometry, lights, the frames.
    device: GpuSpmmMode,
    /// The CPU mode, for the materials', environment's and lights' bandwidths the
    /// pass reads, and for its preview (its own frames and pass never run).
    cpu: AdaptiveMode,
    /// Seconds the last bandwidth pass took on the device (its steps' wall time,
    /// waits for the device included).
    pass_seconds: f64,
}

/// What the frames read of a pass, per pixel.
#[cfg(test)]
fn pass_pixels(b: &Buffers) -> Vec<PassPixel> {
    let g = &b.guide;
    (0..b.level.len())
        .map(|i| PassPixel {
            level: b.level[i],
            sigma: b.sigma[i] as f32,
            depth: g.depth[i] as f32,
            normal_dir: [g.normal_dir[i].x as f32, g.normal_dir[i].y as f32],
            cos_x: g.cos_x[i] as f32,
            mean: b.mean[i] as f32,
        })
        .collect()
}

impl GpuAdaptiveMode {
    /// What the device cannot render: what its device half cannot shade (a `btf`
    /// table read from disk, which has no values in memory to upload), named for this
    /// mode.
    pub fn supports(scene: &Scene) -> Result<(), Unsupported> {
        GpuSpmmMode::supports(scene).map_err(|u| crate::refused_for(ModeKind::Adaptive, u))?;
        AdaptiveMode::supports(scene)
    }

    pub fn new(
        ctx: GpuContext,
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        Self::prepare(
            ctx,
            scene,
            (width, height),
            AdaptiveOptions::default(),
            prepare,
        )
    }

    pub fn prepare(
        ctx: GpuContext,
        scene: Scene,
        (width, height): (u32, u32),
        options: AdaptiveOptions,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        if options.preconvolved {
            return Err(ModeError::Size(
                "the pre-convolved variant of the adaptive mode runs on the CPU only".into(),
            ));
        }
        Self::supports(&scene)?;
        if options.n_b > PassTables::MAX_N_B {
            return Err(ModeError::Size(format!(
                "the adaptive mode's bandwidth pass on the GPU takes at most {} directions \
                 per emitter, not {}",
                PassTables::MAX_N_B,
                options.n_b
            )));
        }
        // The device half first: what does not fit on the device is refused before the
        // CPU analyses the materials.
        let knobs = AdaptiveKnobs {
            mean_samples: options.mean_samples,
            max_samples: options.max_samples.max(1),
            min_share: options.min_share,
            refine_frames: options.refine_frames.max(1),
            split_environment: options.split_environment,
        };
        let device =
            GpuSpmmMode::prepare_adaptive(ctx, scene.clone(), (width, height), prepare, knobs)?;
        let cpu = AdaptiveMode::prepare_with(scene, width, height, prepare, options)?;
        debug_assert_eq!(
            (cpu.options().max_samples, cpu.options().refine_frames),
            (knobs.max_samples, knobs.refine_frames),
            "the CPU mode's knobs, as the device plans with them"
        );
        Ok(Self {
            device,
            cpu,
            pass_seconds: 0.0,
        })
    }

    /// The device half (device bytes, traversal overflows, own samples).
    pub fn device_mode(&self) -> &GpuSpmmMode {
        &self.device
    }

    /// The CPU mode whose pass the frames read.
    pub fn cpu_mode(&self) -> &AdaptiveMode {
        &self.cpu
    }

    /// Runs the bandwidth pass on the device if the view has none (after a restart
    /// that needs one, or a material analysis that came back markedly sharper); true
    /// once the frames have one. Given `stop`, the pass goes in steps of rows, asked
    /// between them (the studio keeps responding on a slow device); a yes keeps the
    /// rest for the next call.
    fn ensure_pass(
        &mut self,
        mut stop: Option<&mut dyn FnMut() -> bool>,
    ) -> Result<bool, EditError> {
        if self.cpu.take_analyses() {
            self.device.adaptive_restart(true);
            self.cpu.preview = None;
        }
        if self.device.has_adaptive_pass() {
            return Ok(true);
        }
        let start = Instant::now();
        let (w, h) = (self.cpu.width(), self.cpu.height());
        let pixels = match stop {
            Some(_) => (PASS_TILE_PIXELS / w.max(1)).max(1) * w,
            None => w * h,
        };
        // Beginning (the tables and the G-buffer) is a step: every call moves the pass on.
        let mut stepped = false;
        if !self.device.adaptive_pass_pending() {
            let orders = self.cpu.strata_orders();
            let tables = self.cpu.pass_tables(&orders);
            self.device.begin_adaptive_pass(&tables)?;
            self.pass_seconds = 0.0;
            stepped = true;
        }
        let done = loop {
            if stepped && stop.as_mut().is_some_and(|s| s()) {
                break false;
            }
            match self.device.continue_adaptive_pass(pixels) {
                Ok(true) => break true,
                Ok(false) if self.device.adaptive_pass_pending() => stepped = true,
                // Never left by a step; refused rather than asked again for ever.
                Ok(false) => return Err(EditError::Size("no bandwidth pass under way".into())),
                // The device half records its failure (`RenderMode::failure`).
                Err(e) => return Err(EditError::Size(e.to_string())),
            }
        };
        self.pass_seconds += start.elapsed().as_secs_f64();
        Ok(done)
    }

    /// Gives the frames the CPU mode's bandwidth pass instead of the device's (tests
    /// that compare the frames' rules with the CPU's on one pass).
    #[cfg(test)]
    pub(crate) fn use_cpu_pass(&mut self) -> Buffers {
        let buffers = self.cpu.bandwidth_pass();
        self.device
            .adaptive_pass(&pass_pixels(&buffers))
            .expect("a pass of the image's size");
        buffers
    }

    /// The preview standing for the image (before the device's first frame).
    fn preview(&self) -> Option<&meso_materials::image::Image> {
        self.cpu
            .preview
            .as_ref()
            .filter(|_| self.device.progress().frames == 0)
    }

    fn summary(&self) -> String {
        let inner = self.device.diagnostics().summary().unwrap_or_default();
        format!(
            "{inner} · adaptive: bandwidth pass {:.0} ms on the device",
            self.pass_seconds * 1e3
        )
    }
}

impl RenderMode for GpuAdaptiveMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Adaptive
    }

    fn render(&mut self, pass: Pass, stop: Option<&mut dyn FnMut() -> bool>) -> Option<FrameStats> {
        if let Pass::Preview { stride } = pass {
            // Before the device's first frame after a restart, the CPU mode's preview
            // (one sample at each previewed pixel, kept apart from the film) stands for
            // the image while the pass runs in steps.
            return match self.device.progress().frames {
                0 => self.cpu.render_preview_pass(stride),
                _ => None,
            };
        }
        let start = Instant::now();
        match self.ensure_pass(stop) {
            Ok(true) => {}
            // Stopped within the pass: no samples yet, the rest at the next call.
            Ok(false) => {
                return Some(FrameStats {
                    seconds: start.elapsed().as_secs_f64(),
                    ..FrameStats::default()
                });
            }
            // Tables that do not fit the scene (never made here) or a lost device,
            // which the device half reports as its failure: nothing is rendered
            // rather than a wrong frame.
            Err(_) => return Some(FrameStats::default()),
        }
        // A frame is one plan and its samples' dispatches: it does not stop.
        let mut stats = self.device.render(pass, None)?;
        stats.seconds = start.elapsed().as_secs_f64();
        Some(stats)
    }

    // The device, the scene, the guides (what each pixel's centre ray first sees) and
    // the denoiser.
    crate::device_half_methods!();

    /// The CPU mode's preview until the device's first frame after a restart, then the
    /// device's image.
    fn image(&self) -> meso_materials::image::Image {
        match self.preview() {
            Some(p) => p.clone(),
            None => self.device.image(),
        }
    }

    fn image_on_device(&self) -> Option<std::sync::Arc<dyn meso_render::ImageOnDevice>> {
        match self.preview() {
            Some(_) => None,
            None => self.device.image_on_device(),
        }
    }

    fn progress(&self) -> Progress {
        let p = self.device.progress();
        Progress {
            // After a frame every pixel has its own samples or up-sampled ones.
            shows_every_pixel: p.frames > 0,
            ..p
        }
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.device.set_samples_per_frame(samples);
        self.cpu.set_samples_per_frame(samples);
    }

    fn diagnostics(&self) -> Diagnostics {
        let mut list = self.device.diagnostics().0;
        for d in &mut list {
            match d {
                Diagnostic::Preparation(p) => {
                    crate::merge_preparation(&self.cpu.core.preparation, p);
                }
                Diagnostic::Summary(s) => *s = self.summary(),
                _ => {}
            }
        }
        Diagnostics(list)
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        // The frames shade the same still or moving: the device half never moves.
        if let SceneEdit::Moving(_) = edit {
            return self.cpu.apply(edit);
        }
        let new_pass = !matches!(
            edit,
            SceneEdit::Material { .. } | SceneEdit::LightSamples(_)
        );
        let device = (self.device.apply(edit.clone()))
            .map_err(|e| crate::edit_refused_for(ModeKind::Adaptive, e))?;
        // The CPU mode keeps the scene, BVH, emitters' and materials' bandwidths the
        // pass reads; what it invalidates says what the frames restart.
        match self.cpu.apply(edit)? {
            Invalidation::Nothing if device == Invalidation::Nothing => {
                // An emission edit re-weights the layers; the moments, of the old
                // weights, start again.
                self.device.adaptive_forget_moments();
                Ok(Invalidation::Nothing)
            }
            // Light samples: the device half restarted its samples; the pass stands.
            Invalidation::Nothing => Ok(device),
            // Up-sampled pixels mix every layer and material: anything else restarts
            // all, with a new pass unless only a material changed.
            _ => {
                // A pass under way is of the scene before the edit: the device drops it.
                self.device.adaptive_restart(new_pass);
                Ok(Invalidation::All)
            }
        }
    }
}
