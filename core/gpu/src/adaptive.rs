//! The adaptive mode's frames on the device (`shaders/adaptive.wgsl`,
//! `shaders/adaptive_render.wgsl`; the CPU's `meso_modes::adaptive` is the reference):
//! the bandwidth buffer's pyramids, each frame's plan (sites and sample counts), the
//! pixels' own counts and luminance moments, and the up-sampling of the resolved
//! image. What the bandwidth pass found per pixel comes in as `PassPixel`s; nothing
//! of a frame goes back to the host.

use bytemuck::{Pod, Zeroable};

use super::GpuContext;
use super::display::DeviceImage;
use super::kernel::{self, Kernel, Slot};
use super::shaders;

/// What the bandwidth pass found at one pixel, as the frames read it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassPixel {
    /// Eq. 11's level.
    pub level: u32,
    /// The predicted standard deviation of one sample (luminance).
    pub sigma: f32,
    /// Distance along the centre ray; infinite where it left the scene.
    pub depth: f32,
    /// Unit screen direction of the projected normal (zero off surfaces).
    pub normal_dir: [f32; 2],
    /// |cos| between the normal and the view direction.
    pub cos_x: f32,
    /// The pass's mean of the frames' estimator (luminance; `Buffers::mean`).
    pub mean: f32,
}

/// The adaptive mode's knobs the frames read (`AdaptiveOptions`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveKnobs {
    pub mean_samples: f64,
    pub max_samples: u32,
    pub min_share: f64,
    pub refine_frames: u32,
    /// Sample the environment map's peaks and its remainder each with its own tables
    /// (`AdaptiveOptions::split_environment`).
    pub split_environment: bool,
}

/// The uniform block of `shaders/adaptive.wgsl` (`AdaptiveParams`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct AdaptiveParams {
    width: u32,
    height: u32,
    top: u32,
    frame: u32,
    drop: u32,
    level: u32,
    aux_words: u32,
    pad0: u32,
    mean_samples: f32,
    max_samples: f32,
    floor_samples: f32,
    pad1: f32,
}

const INPUT_WORDS: u64 = 7;
const MIP_WORDS: u64 = 2;
const STATE_WORDS: u64 = 5;

const SLOTS: [Slot; 7] = [
    Slot::Uniform,
    Slot::Read,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::ReadWrite,
];

struct Kernels {
    mip_base: Kernel,
    mip_level: Kernel,
    plan: Kernel,
    reduce: Kernel,
    counts: Kernel,
    commit: Kernel,
    upsample: Kernel,
    forget_moments: Kernel,
}

/// The adaptive mode's device buffers and kernels at one image size.
pub(super) struct AdaptiveDevice {
    ctx: GpuContext,
    kernels: Kernels,
    /// The bandwidth pass's kernels, made with the first pass.
    pub(super) pass_kernels: Option<super::adaptive_pass::PassKernels>,
    /// A bandwidth pass under way on the device.
    pub(super) pass: Option<super::adaptive_pass::DevicePass>,
    knobs: AdaptiveKnobs,
    width: u32,
    height: u32,
    /// Per pixel what the pass found (`INPUT_WORDS`), as the frames read it.
    pub(super) inputs: wgpu::Buffer,
    mips: wgpu::Buffer,
    state: wgpu::Buffer,
    partials: wgpu::Buffer,
    /// The uniform block, rewritten before each dispatch's submission.
    uniform: wgpu::Buffer,
    /// Stands in for the image in the binds of the kernels that read none.
    no_image: wgpu::Buffer,
    /// Whether `inputs` holds a pass for the current view.
    pub(super) has_pass: bool,
    /// Samples dropped for a non-finite layer since the mode was made.
    pub(super) dropped: u64,
}

/// The coarsest pyramid level: min(floor(log2 W), floor(log2 H)).
pub(super) fn top_level(width: u32, height: u32) -> u32 {
    width.min(height).max(1).ilog2()
}

/// Blocks in all levels of a pyramid over `width` x `height`.
fn mip_blocks(width: u32, height: u32) -> u64 {
    (0..=top_level(width, height))
        .map(|k| u64::from(width.div_ceil(1 << k)) * u64::from(height.div_ceil(1 << k)))
        .sum()
}

impl AdaptiveDevice {
    pub fn new(ctx: &GpuContext, (width, height): (u32, u32), knobs: AdaptiveKnobs) -> Self {
        let source = shaders::module(&[shaders::ADAPTIVE]);
        let kernel = |entry| Kernel::new(ctx, &source, entry, &SLOTS);
        let kernels = Kernels {
            mip_base: kernel("mip_base"),
            mip_level: kernel("mip_level"),
            plan: kernel("plan"),
            reduce: kernel("reduce"),
            counts: kernel("counts"),
            commit: kernel("commit"),
            upsample: kernel("upsample"),
            forget_moments: kernel("forget_moments"),
        };
        let [inputs, mips, state, partials] = Self::buffers(ctx, width, height);
        Self {
            ctx: ctx.clone(),
            kernels,
            pass_kernels: None,
            pass: None,
            knobs,
            width,
            height,
            inputs,
            mips,
            state,
            partials,
            uniform: kernel::uniform(
                ctx,
                "adaptive params",
                bytemuck::bytes_of(&AdaptiveParams::default()),
            ),
            no_image: kernel::zeroed(ctx, "no image", 16),
            has_pass: false,
            dropped: 0,
        }
    }

    fn buffers(ctx: &GpuContext, width: u32, height: u32) -> [wgpu::Buffer; 4] {
        let pixels = u64::from(width) * u64::from(height);
        let (gx, gy) = kernel::groups(width * height);
        [
            kernel::zeroed(ctx, "adaptive inputs", pixels * INPUT_WORDS * 4),
            kernel::zeroed(
                ctx,
                "adaptive mips",
                mip_blocks(width, height) * MIP_WORDS * 4,
            ),
            kernel::zeroed(ctx, "adaptive state", pixels * STATE_WORDS * 4),
            kernel::zeroed(
                ctx,
                "adaptive partials",
                (2 + 2 * u64::from(gx) * u64::from(gy)) * 4,
            ),
        ]
    }

    /// Device bytes of the mode's own buffers.
    pub fn bytes(&self) -> u64 {
        self.inputs.size() + self.mips.size() + self.state.size() + self.partials.size()
    }

    /// A new image size: new buffers, no pass, no samples.
    pub fn resize(&mut self, width: u32, height: u32) {
        [self.inputs, self.mips, self.state, self.partials] =
            Self::buffers(&self.ctx, width, height);
        (self.width, self.height) = (width, height);
        self.has_pass = false;
        self.pass = None;
    }

    fn pixels(&self) -> u32 {
        self.width * self.height
    }

    fn params(&self, frame: u32, level: u32, samples_per_frame: u32) -> AdaptiveParams {
        let spf = f64::from(samples_per_frame.max(1));
        let mean = self.knobs.mean_samples * spf;
        AdaptiveParams {
            width: self.width,
            height: self.height,
            top: top_level(self.width, self.height),
            frame,
            drop: frame / self.knobs.refine_frames.max(1),
            level,
            aux_words: super::film::ADAPTIVE_AUX_WORDS as u32,
            mean_samples: mean as f32,
            max_samples: (f64::from(self.knobs.max_samples) * spf) as f32,
            floor_samples: (self.knobs.min_share * mean) as f32,
            ..AdaptiveParams::default()
        }
    }

    fn bind(
        &self,
        kernel: &Kernel,
        aux: &wgpu::Buffer,
        image: Option<&wgpu::Buffer>,
    ) -> wgpu::BindGroup {
        kernel.bind(
            &self.ctx,
            &[
                &self.uniform,
                &self.inputs,
                &self.mips,
                &self.state,
                aux,
                &self.partials,
                image.unwrap_or(&self.no_image),
            ],
        )
    }

    /// Submits one dispatch of `kernel` over `threads` invocations with `params`
    /// (a submission each: the uniform block is rewritten between them).
    fn run(
        &self,
        kernel: &Kernel,
        params: AdaptiveParams,
        aux: &wgpu::Buffer,
        image: Option<&wgpu::Buffer>,
        threads: u32,
    ) {
        // Written before the submission that reads it (the queue keeps order).
        self.ctx
            .queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&params));
        let bind = self.bind(kernel, aux, image);
        let mut enc = kernel::encoder(&self.ctx);
        kernel.record(&mut enc, &bind, threads);
        self.ctx.queue.submit([enc.finish()]);
    }

    /// Takes a new bandwidth pass (one `PassPixel` per pixel, row-major) and builds its
    /// pyramids; the samples are the caller's to restart.
    pub fn upload_pass(&mut self, pass: &[PassPixel], aux: &wgpu::Buffer) {
        debug_assert_eq!(pass.len(), self.pixels() as usize);
        let words: Vec<u32> = pass
            .iter()
            .flat_map(|p| {
                [
                    p.level,
                    p.sigma.to_bits(),
                    p.depth.to_bits(),
                    p.normal_dir[0].to_bits(),
                    p.normal_dir[1].to_bits(),
                    p.cos_x.to_bits(),
                    p.mean.to_bits(),
                ]
            })
            .collect();
        self.ctx
            .queue
            .write_buffer(&self.inputs, 0, bytemuck::cast_slice(&words));
        self.pass = None;
        self.take_inputs(aux);
    }

    /// Builds the pyramids of the pass now in `inputs`; the frames plan with it.
    pub fn take_inputs(&mut self, aux: &wgpu::Buffer) {
        self.run(
            &self.kernels.mip_base,
            self.params(0, 0, 1),
            aux,
            None,
            self.pixels(),
        );
        for k in 1..=top_level(self.width, self.height) {
            let blocks = self.width.div_ceil(1 << k) * self.height.div_ceil(1 << k);
            self.run(
                &self.kernels.mip_level,
                self.params(0, k, 1),
                aux,
                None,
                blocks,
            );
        }
        self.has_pass = true;
    }

    /// Forgets every pixel's own samples (counts, marks, moments).
    pub fn restart_samples(&self) {
        let mut enc = kernel::encoder(&self.ctx);
        enc.clear_buffer(&self.state, 0, None);
        self.ctx.queue.submit([enc.finish()]);
    }

    /// Forgets the moments only (an emission edit: they were of the old weights).
    pub fn forget_moments(&self, aux: &wgpu::Buffer) {
        self.run(
            &self.kernels.forget_moments,
            self.params(0, 0, 1),
            aux,
            None,
            self.pixels(),
        );
    }

    /// Plans frame `frame`: each site's samples and first sample index into `aux`
    /// (`AUX_PLANNED`, `AUX_FIRST`), zero samples elsewhere; returns the most samples
    /// a pixel takes (one word read back, so the frame dispatches no empty chunks).
    pub fn plan(
        &self,
        frame: u32,
        samples_per_frame: u32,
        aux: &wgpu::Buffer,
    ) -> Result<u32, super::GpuError> {
        let p = self.params(frame, 0, samples_per_frame);
        self.run(&self.kernels.plan, p, aux, None, self.pixels());
        let (gx, gy) = kernel::groups(self.pixels());
        let sums = AdaptiveParams {
            level: gx * gy,
            drop: 0,
            ..p
        };
        self.run(&self.kernels.reduce, sums, aux, None, 64);
        self.run(&self.kernels.counts, p, aux, None, self.pixels());
        let most = AdaptiveParams { drop: 1, ..sums };
        self.run(&self.kernels.reduce, most, aux, None, 64);
        let bytes = kernel::submit_and_read(
            &self.ctx,
            kernel::encoder(&self.ctx),
            &[(&self.partials, 4)],
        )?;
        let most: &[f32] = bytemuck::cast_slice(&bytes[0]);
        // A count is an integer below 2^24 as f32; a broken one is capped.
        Ok((most[0].max(0.0) as u32).min(self.most_samples(samples_per_frame) + 1))
    }

    /// The most samples a pixel can take in one frame (the plan's ceiling).
    fn most_samples(&self, samples_per_frame: u32) -> u32 {
        self.params(0, 0, samples_per_frame).max_samples.ceil() as u32
    }

    /// Readies the commits of frame `frame` (`record_commit`): its parameters.
    pub fn prepare_commit(&self, frame: u32) {
        let p = self.params(frame, 0, 1);
        self.ctx
            .queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&p));
    }

    /// Records, after a dispatch of the frame's samples, that the pixels' own counts
    /// and moments take them (parameters from `prepare_commit`).
    pub fn record_commit(&self, enc: &mut wgpu::CommandEncoder, aux: &wgpu::Buffer) {
        let bind = self.bind(&self.kernels.commit, aux, None);
        self.kernels.commit.record(enc, &bind, self.pixels());
    }

    /// Up-samples `image` (the film's own means) coarse to fine in place.
    pub fn upsample(&self, image: &DeviceImage, aux: &wgpu::Buffer) {
        for k in (0..top_level(self.width, self.height)).rev() {
            self.run(
                &self.kernels.upsample,
                self.params(0, k, 1),
                aux,
                Some(image.buffer()),
                self.pixels(),
            );
        }
    }

    /// What the pass found per pixel, as the frames read it (read back, for tests).
    pub fn pass_pixels(&self) -> Result<Vec<PassPixel>, super::GpuError> {
        let size = u64::from(self.pixels()) * INPUT_WORDS * 4;
        let bytes = kernel::submit_and_read(
            &self.ctx,
            kernel::encoder(&self.ctx),
            &[(&self.inputs, size)],
        )?;
        let words: &[u32] = bytemuck::cast_slice(&bytes[0]);
        Ok(words
            .chunks_exact(INPUT_WORDS as usize)
            .map(|w| PassPixel {
                level: w[0],
                sigma: f32::from_bits(w[1]),
                depth: f32::from_bits(w[2]),
                normal_dir: [f32::from_bits(w[3]), f32::from_bits(w[4])],
                cos_x: f32::from_bits(w[5]),
                mean: f32::from_bits(w[6]),
            })
            .collect())
    }

    /// Per pixel its own sample count (read back, for tests and reports).
    pub fn own_samples(&self) -> Result<Vec<u32>, super::GpuError> {
        let size = u64::from(self.pixels()) * STATE_WORDS * 4;
        let bytes = kernel::submit_and_read(
            &self.ctx,
            kernel::encoder(&self.ctx),
            &[(&self.state, size)],
        )?;
        let words: &[u32] = bytemuck::cast_slice(&bytes[0]);
        Ok(words
            .chunks_exact(STATE_WORDS as usize)
            .map(|s| s[0])
            .collect())
    }
}
