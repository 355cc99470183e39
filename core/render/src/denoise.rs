//! The viewport denoiser: an edge-avoiding a-trous wavelet filter (Dammertz et al.
//! 2010) of the accumulated image, guided by what the first hit of each pixel's
//! centre ray sees (normal, depth, albedo), so it blurs noise within a surface and
//! stops at silhouettes, creases and texture edges. It is for looking at early frames
//! only: the studio fades it out as samples accumulate, `meso render` applies it only
//! with `--denoise`, and references, goldens and reports' progressive errors never
//! see it (the convergence report lists it as its own rows).

use rayon::prelude::*;

use meso_materials::image::Image;

/// What the first hit of each pixel's centre ray sees, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Guides {
    pub width: u32,
    pub height: u32,
    /// Shading normal (unit; zero where the ray leaves the scene).
    pub normal: Vec<[f32; 3]>,
    /// Distance along the ray (infinite where it leaves the scene).
    pub depth: Vec<f32>,
    /// A colour the surface reflects (the BRDF's albedo, a pack's texel response at
    /// normal incidence, a mirror's reflectance); the background's own colour.
    pub albedo: Vec<[f32; 3]>,
}

/// The filter's edge-stopping parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Denoiser {
    /// Passes with the 5x5 B3-spline kernel at steps 1, 2, 4, ...: a footprint of
    /// `4 * 2^passes + 1` pixels.
    pub passes: u32,
    /// Colour difference (of `c / (1 + c)`, so bright highlights do not dominate) at
    /// which a neighbour's weight falls to 1/e; halved at every pass.
    pub sigma_color: f32,
    /// Exponent of the normals' cosine.
    pub normal_power: i32,
    /// Relative depth difference at which the weight falls to 1/e.
    pub sigma_depth: f32,
    /// Albedo difference at which the weight falls to 1/e.
    pub sigma_albedo: f32,
}

impl Default for Denoiser {
    fn default() -> Self {
        Self {
            passes: 4,
            sigma_color: 0.6,
            normal_power: 64,
            sigma_depth: 0.03,
            sigma_albedo: 0.1,
        }
    }
}

impl Denoiser {
    /// The filter for an image of `samples` samples per pixel: the colour tolerance
    /// shrinks as the noise does (1 / sqrt(samples)), so later frames keep their
    /// detail.
    pub fn for_samples(samples: u32) -> Self {
        let d = Self::default();
        Self {
            sigma_color: d.sigma_color / (samples.max(1) as f32).sqrt(),
            ..d
        }
    }
}

/// Samples per pixel at which the studio's denoiser has faded out entirely.
pub const FADE_SAMPLES: u32 = 32;

/// The studio's blend of the denoised image after `samples` samples per pixel: 1 at
/// one sample, falling linearly to 0 at `FADE_SAMPLES`.
pub fn viewport_strength(samples: u32) -> f32 {
    if samples >= FADE_SAMPLES {
        0.0
    } else {
        1.0 - samples.saturating_sub(1) as f32 / (FADE_SAMPLES - 1) as f32
    }
}

const KERNEL: [f32; 5] = [1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0];

fn compress(c: [f32; 3]) -> [f32; 3] {
    c.map(compress_channel)
}

fn compress_channel(v: f32) -> f32 {
    v.max(0.0) / (1.0 + v.max(0.0))
}

fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

impl Denoiser {
    /// The filtered image. `None` when the guides do not match the image's size.
    /// Computes what `apply_reference` does a row at a time on planar copies of the
    /// image and guides, one kernel tap over the whole row per step, so the compiler
    /// vectorises it (8 pixels per instruction with AVX2, detected at run time); the
    /// divisions per neighbour are one per pixel and `exp` is a polynomial
    /// (`exp_neg`). The two agree within 1e-4 relative (tested).
    pub fn apply(&self, image: &Image, guides: &Guides) -> Option<Image> {
        self.apply_unless(image, guides, &mut || false)
    }

    /// `apply`, asking `stop` before each pass and giving up (`None`) once it says
    /// yes: the render thread stops filtering a frame an edit has already made stale.
    pub fn apply_unless(
        &self,
        image: &Image,
        guides: &Guides,
        stop: &mut dyn FnMut() -> bool,
    ) -> Option<Image> {
        let (w, h) = (image.width() as usize, image.height() as usize);
        if (guides.width as usize, guides.height as usize) != (w, h) {
            return None;
        }
        let g = PlanarGuides::new(self, guides);
        let mut current = Planar::of(image.pixels());
        for pass in 0..self.passes {
            if stop() {
                return None;
            }
            let step = 1usize << pass;
            let sigma_c = self.sigma_color / (1u32 << pass) as f32;
            let compressed = Planar(
                current
                    .0
                    .each_ref()
                    .map(|plane| plane.iter().map(|&v| compress_channel(v)).collect()),
            );
            let rows: Vec<[Vec<f32>; 3]> = (0..h)
                .into_par_iter()
                .map(|y| {
                    let row = RowPass {
                        filter: self,
                        guides: &g,
                        src: &current,
                        compressed: &compressed,
                        width: w,
                        height: h,
                        step,
                        inv_color: 1.0 / (sigma_c * sigma_c),
                    };
                    row.run(y)
                })
                .collect();
            for (y, row) in rows.into_iter().enumerate() {
                for (plane, values) in current.0.iter_mut().zip(&row) {
                    plane[y * w..(y + 1) * w].copy_from_slice(values);
                }
            }
        }
        Image::from_pixels(w as u32, h as u32, current.pixels().collect()).ok()
    }

    /// The filter as Dammertz et al. write it, one neighbour at a time with the
    /// library's `exp`: what `apply` is tested and benchmarked against.
    pub fn apply_reference(&self, image: &Image, guides: &Guides) -> Option<Image> {
        let (w, h) = (image.width(), image.height());
        if (guides.width, guides.height) != (w, h) {
            return None;
        }
        let mut current: Vec<[f32; 3]> = image.pixels().to_vec();
        for pass in 0..self.passes {
            let step = 1i64 << pass;
            let sigma_c = self.sigma_color / (1u32 << pass) as f32;
            let src = &current;
            // Each pixel's compressed colour once per pass, not once per neighbour.
            let compressed: Vec<[f32; 3]> = src.par_iter().map(|&c| compress(c)).collect();
            let next: Vec<[f32; 3]> = (0..(w * h) as usize)
                .into_par_iter()
                .map(|p| self.filter_pixel_reference((src, &compressed), guides, p, step, sigma_c))
                .collect();
            current = next;
        }
        Image::from_pixels(w, h, current).ok()
    }

    fn filter_pixel_reference(
        &self,
        (src, compressed): (&[[f32; 3]], &[[f32; 3]]),
        g: &Guides,
        p: usize,
        step: i64,
        sigma_c: f32,
    ) -> [f32; 3] {
        let (w, h) = (i64::from(g.width), i64::from(g.height));
        let (x, y) = (p as i64 % w, p as i64 / w);
        let (cp, np, zp, ap) = (compressed[p], g.normal[p], g.depth[p], g.albedo[p]);
        let mut sum = [0.0f32; 3];
        let mut total = 0.0f32;
        for (j, ky) in KERNEL.iter().enumerate() {
            let qy = y + (j as i64 - 2) * step;
            if !(0..h).contains(&qy) {
                continue;
            }
            for (i, kx) in KERNEL.iter().enumerate() {
                let qx = x + (i as i64 - 2) * step;
                if !(0..w).contains(&qx) {
                    continue;
                }
                let q = (qy * w + qx) as usize;
                let weight =
                    kx * ky * self.edge_weight(cp, np, zp, ap, compressed[q], g, q, sigma_c);
                for k in 0..3 {
                    sum[k] += weight * src[q][k];
                }
                total += weight;
            }
        }
        // The centre's own weight is positive, so `total` is too.
        sum.map(|s| s / total)
    }

    #[allow(clippy::too_many_arguments)]
    fn edge_weight(
        &self,
        cp: [f32; 3],
        np: [f32; 3],
        zp: f32,
        ap: [f32; 3],
        // Both colours compressed (`compress`).
        cq: [f32; 3],
        g: &Guides,
        q: usize,
        sigma_c: f32,
    ) -> f32 {
        let zq = g.depth[q];
        // Background and surface never mix; two background pixels always do.
        match (zp.is_finite(), zq.is_finite()) {
            (false, false) => return 1.0,
            (true, false) | (false, true) => return 0.0,
            (true, true) => {}
        }
        let nq = g.normal[q];
        let cos = (np[0] * nq[0] + np[1] * nq[1] + np[2] * nq[2]).max(0.0);
        let w_normal = cos.powi(self.normal_power);
        if w_normal == 0.0 {
            return 0.0;
        }
        // The depth, albedo and colour weights are exponentials: one exp of the sum.
        let depth = (zp - zq).abs() / (self.sigma_depth * zp.max(1e-6));
        let albedo = dist2(ap, g.albedo[q]).sqrt() / self.sigma_albedo;
        let color = dist2(cp, cq) / (sigma_c * sigma_c);
        w_normal * (-(depth + albedo + color)).exp()
    }
}

/// Three colour channels, each a row-major plane.
struct Planar([Vec<f32>; 3]);

impl Planar {
    fn of(pixels: &[[f32; 3]]) -> Self {
        Self(std::array::from_fn(|k| {
            pixels.iter().map(|p| p[k]).collect()
        }))
    }

    fn pixels(&self) -> impl Iterator<Item = [f32; 3]> + '_ {
        (0..self.0[0].len()).map(|p| [self.0[0][p], self.0[1][p], self.0[2][p]])
    }
}

/// The guides in planes, background made arithmetic: `background` is 1 or 0, and a
/// background pixel's normal, depth and albedo are 0 so every weight computed for it is
/// finite (and then replaced: background and surface never mix, two background pixels
/// always do). `inv_depth` is the centre's depth scale, one division per pixel.
struct PlanarGuides {
    normal: Planar,
    albedo: Planar,
    depth: Vec<f32>,
    inv_depth: Vec<f32>,
    background: Vec<f32>,
}

impl PlanarGuides {
    fn new(filter: &Denoiser, g: &Guides) -> Self {
        let surface = |p: usize| g.depth[p].is_finite();
        let n = g.depth.len();
        let keep = |v: [f32; 3], p: usize| if surface(p) { v } else { [0.0; 3] };
        Self {
            normal: Planar::of(&(0..n).map(|p| keep(g.normal[p], p)).collect::<Vec<_>>()),
            albedo: Planar::of(&(0..n).map(|p| keep(g.albedo[p], p)).collect::<Vec<_>>()),
            depth: (0..n)
                .map(|p| if surface(p) { g.depth[p] } else { 0.0 })
                .collect(),
            inv_depth: (0..n)
                .map(|p| {
                    let z = if surface(p) { g.depth[p] } else { 0.0 };
                    1.0 / (filter.sigma_depth * z.max(1e-6))
                })
                .collect(),
            background: (0..n).map(|p| if surface(p) { 0.0 } else { 1.0 }).collect(),
        }
    }
}

/// One pass of `Denoiser::apply` over one row.
struct RowPass<'a> {
    filter: &'a Denoiser,
    guides: &'a PlanarGuides,
    src: &'a Planar,
    compressed: &'a Planar,
    width: usize,
    height: usize,
    step: usize,
    inv_color: f32,
}

impl<'a> RowPass<'a> {
    /// Row `y` filtered: per channel, the row's new values.
    fn run(&self, y: usize) -> [Vec<f32>; 3] {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked above).
            return unsafe { self.run_avx512(y) };
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked above).
            return unsafe { self.run_avx2(y) };
        }
        self.run_portable(y)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn run_avx2(&self, y: usize) -> [Vec<f32>; 3] {
        self.run_portable(y)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn run_avx512(&self, y: usize) -> [Vec<f32>; 3] {
        self.run_portable(y)
    }

    /// Inlined into `run_avx2` and `run_avx512`, so the same code is compiled for
    /// each instruction set (and gives the same bits: Rust fuses no multiply and add,
    /// and nothing is reordered).
    #[inline(always)]
    fn run_portable(&self, y: usize) -> [Vec<f32>; 3] {
        // The default power (64) as six squarings inside the loop, which then
        // vectorises; any other through `powi`.
        match self.filter.normal_power {
            64 => self.taps(y, |c| {
                let c = c * c;
                let c = c * c;
                let c = c * c;
                let c = c * c;
                let c = c * c;
                c * c
            }),
            n => self.taps(y, |c| c.powi(n)),
        }
    }

    /// The 25 taps of row `y`, one pass over the row each: for every pixel, the
    /// neighbour's edge-stopping weight and its weighted colour.
    #[inline(always)]
    fn taps(&self, y: usize, power: impl Fn(f32) -> f32) -> [Vec<f32>; 3] {
        let (w, step) = (self.width, self.step);
        let mut sum: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; w]);
        let mut total = vec![0.0f32; w];
        let row = y * w;
        let g = self.guides;
        for (j, ky) in KERNEL.iter().enumerate() {
            let Some(qy) = (y + j * step).checked_sub(2 * step) else {
                continue;
            };
            if qy >= self.height {
                continue;
            }
            for (i, kx) in KERNEL.iter().enumerate() {
                // Pixels x of this row whose neighbour x + (i - 2) * step is inside.
                let (x0, x1) = if i < 2 {
                    ((2 - i) * step, w)
                } else {
                    (0, w.saturating_sub((i - 2) * step))
                };
                if x0 >= x1 {
                    continue;
                }
                let n = x1 - x0;
                let (p, q) = (row + x0, qy * w + x0 + i * step - 2 * step);
                let centre = |v: &'a [f32]| &v[p..p + n];
                let near = |v: &'a [f32]| &v[q..q + n];
                let (npx, npy, npz) = (
                    centre(&g.normal.0[0]),
                    centre(&g.normal.0[1]),
                    centre(&g.normal.0[2]),
                );
                let (nqx, nqy, nqz) = (
                    near(&g.normal.0[0]),
                    near(&g.normal.0[1]),
                    near(&g.normal.0[2]),
                );
                let (zp, zq, inv_z) = (centre(&g.depth), near(&g.depth), centre(&g.inv_depth));
                let (bp, bq) = (centre(&g.background), near(&g.background));
                let (apr, apg, apb) = (
                    centre(&g.albedo.0[0]),
                    centre(&g.albedo.0[1]),
                    centre(&g.albedo.0[2]),
                );
                let (aqr, aqg, aqb) = (
                    near(&g.albedo.0[0]),
                    near(&g.albedo.0[1]),
                    near(&g.albedo.0[2]),
                );
                let c = &self.compressed.0;
                let (cpr, cpg, cpb) = (centre(&c[0]), centre(&c[1]), centre(&c[2]));
                let (cqr, cqg, cqb) = (near(&c[0]), near(&c[1]), near(&c[2]));
                let (sr, sg, sb) = (
                    near(&self.src.0[0]),
                    near(&self.src.0[1]),
                    near(&self.src.0[2]),
                );
                let (inv_albedo, inv_color, kk) =
                    (1.0 / self.filter.sigma_albedo, self.inv_color, kx * ky);
                let [out_r, out_g, out_b] = &mut sum;
                let (out_r, out_g, out_b) =
                    (&mut out_r[x0..x1], &mut out_g[x0..x1], &mut out_b[x0..x1]);
                let tot = &mut total[x0..x1];
                for x in 0..n {
                    let cos = (npx[x] * nqx[x] + npy[x] * nqy[x] + npz[x] * nqz[x]).max(0.0);
                    let (dr, dg, db) = (apr[x] - aqr[x], apg[x] - aqg[x], apb[x] - aqb[x]);
                    let (er, eg, eb) = (cpr[x] - cqr[x], cpg[x] - cqg[x], cpb[x] - cqb[x]);
                    let exponent = (zp[x] - zq[x]).abs() * inv_z[x]
                        + (dr * dr + dg * dg + db * db).sqrt() * inv_albedo
                        + (er * er + eg * eg + eb * eb) * inv_color;
                    let surface = power(cos) * exp_neg(exponent);
                    let edge = if bp[x] != bq[x] {
                        0.0
                    } else if bp[x] > 0.0 {
                        1.0
                    } else {
                        surface
                    };
                    let weight = kk * edge;
                    out_r[x] += weight * sr[x];
                    out_g[x] += weight * sg[x];
                    out_b[x] += weight * sb[x];
                    tot[x] += weight;
                }
            }
        }
        // The centre's own weight is positive, so `total` is too.
        for channel in sum.iter_mut() {
            for (v, t) in channel.iter_mut().zip(&total) {
                *v /= *t;
            }
        }
        sum
    }
}

/// `exp(-x)` for `x >= 0` within 1e-5 relative (the polynomial 2e-7 in f32, the rest
/// the f32 product `x log2 e` at large x); NaN and infinity give 0. 2^(-x log2 e) split
/// into a power of two, set in the exponent bits, and a degree-5 polynomial of the
/// fraction; no branch, so a loop of it vectorises. Below 2^-127 the result is 0
/// (such weights are below any f32 image's rounding).
#[inline(always)]
fn exp_neg(x: f32) -> f32 {
    // `max` returns -127 for NaN too (`clamp` would keep the NaN); `min` keeps a
    // negative x's t at 0.
    #[allow(clippy::manual_clamp)]
    let t = (-x * std::f32::consts::LOG2_E).max(-127.0).min(0.0);
    // floor(t) by truncation (t <= 0): `f32::floor` is a library call on the x86-64
    // baseline and would not vectorise, nor would `as` (its saturation and NaN rule
    // make the compiler convert one lane at a time).
    // SAFETY: t is finite and within [-127, 0], so it fits an i32.
    let i = unsafe { t.to_int_unchecked::<i32>() };
    let i = i - i32::from(i as f32 > t);
    let f = t - i as f32;
    // 2^f on [0, 1): coefficients fitted for the least largest relative error with
    // the constant 1, so exp(-0) is 1 (8.2e-8 in exact arithmetic), evaluated in
    // Estrin's form, whose dependency chain is half Horner's.
    const C: [f32; 6] = [
        1.0,
        0.693_151_3,
        0.240_164_46,
        0.055_799_91,
        0.009_017_038,
        0.001_867_126_3,
    ];
    let f2 = f * f;
    let p = (C[0] + C[1] * f) + f2 * ((C[2] + C[3] * f) + f2 * (C[4] + C[5] * f));
    // i = -127 gives the bits of 0.0.
    f32::from_bits(((i + 127) as u32) << 23) * p
}

impl Guides {
    /// The guides of the image of half the size (rounded up) that `halve` makes: each
    /// 2 x 2 block's top-left pixel's.
    pub fn halved(&self) -> Guides {
        let (w, hw) = (self.width as usize, self.width.div_ceil(2) as usize);
        let n = hw * self.height.div_ceil(2) as usize;
        let pick = |i: usize| 2 * (i / hw) * w + 2 * (i % hw);
        Guides {
            width: hw as u32,
            height: self.height.div_ceil(2),
            normal: (0..n).map(|i| self.normal[pick(i)]).collect(),
            depth: (0..n).map(|i| self.depth[pick(i)]).collect(),
            albedo: (0..n).map(|i| self.albedo[pick(i)]).collect(),
        }
    }
}

impl Denoiser {
    /// The filter at half the resolution, for the viewport's first picture after an
    /// edit that keeps the samples (an emission edit) while `apply` would take too
    /// long: the image averaged over 2 x 2 blocks, filtered with `half_guides`
    /// (`Guides::halved`) by one pass fewer (the same footprint in full pixels) and
    /// half the colour tolerance (a block's mean has half a pixel's noise), then
    /// spread back bilinearly. About a quarter of `apply`'s time; softer at edges
    /// (within two pixels of a depth edge, tested). `None` when the guides are not the halved image's size.
    pub fn apply_halved(&self, image: &Image, half_guides: &Guides) -> Option<Image> {
        let (w, h) = (image.width(), image.height());
        if (half_guides.width, half_guides.height) != (w.div_ceil(2), h.div_ceil(2)) {
            return None;
        }
        let coarse = Denoiser {
            passes: self.passes.saturating_sub(1).max(1),
            sigma_color: self.sigma_color / 2.0,
            ..*self
        };
        let filtered = coarse.apply(&halve(image), half_guides)?;
        Some(double(&filtered, w, h))
    }
}

/// Each 2 x 2 block's mean (the pixels of it inside the image).
fn halve(image: &Image) -> Image {
    let (w, h) = (image.width(), image.height());
    let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = Image::new(hw, hh);
    out.pixels_mut()
        .par_chunks_mut(hw as usize)
        .enumerate()
        .for_each(|(by, row)| {
            for (bx, p) in row.iter_mut().enumerate() {
                let (mut sum, mut n) = ([0.0f32; 3], 0.0f32);
                for y in (2 * by as u32)..(2 * by as u32 + 2).min(h) {
                    for x in (2 * bx as u32)..(2 * bx as u32 + 2).min(w) {
                        let v = image.get(x, y);
                        (0..3).for_each(|k| sum[k] += v[k]);
                        n += 1.0;
                    }
                }
                *p = sum.map(|s| s / n);
            }
        });
    out
}

/// `small` (from `halve`) spread back to `w` x `h` bilinearly, its pixels' centres at
/// their blocks' centres.
fn double(small: &Image, w: u32, h: u32) -> Image {
    let (sw, sh) = (small.width(), small.height());
    // Along an axis: the two coarse pixels around full pixel x and the second's weight.
    let axis = |len: u32, coarse: u32| -> Vec<(u32, u32, f32)> {
        (0..len)
            .map(|x| {
                let u = (x as f32 + 0.5) / 2.0 - 0.5;
                let i0 = u.floor().max(0.0) as u32;
                let i0 = i0.min(coarse - 1);
                let i1 = (i0 + 1).min(coarse - 1);
                (i0, i1, (u - i0 as f32).clamp(0.0, 1.0))
            })
            .collect()
    };
    let (cols, rows) = (axis(w, sw), axis(h, sh));
    crate::preview::bilinear(small, (&cols, &rows))
}

/// `noisy` where `strength` is 0, `denoised` where it is 1, linear in between.
pub fn blend(noisy: &Image, denoised: &Image, strength: f32) -> Image {
    let mut out = noisy.clone();
    let s = strength.clamp(0.0, 1.0);
    for (o, d) in out.pixels_mut().iter_mut().zip(denoised.pixels()) {
        for k in 0..3 {
            o[k] += s * (d[k] - o[k]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat_guides(w: u32, h: u32) -> Guides {
        let n = (w * h) as usize;
        Guides {
            width: w,
            height: h,
            normal: vec![[0.0, 0.0, 1.0]; n],
            depth: vec![1.0; n],
            albedo: vec![[0.5; 3]; n],
        }
    }

    fn noisy(w: u32, h: u32, level: f32, amplitude: f32) -> Image {
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let u = meso_materials::rng::SampleStream::new(&[u64::from(x), u64::from(y)]).at(0)
                    as f32;
                img.set(x, y, [level + amplitude * (u - 0.5) * 2.0; 3]);
            }
        }
        img
    }

    fn rms(img: &Image, level: f32) -> f32 {
        (img.pixels()
            .iter()
            .map(|p| (p[0] - level).powi(2))
            .sum::<f32>()
            / img.pixels().len() as f32)
            .sqrt()
    }

    #[test]
    fn noise_on_one_flat_surface_is_smoothed_and_its_level_kept() {
        let img = noisy(64, 64, 0.5, 0.2);
        let out = Denoiser::default()
            .apply(&img, &flat_guides(64, 64))
            .expect("sizes match");
        let (before, after) = (rms(&img, 0.5), rms(&out, 0.5));
        // Uniform noise of amplitude 0.2 has RMS 0.115; the filter must cut it by 4x.
        assert!(after < before / 4.0, "{before} -> {after}");
        let mean = out.pixels().iter().map(|p| p[0]).sum::<f32>() / 4096.0;
        assert!((mean - 0.5).abs() < 0.01, "mean {mean}");
    }

    #[test]
    fn the_halved_filter_smooths_keeps_the_level_and_keeps_edges_within_two_pixels() {
        let (w, h) = (65u32, 48u32);
        let d = Denoiser::for_samples(1);
        // Noise on one flat surface: smoothed, its level kept.
        let img = noisy(w, h, 0.5, 0.2);
        let g = flat_guides(w, h);
        assert_eq!((g.halved().width, g.halved().height), (33, 24));
        let out = d.apply_halved(&img, &g.halved()).expect("sizes match");
        assert_eq!((out.width(), out.height()), (w, h));
        let (before, after) = (rms(&img, 0.5), rms(&out, 0.5));
        assert!(after < before / 4.0, "{before} -> {after}");
        assert!(
            d.apply_halved(&img, &g).is_none(),
            "full-size guides refused"
        );
        // A step at a depth edge (x = 30): pixels two or more away keep their side.
        let mut step = Image::new(w, h);
        let mut g = flat_guides(w, h);
        for y in 0..h {
            for x in 0..w {
                step.set(x, y, [if x < 30 { 0.2 } else { 0.8 }; 3]);
                if x >= 30 {
                    g.depth[(y * w + x) as usize] = 2.0;
                }
            }
        }
        let out = d.apply_halved(&step, &g.halved()).expect("sizes match");
        for y in 0..h {
            for x in (0..28).chain(32..w) {
                let want = if x < 30 { 0.2 } else { 0.8 };
                let got = out.get(x, y)[0];
                assert!((got - want).abs() < 0.02, "({x}, {y}): {got} vs {want}");
            }
        }
    }

    #[test]
    fn a_stopped_filter_gives_up_between_passes() {
        let (img, g) = (noisy(16, 16, 0.5, 0.2), flat_guides(16, 16));
        let d = Denoiser::default();
        let mut asked = 0;
        let mut after_two = || {
            asked += 1;
            asked > 2
        };
        assert!(d.apply_unless(&img, &g, &mut after_two).is_none());
        assert_eq!(asked, 3, "asked before each pass until it said yes");
        assert_eq!(d.apply_unless(&img, &g, &mut || false), d.apply(&img, &g));
    }

    #[test]
    fn edges_in_every_guide_are_kept() {
        // Left half at 0.2, right half at 0.8, with an edge in one guide at a time:
        // the filter must keep the step (no pixel pulled across by more than 2%).
        let (w, h) = (32, 16);
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                img.set(x, y, [if x < w / 2 { 0.2 } else { 0.8 }; 3]);
            }
        }
        for guide in ["normal", "depth", "albedo", "background"] {
            let mut g = flat_guides(w, h);
            for y in 0..h {
                for x in w / 2..w {
                    let p = (y * w + x) as usize;
                    match guide {
                        "normal" => g.normal[p] = [1.0, 0.0, 0.0],
                        "depth" => g.depth[p] = 2.0,
                        "albedo" => g.albedo[p] = [0.9; 3],
                        _ => g.depth[p] = f32::INFINITY,
                    }
                }
            }
            let out = Denoiser {
                // The colour weight alone would also keep this step; switch it off.
                sigma_color: 1e6,
                ..Denoiser::default()
            }
            .apply(&img, &g)
            .expect("sizes match");
            for y in 0..h {
                for x in 0..w {
                    let want = img.get(x, y)[0];
                    let got = out.get(x, y)[0];
                    assert!(
                        (got - want).abs() < 0.02 * 0.6,
                        "{guide}: ({x}, {y}) {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_polynomial_exp_is_within_its_stated_error() {
        let mut worst = 0.0f64;
        for k in 0..=200_000 {
            let x = k as f32 * 0.0005; // 0 to 100
            let want = (-f64::from(x)).exp();
            let got = f64::from(exp_neg(x));
            if want > 1e-37 {
                worst = worst.max((got - want).abs() / want);
            } else {
                assert!(got <= 2e-37, "exp(-{x}) = {got}");
            }
        }
        assert!(worst < 1e-5, "relative error {worst}");
        assert_eq!(exp_neg(0.0), 1.0);
        assert_eq!(exp_neg(f32::INFINITY), 0.0);
        assert_eq!(exp_neg(f32::NAN), 0.0);
    }

    /// Guides with surfaces at three depths, creases in the normals, albedo steps and
    /// background, over a noisy image with highlights: every kind of edge, at sizes
    /// that are not multiples of the kernel's steps.
    fn busy_scene(w: u32, h: u32) -> (Image, Guides) {
        let mut g = flat_guides(w, h);
        let mut img = noisy(w, h, 0.4, 0.35);
        for y in 0..h {
            for x in 0..w {
                let p = (y * w + x) as usize;
                let u = meso_materials::rng::SampleStream::new(&[u64::from(x), u64::from(y), 9]);
                g.depth[p] = match (x * 3 / w, y % 7) {
                    (_, 0) if x % 5 == 0 => f32::INFINITY,
                    (0, _) => 1.0,
                    (1, _) => 1.0 + 0.02 * u.at(0) as f32,
                    _ => 4.0,
                };
                let tilt = if (x / 6 + y / 9) % 2 == 0 { 0.3 } else { -0.2 };
                let n: [f32; 3] = [tilt, 0.1, 1.0];
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                g.normal[p] = n.map(|c| c / len);
                g.albedo[p] = [0.2 + 0.6 * ((x / 11) % 2) as f32, 0.5, 0.4];
                if u.at(1) < 0.02 {
                    img.set(x, y, [25.0, 20.0, 18.0]);
                }
            }
        }
        (img, g)
    }

    /// The AVX2 build of a row pass gives the portable build's bits (docs/rendering.md
    /// says so); on a CPU without AVX2 both calls run the portable code.
    #[test]
    fn the_avx512_avx2_and_portable_rows_are_bit_identical() {
        let (img, guides) = busy_scene(61, 37);
        let filter = Denoiser::for_samples(2);
        let g = PlanarGuides::new(&filter, &guides);
        let src = Planar::of(img.pixels());
        let compressed = Planar::of(
            &img.pixels()
                .iter()
                .map(|&c| compress(c))
                .collect::<Vec<_>>(),
        );
        for step in [1, 2, 4, 8] {
            let row = RowPass {
                filter: &filter,
                guides: &g,
                src: &src,
                compressed: &compressed,
                width: 61,
                height: 37,
                step,
                inv_color: 1.0 / (filter.sigma_color * filter.sigma_color),
            };
            for y in 0..37 {
                let portable = row.run_portable(y);
                let mut others = vec![("dispatched", row.run(y))];
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU has AVX2 (checked above).
                    others.push(("avx2", unsafe { row.run_avx2(y) }));
                }
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the CPU has AVX-512F (checked above).
                    others.push(("avx512", unsafe { row.run_avx512(y) }));
                }
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                for (name, other) in &others {
                    for k in 0..3 {
                        assert_eq!(
                            bits(&other[k]),
                            bits(&portable[k]),
                            "{name}: step {step}, row {y}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_fast_filter_agrees_with_the_reference() {
        for (w, h) in [(61, 37), (128, 96), (5, 3)] {
            let (img, g) = busy_scene(w, h);
            for samples in [1, 4, 16] {
                let d = Denoiser::for_samples(samples);
                let fast = d.apply(&img, &g).expect("sizes match");
                let slow = d.apply_reference(&img, &g).expect("sizes match");
                for (a, b) in fast.pixels().iter().zip(slow.pixels()) {
                    for k in 0..3 {
                        assert!(
                            (a[k] - b[k]).abs() <= 1e-4 * b[k].abs().max(1.0),
                            "{w}x{h}, {samples} spp: {a:?} vs {b:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_viewport_blend_fades_out_and_guides_must_match() {
        assert_eq!(viewport_strength(1), 1.0);
        assert!(viewport_strength(16) > 0.0 && viewport_strength(16) < 1.0);
        assert_eq!(viewport_strength(FADE_SAMPLES), 0.0);
        let img = noisy(8, 8, 0.5, 0.2);
        let flat = Image::from_pixels(8, 8, vec![[0.5; 3]; 64]).expect("size");
        assert_eq!(blend(&img, &flat, 0.0), img);
        assert_eq!(blend(&img, &flat, 1.0), flat);
        assert!(
            Denoiser::default()
                .apply(&img, &flat_guides(8, 9))
                .is_none()
        );
    }
}
