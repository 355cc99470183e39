//! The adaptive mode's bandwidth pass on the device (`shaders/adaptive_pass.wgsl`; the
//! CPU's `meso_modes::adaptive` pass is the reference): the G-buffer, the per-pixel
//! analysis over n_b light directions per emitter, the guards, eq. 11's levels and
//! the predicted deviations, written where the frames read them. What the pass reads
//! besides the scene (the rules' constants, the strata and their orders, the
//! materials', the environment's and the lights' rate tables) comes from the caller as
//! `PassTables`, since the bandwidth analysis of materials is the CPU mode's.

use super::GpuContext;
use super::kernel::{self, Kernel};
use super::shaders;

/// The constants of the pass's rules (the CPU mode's, passed in so that one
/// definition holds for both devices).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassRules {
    /// Guard rays per emitter and pixel.
    pub guard_rays: u32,
    /// The visible share's step between neighbours above which a pixel is shaded at
    /// level 0.
    pub visibility_step: f64,
    /// The mean radiance's relative step between neighbours, likewise.
    pub radiance_step: f64,
    /// The rate of mirrors and of the environment seen directly.
    pub full_rate: f64,
    /// The cosines below this are taken as this.
    pub min_cos: f64,
    /// The relative depth step that separates surfaces.
    pub depth_sigma: f64,
    /// The radiance guard's floor, as a share of the image's mean |radiance|.
    pub dark_share: f64,
    /// Fixed directions per side of a material's rate table (its size is grid^4).
    pub grid: u32,
    /// Samples per side of an area light's rate table.
    pub light_res: u32,
}

/// What the device's bandwidth pass reads besides the scene.
#[derive(Clone, Debug)]
pub struct PassTables<'a> {
    /// Light directions per emitter (1 to `MAX_N_B`).
    pub n_b: u32,
    /// The shift of the n_b strata of the unit square (the same for every pixel).
    pub strata_shift: [f64; 2],
    /// Horizontal and vertical field of view, radians.
    pub fov: [f64; 2],
    pub rules: PassRules,
    /// The order in which the environment map's strategy visits the strata.
    pub map_order: &'a [u32],
    /// The order in which a map sampled in two parts draws its second part (its
    /// remainder) over the strata.
    pub remainder_order: &'a [u32],
    /// Per scene light, the order in which its points visit the strata.
    pub light_orders: Vec<&'a [u32]>,
    /// Per scene material, its rate table (`grid`^4, row-major by fixed direction);
    /// `None`: a material the pass finds no frequency in (shaded at the coarsest level).
    pub material_rates: Vec<Option<&'a [f32]>>,
    /// The environment map's rates per map pixel (width, height, rates).
    pub environment_rates: Option<(u32, u32, &'a [f32])>,
    /// Per scene light, an area light's rate table (`light_res`^2); `None` for others.
    pub light_rates: Vec<Option<&'a [f32]>>,
}

/// Words of the tables' header (`H_*` in the shader).
const HEADER_WORDS: usize = 23;
/// The shader's `H_FIRST`: the first pixel of an analysis dispatch.
const H_FIRST: u64 = 5;
const NO_TABLE: u32 = u32::MAX;
/// Floats per pixel of the scratch buffer: the G-buffer and the analysis' results.
const SCRATCH_FLOATS: u64 = 8 + 4;

impl PassTables<'_> {
    /// The most light directions per emitter the shader holds (`MAX_N_B`).
    pub const MAX_N_B: u32 = 64;

    /// The tables as the shader reads them, for a scene of `materials` materials and
    /// `lights` lights; an error names what does not fit.
    pub(super) fn words(&self, materials: usize, lights: usize) -> Result<Vec<u32>, String> {
        let n_b = self.n_b;
        if !(1..=Self::MAX_N_B).contains(&n_b) {
            return Err(format!(
                "the bandwidth pass on the device takes 1 to {} directions per emitter, not {n_b}",
                Self::MAX_N_B
            ));
        }
        let r = self.rules;
        let order_ok = |o: &[u32]| o.len() == n_b as usize && o.iter().all(|&k| k < n_b);
        if !order_ok(self.map_order)
            || !order_ok(self.remainder_order)
            || self.light_orders.len() != lights
        {
            return Err("the pass's strata orders do not match its n_b and lights".into());
        }
        let table = |len: usize, want: u32| len == (want as usize).pow(2);
        let grid_len = (r.grid as usize).pow(4);
        if self.material_rates.len() != materials
            || self
                .material_rates
                .iter()
                .flatten()
                .any(|t| t.len() != grid_len)
            || self.light_rates.len() != lights
            || self
                .light_rates
                .iter()
                .flatten()
                .any(|t| !table(t.len(), r.light_res))
            || r.grid == 0
            || r.light_res == 0
        {
            return Err("the pass's rate tables do not match the scene".into());
        }
        let f = |x: f64| (x as f32).to_bits();
        let mut w = vec![0u32; HEADER_WORDS];
        w[..13].copy_from_slice(&[
            n_b,
            f(self.strata_shift[0]),
            f(self.strata_shift[1]),
            f(self.fov[0]),
            f(self.fov[1]),
            0,
            r.guard_rays,
            f(r.visibility_step),
            f(r.radiance_step),
            f(r.full_rate),
            f(r.min_cos),
            f(r.depth_sigma),
            f(r.dark_share),
        ]);
        w[20] = r.grid;
        w[21] = r.light_res;
        w[13] = w.len() as u32;
        w.extend_from_slice(self.map_order);
        w[22] = w.len() as u32;
        w.extend_from_slice(self.remainder_order);
        w[14] = w.len() as u32;
        for order in &self.light_orders {
            if !order_ok(order) {
                return Err("the pass's strata orders do not match its n_b and lights".into());
            }
            w.extend_from_slice(order);
        }
        // Per material and per light an offset, then the tables they point to.
        let offsets = |w: &mut Vec<u32>, tables: &[Option<&[f32]>]| {
            let at = w.len();
            w.resize(at + tables.len(), NO_TABLE);
            for (i, t) in tables.iter().enumerate() {
                if let Some(t) = t {
                    w[at + i] = w.len() as u32;
                    w.extend(t.iter().map(|x| x.to_bits()));
                }
            }
            at as u32
        };
        w[15] = offsets(&mut w, &self.material_rates);
        w[19] = offsets(&mut w, &self.light_rates);
        w[16] = NO_TABLE;
        if let Some((width, height, rates)) = self.environment_rates {
            if rates.len() != width as usize * height as usize || rates.is_empty() {
                return Err("the environment's rate table does not match its size".into());
            }
            w[16] = w.len() as u32;
            w[17] = width;
            w[18] = height;
            w.extend(rates.iter().map(|x| x.to_bits()));
        }
        if w.len() >= NO_TABLE as usize {
            return Err("the pass's tables exceed 2^32 words".into());
        }
        Ok(w)
    }
}

/// The pass's kernels: the integrator's module with `adaptive_pass.wgsl`, bound as
/// the integrator's kernels are (`mode.rs` `SLOTS`), with `frame` bound to the pass's
/// own buffer and `aux` to the frames' inputs.
pub(super) struct PassKernels {
    gbuffer: Kernel,
    analyse: Kernel,
    partials: Kernel,
    total: Kernel,
    finish: Kernel,
}

impl PassKernels {
    pub fn new(ctx: &GpuContext) -> Self {
        let source = shaders::adaptive_pass();
        let kernel = |entry| Kernel::new(ctx, &source, entry, &super::mode::SLOTS);
        Self {
            gbuffer: kernel("pass_gbuffer"),
            analyse: kernel("pass_analyse"),
            partials: kernel("pass_partials"),
            total: kernel("pass_total"),
            finish: kernel("pass_finish"),
        }
    }
}

/// A bandwidth pass under way on the device: its buffer (scratch, then tables), bound
/// with the scene's buffers, and the first pixel not yet analysed.
pub(super) struct DevicePass {
    buffer: wgpu::Buffer,
    /// Byte offset of the tables' `H_FIRST` word in `buffer`.
    first_at: u64,
    bind: [wgpu::BindGroup; 5],
    pixels: u32,
    next: u32,
}

impl DevicePass {
    /// Where the tables start in the pass's buffer for `pixels` pixels, in words (the
    /// shader's `tables_at`: after the scratch, the partials and their total).
    pub fn tables_at(pixels: u32) -> u64 {
        u64::from(pixels) * SCRATCH_FLOATS + u64::from(pixels.div_ceil(kernel::WORKGROUP)) + 1
    }

    /// Uploads `words` (the tables, `PassTables::words`) and records the G-buffer;
    /// `scene` are the integrator's buffers but `frame` and `aux` (the pass's buffer
    /// and `inputs`, the frames'). The caller has checked the buffer's size.
    pub fn begin(
        ctx: &GpuContext,
        kernels: &PassKernels,
        words: &[u32],
        scene: [&wgpu::Buffer; 7],
        inputs: &wgpu::Buffer,
        pixels: u32,
    ) -> Self {
        let tables_at = Self::tables_at(pixels) * 4;
        let buffer = kernel::zeroed(ctx, "adaptive pass", tables_at + words.len() as u64 * 4);
        ctx.queue
            .write_buffer(&buffer, tables_at, bytemuck::cast_slice(words));
        let [params, nodes, tris, shade, data, counters, env] = scene;
        let buffers = [
            params, nodes, tris, shade, data, &buffer, inputs, counters, env,
        ];
        let bind = [
            &kernels.gbuffer,
            &kernels.analyse,
            &kernels.partials,
            &kernels.total,
            &kernels.finish,
        ]
        .map(|k| k.bind(ctx, &buffers));
        let mut enc = kernel::encoder(ctx);
        kernels.gbuffer.record(&mut enc, &bind[0], pixels);
        ctx.queue.submit([enc.finish()]);
        Self {
            buffer,
            first_at: tables_at + H_FIRST * 4,
            bind,
            pixels,
            next: 0,
        }
    }

    /// Analyses up to `count` more pixels; true once every pixel is analysed, the
    /// guards, levels, deviations and guides written to the frames' inputs.
    pub fn advance(&mut self, ctx: &GpuContext, kernels: &PassKernels, count: u32) -> bool {
        let n = count.max(1).min(self.pixels - self.next);
        if n > 0 {
            ctx.queue
                .write_buffer(&self.buffer, self.first_at, bytemuck::bytes_of(&self.next));
            let mut enc = kernel::encoder(ctx);
            kernels.analyse.record(&mut enc, &self.bind[1], n);
            ctx.queue.submit([enc.finish()]);
            self.next += n;
        }
        if self.next < self.pixels {
            return false;
        }
        let mut enc = kernel::encoder(ctx);
        kernels
            .partials
            .record(&mut enc, &self.bind[2], self.pixels);
        kernels
            .total
            .record(&mut enc, &self.bind[3], kernel::WORKGROUP);
        kernels.finish.record(&mut enc, &self.bind[4], self.pixels);
        ctx.queue.submit([enc.finish()]);
        true
    }
}
