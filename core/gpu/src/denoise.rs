//! The viewport denoiser on the device (`shaders/denoise.wgsl`): the edge-avoiding
//! a-trous filter of `render::denoise` (its `apply_reference` is the definition this
//! is tested against), one dispatch per pass, then the studio's blend with the
//! estimate, all in one submission, so a GPU mode's early frames reach the window
//! filtered without a round trip through the host. The guides come from the GPU
//! mode's own pass (`shaders/guides.wgsl`, `GUIDE_FLOATS` per pixel).

use bytemuck::{Pod, Zeroable};

use super::display::DeviceImage;
use super::kernel::{self, Kernel, Slot};
use super::{GpuContext, shaders};
use meso_render::Denoiser;

/// Floats per pixel of a guides buffer: (normal, distance), (albedo, 0).
pub(super) const GUIDE_FLOATS: u64 = 8;

/// The uniform block of `shaders/denoise.wgsl` (`DenoiseParams`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenoiseParams {
    width: u32,
    height: u32,
    step: u32,
    normal_power: u32,
    inv_color: f32,
    sigma_depth: f32,
    sigma_albedo: f32,
    strength: f32,
}

const SLOTS: [Slot; 5] = [
    Slot::Uniform,
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::Read,
];

/// The filter's kernels and the uniform blocks of its passes (one per pass and one
/// for the blend: every pass of a submission reads its own).
pub(super) struct DeviceDenoiser {
    ctx: GpuContext,
    atrous: Kernel,
    blend: Kernel,
    params: Vec<wgpu::Buffer>,
}

impl DeviceDenoiser {
    pub fn new(ctx: &GpuContext) -> Self {
        let source = shaders::module(&[shaders::DENOISE]);
        Self {
            ctx: ctx.clone(),
            atrous: Kernel::new(ctx, &source, "atrous", &SLOTS),
            blend: Kernel::new(ctx, &source, "blend", &SLOTS),
            params: Vec::new(),
        }
    }

    /// Whether the device filters with `denoiser` (a negative normal power is the
    /// host's alone).
    pub fn takes(denoiser: &Denoiser) -> bool {
        denoiser.normal_power >= 0 && denoiser.passes <= 16
    }

    /// `image` blended with its filtered version at `strength` (0: the image, 1: the
    /// filtered image), guided by `guides` (`GUIDE_FLOATS` per pixel of the image's
    /// size), into a buffer of its own. `None` when the device does not take
    /// `denoiser` (`takes`).
    pub fn apply(
        &mut self,
        image: &DeviceImage,
        guides: &wgpu::Buffer,
        denoiser: &Denoiser,
        strength: f32,
    ) -> Option<DeviceImage> {
        if !Self::takes(denoiser) {
            return None;
        }
        let (width, height) = (image.width(), image.height());
        let pixels = width * height;
        let bytes = u64::from(pixels) * 16;
        let passes = denoiser.passes as usize;
        while self.params.len() < passes + 1 {
            self.params.push(kernel::uniform(
                &self.ctx,
                "denoise params",
                bytemuck::bytes_of(&DenoiseParams::zeroed()),
            ));
        }
        let base = DenoiseParams {
            width,
            height,
            step: 1,
            normal_power: denoiser.normal_power.max(0) as u32,
            inv_color: 0.0,
            sigma_depth: denoiser.sigma_depth,
            sigma_albedo: denoiser.sigma_albedo,
            strength: strength.clamp(0.0, 1.0),
        };
        for (pass, params) in self.params.iter().take(passes).enumerate() {
            let sigma_c = denoiser.sigma_color / (1u32 << pass) as f32;
            let p = DenoiseParams {
                step: 1 << pass,
                inv_color: 1.0 / (sigma_c * sigma_c),
                ..base
            };
            self.ctx
                .queue
                .write_buffer(params, 0, bytemuck::bytes_of(&p));
        }
        let blend_params = &self.params[passes];
        self.ctx
            .queue
            .write_buffer(blend_params, 0, bytemuck::bytes_of(&base));
        // Ping-pong between two scratch images; the blend writes the result's own.
        let scratch = [
            kernel::zeroed(&self.ctx, "denoise ping", bytes),
            kernel::zeroed(&self.ctx, "denoise pong", bytes),
        ];
        let out = kernel::zeroed(&self.ctx, "denoised image", bytes);
        let mut enc = kernel::encoder(&self.ctx);
        let mut filtered = image.buffer();
        for pass in 0..passes {
            let target = &scratch[pass % 2];
            let bind = self.atrous.bind(
                &self.ctx,
                &[&self.params[pass], guides, filtered, target, image.buffer()],
            );
            self.atrous.record(&mut enc, &bind, pixels);
            filtered = target;
        }
        let bind = self.blend.bind(
            &self.ctx,
            &[blend_params, guides, filtered, &out, image.buffer()],
        );
        self.blend.record(&mut enc, &bind, pixels);
        self.ctx.queue.submit([enc.finish()]);
        Some(DeviceImage::new(self.ctx.clone(), out, width, height))
    }
}
