//! The viewport denoiser in the GPU mode: its guides traced on the device
//! (`shaders/guides.wgsl`, the integrator's module and bindings with a buffer of its
//! own in `frame`'s place), kept until an edit or a resize, and the filter
//! (`denoise.rs`) run on the frame's resolved image.

use std::sync::{Arc, Mutex};

use super::*;
use crate::denoise::{DeviceDenoiser, GUIDE_FLOATS};
use meso_render::{Denoiser, Guides};

/// What the GPU mode keeps for the denoiser, made on first use.
#[derive(Default)]
pub(super) struct Denoising {
    guides_kernel: Option<Kernel>,
    /// The guides of the current view and scene (`None`: trace them again).
    guides: Option<wgpu::Buffer>,
    filter: Option<DeviceDenoiser>,
}

impl Denoising {
    /// Forgets the guides (an edit or a resize).
    pub(super) fn forget_guides(&mut self) {
        self.guides = None;
    }
}

/// The mode's denoiser state behind a lock: `RenderMode`'s filtering takes `&self`.
pub(super) type SharedDenoising = Mutex<Denoising>;

impl GpuSpmmMode {
    /// Makes the guides' and the filter's kernels now (`RenderMode::prepare_denoiser`).
    pub(super) fn make_denoiser_kernels(&self) {
        let Ok(mut state) = self.denoising.lock() else {
            return;
        };
        let ctx = &self.ctx;
        state
            .guides_kernel
            .get_or_insert_with(|| Kernel::new(ctx, &shaders::integrator(), "guides", &SLOTS));
        state.filter.get_or_insert_with(|| DeviceDenoiser::new(ctx));
    }

    /// Whether the denoiser's kernels are made (tests).
    #[cfg(test)]
    pub(crate) fn denoiser_kernels_made(&self) -> bool {
        self.denoising
            .lock()
            .is_ok_and(|s| s.guides_kernel.is_some() && s.filter.is_some())
    }

    /// The guides of the current view, traced on the device the first time they are
    /// asked for since the last edit.
    fn device_guides(&self, state: &mut Denoising) -> Result<wgpu::Buffer, GpuError> {
        if let Some(g) = &state.guides {
            return Ok(g.clone());
        }
        let ctx = &self.ctx;
        let kernel = state
            .guides_kernel
            .get_or_insert_with(|| Kernel::new(ctx, &shaders::integrator(), "guides", &SLOTS));
        let (w, h) = (self.core.film.width(), self.core.film.height());
        let bytes = u64::from(w) * u64::from(h) * GUIDE_FLOATS * 4;
        let guides = kernel::zeroed(ctx, "guides", bytes);
        let g = &self.res.geometry;
        let bind = kernel.bind(
            ctx,
            &[
                &self.res.params,
                &g.nodes,
                &g.tris,
                &g.shade,
                &self.res.data,
                &guides,
                &self.core.film.aux,
                &self.res.counters,
                &self.res.env,
            ],
        );
        ctx.queue.write_buffer(
            &self.res.params,
            0,
            bytemuck::bytes_of(&self.params(self.core.next_sample)),
        );
        let mut enc = kernel::encoder(ctx);
        kernel.record(&mut enc, &bind, w * h);
        ctx.queue.submit([enc.finish()]);
        if let Some(e) = ctx.failure() {
            return Err(e);
        }
        state.guides = Some(guides.clone());
        Ok(guides)
    }

    /// The guides of every pixel, read back (`RenderMode::guides`: the host's filter,
    /// `meso render --denoise`).
    pub(super) fn host_guides(&self) -> Option<Guides> {
        if self.failure.is_some() {
            return None;
        }
        let mut state = self.denoising.lock().ok()?;
        let buffer = self.device_guides(&mut state).ok()?;
        let (w, h) = (self.core.film.width(), self.core.film.height());
        let pixels = u64::from(w) * u64::from(h);
        let bytes = kernel::submit_and_read(
            &self.ctx,
            kernel::encoder(&self.ctx),
            &[(&buffer, pixels * GUIDE_FLOATS * 4)],
        )
        .ok()?;
        let floats: &[f32] = bytemuck::cast_slice(&bytes[0]);
        let texels = floats.chunks_exact(GUIDE_FLOATS as usize);
        Some(Guides {
            width: w,
            height: h,
            normal: texels.clone().map(|t| [t[0], t[1], t[2]]).collect(),
            depth: texels.clone().map(|t| t[3]).collect(),
            albedo: texels.map(|t| [t[4], t[5], t[6]]).collect(),
        })
    }

    /// `RenderMode::denoised_on_device` for an image of this mode's device.
    pub(super) fn denoise_on_device(
        &self,
        image: &dyn ImageOnDevice,
        denoiser: &Denoiser,
        strength: f32,
    ) -> Option<Arc<dyn ImageOnDevice>> {
        let image = image.as_any().downcast_ref::<DeviceImage>()?;
        let (w, h) = (self.core.film.width(), self.core.film.height());
        if self.failure.is_some()
            || !image.context().same_device(&self.ctx)
            || (image.width(), image.height()) != (w, h)
            || !DeviceDenoiser::takes(denoiser)
        {
            return None;
        }
        let mut state = self.denoising.lock().ok()?;
        let guides = self.device_guides(&mut state).ok()?;
        let filter = state
            .filter
            .get_or_insert_with(|| DeviceDenoiser::new(&self.ctx));
        let out = filter.apply(image, &guides, denoiser, strength)?;
        Some(Arc::new(out))
    }
}
