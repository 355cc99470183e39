//! `DeviceFilm`: the GPU mode's progressive film, kept on the device so a frame needs
//! no read-back (shaders/film.wgsl). The rules are the CPU film's
//! (`render::film::Film`, the reference): per layer and pixel a running sum and a
//! sample count, a non-finite sample dropped and counted, per pixel the materials and
//! the texture-coordinate box its samples shaded so an edit restarts only the pixels
//! it reaches. Sums are f32 (the CPU's are f64): docs/gpu.md states the error this
//! leaves after 10,000 samples, which `tests.rs` measures.
//!
//! Layers are laid out one after the other, so a layer is cleared or copied as one
//! range of the buffer. Between frames only an edit moves data to or from the host:
//! a texel edit reads the per-pixel boxes back to decide which pixels restart.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;

use super::display::DeviceImage;
use super::kernel::{self, Kernel, Slot};
use super::{GpuContext, GpuError, shaders};
use meso_render::film::{LayeredFilm, UvBox};

/// Words per pixel of the `aux` buffer of the spmm and biscale modes
/// (`shaders/integrator.wgsl`: the marks and the dispatch's sample count).
pub(super) const AUX_WORDS: usize = 7;
/// Words per pixel of the adaptive mode's `aux`: the plan's words after those
/// (`shaders/adaptive.wgsl`).
pub(super) const ADAPTIVE_AUX_WORDS: usize = 13;
/// The adaptive plan's words of a pixel the host reads back: the block deviation
/// (negative off sites) and the samples planned (`shaders/adaptive.wgsl`).
pub(super) const AUX_SIGMA: usize = 11;
pub(super) const AUX_PLANNED: usize = 12;
const _: () = assert!(AUX_SIGMA < ADAPTIVE_AUX_WORDS && AUX_PLANNED < ADAPTIVE_AUX_WORDS);
const MARK_WORDS: u64 = 6;
/// Bytes per layer and pixel of the sums (RGB and the count).
const SUM_BYTES: u64 = 16;
/// The most layers a film has (`render::layers`: three, then one per light up to
/// `MANY_LIGHTS`); `shaders/film.wgsl` bounds its loops by it.
pub(super) const MAX_LAYERS: usize = 19;

/// The uniform block of `shaders/film.wgsl` (`FilmParams`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct FilmParams {
    width: u32,
    height: u32,
    layers: u32,
    active: u32,
    all: u32,
    aux_words: u32,
    pad: [u32; 2],
    weights: [[f32; 4]; 32],
}

const SLOTS: [Slot; 8] = [
    Slot::Uniform,
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::Read,
    Slot::ReadWrite,
];

struct Kernels {
    accumulate: Kernel,
    restart: Kernel,
    min_samples: Kernel,
    resolve: Kernel,
}

struct Binds {
    accumulate: wgpu::BindGroup,
    restart: wgpu::BindGroup,
    min_samples: wgpu::BindGroup,
    resolve: wgpu::BindGroup,
}

/// The film on the device, with the one-sample buffers the integrator writes.
pub(super) struct DeviceFilm {
    ctx: GpuContext,
    width: u32,
    height: u32,
    layers: usize,
    /// Words per pixel of `aux` (`AUX_WORDS` or `ADAPTIVE_AUX_WORDS`).
    aux_words: usize,
    /// One sample's layers (pixel-major, RGB f32) and per-pixel marks: the
    /// integrator's output, the accumulation's input.
    pub frame: wgpu::Buffer,
    pub aux: wgpu::Buffer,
    sums: wgpu::Buffer,
    marks: wgpu::Buffer,
    stats: wgpu::Buffer,
    flags: wgpu::Buffer,
    image: wgpu::Buffer,
    params: wgpu::Buffer,
    kernels: Kernels,
    binds: Binds,
    /// The host's copies of the device's counts, as of the last `refresh`.
    dropped: u64,
    min_samples: u32,
}

/// Bytes a `width` x `height` film with `layers` layers holds on the device.
pub(super) fn bytes_for(width: u32, height: u32, layers: usize, aux_words: usize) -> u64 {
    let pixels = u64::from(width) * u64::from(height);
    // Sums; marks, flags and the resolved image; one sample's layers and aux.
    pixels * (layers as u64 * (SUM_BYTES + 12) + MARK_WORDS * 4 + 4 + 16 + aux_words as u64 * 4)
}

/// The largest single buffer of such a film (its sums, or the adaptive mode's `aux`
/// words), which the device's buffer limit must hold.
pub(super) fn largest_buffer(width: u32, height: u32, layers: usize, aux_words: usize) -> u64 {
    let pixels = u64::from(width) * u64::from(height);
    (pixels * layers as u64 * SUM_BYTES).max(pixels * aux_words as u64 * 4)
}

/// A film's per-pixel buffers at `width` x `height` with `layers` layers: one sample's
/// layers and aux words, the sums, the marks, the restart flags, the resolved image.
fn pixel_buffers(
    ctx: &GpuContext,
    (width, height): (u32, u32),
    layers: usize,
    aux_words: usize,
) -> [wgpu::Buffer; 6] {
    let pixels = u64::from(width) * u64::from(height);
    let layers = layers as u64;
    [
        kernel::zeroed(ctx, "frame", pixels * layers * 12),
        kernel::zeroed(ctx, "aux", pixels * aux_words as u64 * 4),
        kernel::zeroed(ctx, "film sums", pixels * layers * SUM_BYTES),
        kernel::zeroed(ctx, "film marks", pixels * MARK_WORDS * 4),
        kernel::zeroed(ctx, "film flags", pixels * 4),
        kernel::zeroed(ctx, "film image", pixels * 16),
    ]
}

impl DeviceFilm {
    #[cfg(test)]
    pub fn new(ctx: &GpuContext, width: u32, height: u32, layers: usize) -> Self {
        Self::with_aux(ctx, (width, height), layers, AUX_WORDS)
    }

    /// A film whose `aux` buffer has `aux_words` words per pixel.
    pub fn with_aux(
        ctx: &GpuContext,
        (width, height): (u32, u32),
        layers: usize,
        aux_words: usize,
    ) -> Self {
        let source = shaders::module(&[shaders::FILM]);
        let kernel = |entry| Kernel::new(ctx, &source, entry, &SLOTS);
        let kernels = Kernels {
            accumulate: kernel("accumulate"),
            restart: kernel("restart"),
            min_samples: kernel("min_samples"),
            resolve: kernel("resolve"),
        };
        let params = kernel::uniform(
            ctx,
            "film params",
            bytemuck::bytes_of(&FilmParams::zeroed()),
        );
        let stats = kernel::zeroed(ctx, "film stats", 8);
        let [frame, aux, sums, marks, flags, image] =
            pixel_buffers(ctx, (width, height), layers, aux_words);
        let binds = Self::bind(
            ctx,
            &kernels,
            [&params, &frame, &aux, &sums, &marks, &stats, &flags, &image],
        );
        let mut film = Self {
            ctx: ctx.clone(),
            width,
            height,
            layers,
            aux_words,
            frame,
            aux,
            sums,
            marks,
            stats,
            flags,
            image,
            params,
            kernels,
            binds,
            dropped: 0,
            min_samples: 0,
        };
        // Empty boxes are not zero bits: the restart pass writes them.
        film.reset();
        film
    }

    fn bind(ctx: &GpuContext, k: &Kernels, buffers: [&wgpu::Buffer; 8]) -> Binds {
        Binds {
            accumulate: k.accumulate.bind(ctx, &buffers),
            restart: k.restart.bind(ctx, &buffers),
            min_samples: k.min_samples.bind(ctx, &buffers),
            resolve: k.resolve.bind(ctx, &buffers),
        }
    }

    fn rebind(&mut self) {
        self.binds = Self::bind(
            &self.ctx,
            &self.kernels,
            [
                &self.params,
                &self.frame,
                &self.aux,
                &self.sums,
                &self.marks,
                &self.stats,
                &self.flags,
                &self.image,
            ],
        );
    }

    /// The device the film lives on.
    pub(super) fn context(&self) -> &GpuContext {
        &self.ctx
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    /// Words per pixel of `aux`.
    pub fn aux_words(&self) -> usize {
        self.aux_words
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    fn pixels(&self) -> u32 {
        self.width * self.height
    }

    /// Bytes the film's buffers hold on the device.
    pub fn bytes(&self) -> u64 {
        bytes_for(self.width, self.height, self.layers, self.aux_words)
    }

    /// Writes the parameters every film pass of the next submission reads: the
    /// active layers, whether `restart` takes every pixel, the layer weights.
    pub fn set_params(&self, active: &[usize], all: bool, weights: &[DVec3]) {
        let mut p = FilmParams {
            width: self.width,
            height: self.height,
            layers: self.layers as u32,
            active: active.iter().fold(0, |m, &l| m | (1u32 << l)),
            all: u32::from(all),
            aux_words: self.aux_words as u32,
            ..FilmParams::zeroed()
        };
        let max = f64::from(f32::MAX);
        for (w, out) in weights.iter().zip(&mut p.weights) {
            let w = w.clamp(DVec3::splat(-max), DVec3::splat(max));
            *out = [w.x as f32, w.y as f32, w.z as f32, 0.0];
        }
        self.ctx
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&p));
    }

    /// Records the accumulation of the sample in `frame` and `aux` (its active layers
    /// as the last `set_params` says).
    pub fn record_accumulate(&self, enc: &mut wgpu::CommandEncoder) {
        self.kernels
            .accumulate
            .record(enc, &self.binds.accumulate, self.pixels());
    }

    /// Records the pass that finds the fewest samples of the active layers; `refresh`
    /// reads it back.
    pub fn record_min_samples(&self, enc: &mut wgpu::CommandEncoder) {
        self.ctx
            .queue
            .write_buffer(&self.stats, 4, bytemuck::bytes_of(&u32::MAX));
        self.kernels
            .min_samples
            .record(enc, &self.binds.min_samples, self.pixels());
    }

    /// The buffer `refresh` reads (the dropped count and the fewest samples).
    pub fn stats(&self) -> &wgpu::Buffer {
        &self.stats
    }

    /// Takes the two words of `stats` read back after `record_min_samples`.
    pub fn refresh(&mut self, stats: &[u32]) {
        self.dropped = u64::from(stats[0]);
        self.min_samples = if self.pixels() == 0 { 0 } else { stats[1] };
    }

    /// Counts the fewest samples now (after an edit restarted pixels or layers).
    pub fn recount(&mut self, active: &[usize]) -> Result<(), GpuError> {
        self.set_params(active, false, &[]);
        let mut enc = kernel::encoder(&self.ctx);
        self.record_min_samples(&mut enc);
        let bytes = kernel::submit_and_read(&self.ctx, enc, &[(&self.stats, 8)])?;
        self.refresh(bytemuck::cast_slice(&bytes[0]));
        Ok(())
    }

    /// Samples dropped for being NaN or infinite, as of the last count.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The fewest samples any pixel has in the active layers, as of the last count.
    pub fn min_samples(&self) -> u32 {
        self.min_samples
    }

    /// Forgets every sample (a camera or geometry change); the dropped count stays.
    pub fn reset(&mut self) {
        self.restart(true);
    }

    /// Runs the restart pass over every pixel (`all`) or the flagged ones.
    fn restart(&mut self, all: bool) {
        self.set_params(&[], all, &[]);
        let mut enc = kernel::encoder(&self.ctx);
        self.kernels
            .restart
            .record(&mut enc, &self.binds.restart, self.pixels());
        self.ctx.queue.submit([enc.finish()]);
        self.min_samples = 0;
    }

    /// Per pixel, the materials its samples shaded and their texture-coordinate box
    /// (read back: an edit of a few texels decides here which pixels restart).
    pub fn marks(&self) -> Result<Vec<(u64, UvBox)>, GpuError> {
        let enc = kernel::encoder(&self.ctx);
        let size = u64::from(self.pixels()) * MARK_WORDS * 4;
        let bytes = kernel::submit_and_read(&self.ctx, enc, &[(&self.marks, size)])?;
        let words: &[u32] = bytemuck::cast_slice(&bytes[0]);
        Ok(words
            .chunks_exact(MARK_WORDS as usize)
            .take(self.pixels() as usize)
            .map(|m| {
                let mask = u64::from(m[0]) | (u64::from(m[1]) << 32);
                (mask, [m[2], m[3], m[4], m[5]].map(f32::from_bits))
            })
            .collect())
    }

    /// Forgets every sample of the pixels whose marks pass `restarts`; returns them
    /// (row-major, in order), as the CPU film's `reset_reaching_pixels`.
    pub fn reset_where(
        &mut self,
        restarts: impl Fn(u64, &UvBox) -> bool,
    ) -> Result<Vec<u32>, GpuError> {
        let marks = self.marks()?;
        let flags: Vec<u32> = marks
            .iter()
            .map(|(mask, b)| u32::from(restarts(*mask, b)))
            .collect();
        let pixels: Vec<u32> = (0..flags.len() as u32)
            .filter(|&p| flags[p as usize] != 0)
            .collect();
        if !pixels.is_empty() {
            self.ctx
                .queue
                .write_buffer(&self.flags, 0, bytemuck::cast_slice(&flags));
            self.restart(false);
        }
        Ok(pixels)
    }

    /// A new image size: every sample is forgotten, the dropped count kept.
    pub fn resize(&mut self, width: u32, height: u32) {
        // The kernels, the parameters and the counts stay; the per-pixel buffers go.
        [
            self.frame, self.aux, self.sums, self.marks, self.flags, self.image,
        ] = pixel_buffers(&self.ctx, (width, height), self.layers, self.aux_words);
        (self.width, self.height) = (width, height);
        self.rebind();
        self.reset();
    }

    /// The image of the film now, each layer weighted by `weights`, resolved on the
    /// device into a buffer of its own (the film goes on changing; the image not).
    pub fn resolve(&self, active: &[usize], weights: &[DVec3]) -> DeviceImage {
        self.set_params(active, false, weights);
        let mut enc = kernel::encoder(&self.ctx);
        self.kernels
            .resolve
            .record(&mut enc, &self.binds.resolve, self.pixels());
        let size = u64::from(self.pixels()) * 16;
        let own = kernel::zeroed(&self.ctx, "resolved image", size);
        enc.copy_buffer_to_buffer(&self.image, 0, &own, 0, size.max(16));
        self.ctx.queue.submit([enc.finish()]);
        DeviceImage::new(self.ctx.clone(), own, self.width, self.height)
    }

    /// Rebuilds the sums with `layers` layers, new layer `l` copied from old layer
    /// `from(l)` (empty where `None`), and the one-sample buffer to match.
    fn relayer(&mut self, layers: usize, from: impl Fn(usize) -> Option<usize>) {
        let layer_bytes = u64::from(self.pixels()) * SUM_BYTES;
        let sums = kernel::zeroed(&self.ctx, "film sums", layer_bytes * layers as u64);
        let mut enc = kernel::encoder(&self.ctx);
        for l in 0..layers {
            if let Some(old) = from(l)
                && layer_bytes > 0
            {
                enc.copy_buffer_to_buffer(
                    &self.sums,
                    old as u64 * layer_bytes,
                    &sums,
                    l as u64 * layer_bytes,
                    layer_bytes,
                );
            }
        }
        self.ctx.queue.submit([enc.finish()]);
        self.sums = sums;
        // The integrator's bindings hold the one-sample buffer: a new one only when
        // its size changes, which the mode sees in the layer count and rebinds.
        if layers != self.layers {
            self.frame = kernel::zeroed(
                &self.ctx,
                "frame",
                u64::from(self.pixels()) * layers as u64 * 12,
            );
        }
        self.layers = layers;
        self.rebind();
    }
}

impl LayeredFilm for DeviceFilm {
    fn layers(&self) -> usize {
        self.layers
    }

    fn reset_layer(&mut self, layer: usize) {
        let layer_bytes = u64::from(self.pixels()) * SUM_BYTES;
        if layer_bytes == 0 {
            return;
        }
        let mut enc = kernel::encoder(&self.ctx);
        enc.clear_buffer(&self.sums, layer as u64 * layer_bytes, Some(layer_bytes));
        self.ctx.queue.submit([enc.finish()]);
        self.min_samples = 0;
    }

    fn keep_layers(&mut self, layers: usize, keep: usize) {
        self.relayer(layers, |l| (l < keep).then_some(l));
    }

    fn push_layer(&mut self) {
        let old = self.layers;
        self.relayer(old + 1, |l| (l < old).then_some(l));
    }

    fn remove_layer(&mut self, layer: usize) {
        self.relayer(self.layers - 1, |l| Some(l + usize::from(l >= layer)));
    }
}
