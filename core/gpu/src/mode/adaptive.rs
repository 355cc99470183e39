//! The GPU mode's frames for the adaptive mode: the same skeleton, film, geometry,
//! materials and lights as the spmm mode, with each frame's samples where the plan
//! puts them (`crate::adaptive`, `shaders/adaptive.wgsl`) rather than one per pixel.
//! The bandwidth pass that the plan reads is the caller's (`adaptive_pass`).

use super::*;
use crate::adaptive::{AdaptiveKnobs, PassPixel};
use crate::adaptive_pass::{DevicePass, PassKernels, PassTables};

/// Samples of a pixel per dispatch (`ADAPTIVE_CHUNK` of `shaders/adaptive_render.wgsl`).
pub(crate) const ADAPTIVE_CHUNK: u32 = 8;

impl GpuSpmmMode {
    /// The device half of the adaptive mode: `scene` on `ctx`, its frames planned by
    /// `knobs`. It renders nothing until `adaptive_pass` gives it a bandwidth pass;
    /// `meso_modes`' `GpuAdaptiveMode` wraps it.
    pub fn prepare_adaptive(
        ctx: GpuContext,
        scene: Scene,
        (width, height): (u32, u32),
        prepare: Prepare,
        knobs: AdaptiveKnobs,
    ) -> Result<Self, ModeError> {
        Self::prepare_with(
            ctx,
            scene,
            (width, height),
            prepare,
            false,
            Frames::Adaptive(knobs),
        )
    }

    /// A bandwidth pass for the view as it is now (one `PassPixel` per pixel,
    /// row-major): its pyramids are built on the device and every sample restarts.
    pub fn adaptive_pass(&mut self, pass: &[PassPixel]) -> Result<(), EditError> {
        let (w, h) = (self.core.film.width(), self.core.film.height());
        let Some(a) = &mut self.adaptive else {
            return Err(EditError::Size(
                "this device mode renders spmm frames, not adaptive ones".into(),
            ));
        };
        if pass.len() != (w * h) as usize {
            return Err(EditError::Size(format!(
                "a bandwidth pass of {} pixels for a {w} x {h} image",
                pass.len()
            )));
        }
        a.upload_pass(pass, &self.core.film.aux);
        self.restart_all();
        Ok(())
    }

    /// Starts a bandwidth pass on the device for the view as it is now: `tables` go up
    /// and the G-buffer is traced; `continue_adaptive_pass` analyses the pixels. A
    /// pass under way is dropped.
    pub fn begin_adaptive_pass(&mut self, tables: &PassTables) -> Result<(), EditError> {
        let (w, h) = (self.core.film.width(), self.core.film.height());
        let scene = &self.core.scene;
        let words = tables
            .words(scene.materials.len(), scene.lights.len())
            .map_err(EditError::Size)?;
        // The pass's one buffer: its scratch (48 bytes a pixel), then the tables.
        let total = DevicePass::tables_at(w * h) as usize + words.len();
        if let Some(p) = words_size_problem(&self.ctx, "the adaptive bandwidth pass", total) {
            return Err(EditError::Size(p));
        }
        // The integrator's parameters of the view (the pass reads its camera,
        // lights, layers' weights).
        self.ctx.queue.write_buffer(
            &self.res.params,
            0,
            bytemuck::bytes_of(&self.params(self.core.next_sample)),
        );
        let Some(a) = &mut self.adaptive else {
            return Err(EditError::Size(
                "this device mode renders spmm frames, not adaptive ones".into(),
            ));
        };
        a.pass = None;
        let kernels = a
            .pass_kernels
            .get_or_insert_with(|| PassKernels::new(&self.ctx));
        let g = &self.res.geometry;
        let scene = [
            &self.res.params,
            &g.nodes,
            &g.tris,
            &g.shade,
            &self.res.data,
            &self.res.counters,
            &self.res.env,
        ];
        a.pass = Some(DevicePass::begin(
            &self.ctx,
            kernels,
            &words,
            scene,
            &a.inputs,
            w * h,
        ));
        Ok(())
    }

    /// Whether a bandwidth pass is under way on the device.
    pub fn adaptive_pass_pending(&self) -> bool {
        self.adaptive.as_ref().is_some_and(|a| a.pass.is_some())
    }

    /// Analyses up to `pixels` more pixels of the pass under way and waits for the
    /// device; once every pixel is done, the pass is the frames' (its pyramids built,
    /// every sample restarted) and this returns true. False with no pass under way. A
    /// device lost meanwhile is the mode's failure (`RenderMode::failure`).
    pub fn continue_adaptive_pass(&mut self, pixels: u32) -> Result<bool, GpuError> {
        let ctx = self.ctx.clone();
        let aux = &self.core.film.aux;
        let Some(a) = &mut self.adaptive else {
            return Ok(false);
        };
        let (Some(pass), Some(kernels)) = (&mut a.pass, &a.pass_kernels) else {
            return Ok(false);
        };
        let done = pass.advance(&ctx, kernels, pixels);
        if done {
            a.pass = None;
            a.take_inputs(aux);
            self.restart_all();
        }
        // A device lost during the pass is this mode's failure, as in a frame.
        if let Err(e) = kernel::wait(&ctx) {
            self.failure = Some(e.clone());
            return Err(e);
        }
        Ok(done)
    }

    /// What the current pass found per pixel (read back, for tests).
    pub fn adaptive_pass_pixels(&self) -> Result<Vec<PassPixel>, GpuError> {
        match &self.adaptive {
            Some(a) => a.pass_pixels(),
            None => Ok(Vec::new()),
        }
    }

    /// Whether the adaptive frames have a bandwidth pass for the current view (a
    /// camera, size or geometry change, or `adaptive_restart`, takes it away).
    pub fn has_adaptive_pass(&self) -> bool {
        self.adaptive.as_ref().is_some_and(|a| a.has_pass)
    }

    /// Forgets every sample; with `new_pass` the bandwidth pass too (the caller gives
    /// a new one before the next frame).
    pub fn adaptive_restart(&mut self, new_pass: bool) {
        if let Some(a) = &mut self.adaptive {
            a.has_pass &= !new_pass;
            // A pass under way is of the scene before the edit.
            a.pass = None;
        }
        self.restart_all();
    }

    /// An emission edit: the samples stand, the moments (of the old weights) go.
    pub fn adaptive_forget_moments(&self) {
        if let Some(a) = &self.adaptive {
            a.forget_moments(&self.core.film.aux);
        }
    }

    /// Per pixel, the samples it took itself since the last restart (read back).
    pub fn adaptive_own_samples(&self) -> Result<Vec<u32>, GpuError> {
        match &self.adaptive {
            Some(a) => a.own_samples(),
            None => Ok(Vec::new()),
        }
    }

    /// The last frame's plan, read back: per pixel whether it was a site and the
    /// samples it was given.
    pub fn adaptive_plan(&self) -> Result<Vec<(bool, u32)>, GpuError> {
        let words = crate::film::ADAPTIVE_AUX_WORDS;
        let size = u64::from(self.core.film.width() * self.core.film.height()) * words as u64 * 4;
        let bytes = kernel::submit_and_read(
            &self.ctx,
            kernel::encoder(&self.ctx),
            &[(&self.core.film.aux, size)],
        )?;
        let aux: &[u32] = bytemuck::cast_slice(&bytes[0]);
        Ok(aux
            .chunks_exact(words)
            .map(|a| {
                let sigma = f32::from_bits(a[crate::film::AUX_SIGMA]);
                (sigma >= 0.0, a[crate::film::AUX_PLANNED])
            })
            .collect())
    }

    /// Samples dropped for a non-finite layer by the adaptive frames.
    pub(super) fn adaptive_dropped(&self) -> u64 {
        self.adaptive.as_ref().map_or(0, |a| a.dropped)
    }

    /// A new image size for the adaptive buffers (no pass until the caller gives one).
    pub(super) fn resize_adaptive(&mut self) {
        let (w, h) = (self.core.film.width(), self.core.film.height());
        if let Some(a) = &mut self.adaptive {
            a.resize(w, h);
        }
    }

    /// One adaptive frame: the plan (sites and their samples, on the device), the
    /// samples in chunks of `CHUNK` per pixel, each followed by the film's
    /// accumulation and the pixels' own counts and moments; one read-back of the
    /// frame's counters.
    pub(super) fn render_adaptive_frame(&mut self) -> Result<Counters, GpuError> {
        let Some(a) = &self.adaptive else {
            return Ok(Counters::default());
        };
        if !a.has_pass {
            return Ok(Counters::default());
        }
        let ctx = &self.ctx;
        let (w, h) = (self.core.film.width(), self.core.film.height());
        let frame = self.core.frames;
        let aux = &self.core.film.aux;
        let most = a.plan(frame, self.core.samples_per_frame, aux)?;
        let active = self.core.layers.active(&self.core.scene);
        self.core.film.set_params(&active, false, &[]);
        let mut enc = kernel::encoder(ctx);
        enc.clear_buffer(&self.res.counters, 0, None);
        ctx.queue.submit([enc.finish()]);
        // Up to the most samples the plan gives a pixel, in chunks; a pixel whose
        // samples are done leaves at once.
        a.prepare_commit(frame);
        for first in (0..most).step_by(ADAPTIVE_CHUNK as usize) {
            ctx.queue.write_buffer(
                &self.res.params,
                0,
                bytemuck::bytes_of(&self.params(u64::from(first))),
            );
            let mut enc = kernel::encoder(ctx);
            self.kernel.record(&mut enc, &self.res.bind, w * h);
            self.core.film.record_accumulate(&mut enc);
            a.record_commit(&mut enc, aux);
            ctx.queue.submit([enc.finish()]);
        }
        let mut enc = kernel::encoder(ctx);
        self.core.film.record_min_samples(&mut enc);
        ctx.queue.submit([enc.finish()]);
        let counters = self.read_counters()?;
        // A sample is a primary ray here: the counts are the plan's.
        Ok(Counters {
            samples: counters.rays.primary,
            ..counters
        })
    }
}
