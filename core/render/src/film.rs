//! The progressive film: per pixel and per *layer* a running sum in f64 and a sample
//! count. Radiance is linear in each light's emission, in the ambient radiance and in
//! the background, so a mode accumulates each of them for unit emission in its own
//! layer and `resolve` weights the layers: an emission edit re-weights without losing a
//! sample, and a moved light restarts only its layer. A non-finite sample is dropped
//! and counted, never added (docs/rendering.md).

use glam::DVec3;
use rayon::prelude::*;

use meso_materials::image::Image;

#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    width: u32,
    height: u32,
    layers: usize,
    /// Pixel-major: index `pixel * layers + layer`.
    sum: Vec<[f64; 3]>,
    count: Vec<u32>,
    /// Per pixel, the materials its samples shaded (bit `m % 64`): a material edit
    /// restarts only these pixels.
    touched: Vec<u64>,
    /// Per pixel, the texture coordinates its samples shaded, as a box (u min, v min,
    /// u max, v max; empty while u min > u max): an edit of a few texels restarts only
    /// the pixels whose box reaches one of them.
    reached: Vec<UvBox>,
    dropped: u64,
}

/// A box of texture coordinates (before tiling): u min, v min, u max, v max.
pub type UvBox = [f32; 4];

/// The box that holds nothing.
pub const EMPTY_UV_BOX: UvBox = [
    f32::INFINITY,
    f32::INFINITY,
    f32::NEG_INFINITY,
    f32::NEG_INFINITY,
];

/// One row of the film, handed to a worker thread.
pub struct FilmRow<'a> {
    pub y: u32,
    layers: usize,
    sum: &'a mut [[f64; 3]],
    count: &'a mut [u32],
    touched: &'a mut [u64],
    reached: &'a mut [UvBox],
    dropped: u64,
}

impl FilmRow<'_> {
    /// Adds one sample of `layer` at column `x`; returns false if it was dropped.
    #[inline]
    pub fn add(&mut self, x: u32, layer: usize, rgb: DVec3) -> bool {
        if rgb.is_finite() {
            let i = x as usize * self.layers + layer;
            let s = &mut self.sum[i];
            s[0] += rgb.x;
            s[1] += rgb.y;
            s[2] += rgb.z;
            self.count[i] += 1;
            true
        } else {
            self.dropped += 1;
            false
        }
    }

    /// Records that the pixel's samples shaded the materials in `mask`.
    #[inline]
    pub fn touch(&mut self, x: u32, mask: u64) {
        self.touched[x as usize] |= mask;
    }

    /// Records that one of the pixel's samples shaded texture coordinates `uv`.
    #[inline]
    pub fn reach(&mut self, x: u32, uv: glam::DVec2) {
        extend_uv_box(&mut self.reached[x as usize], uv);
    }

    /// Records that the pixel's samples shaded the texture coordinates in box `b`.
    #[inline]
    pub fn reach_box(&mut self, x: u32, b: &UvBox) {
        let r = &mut self.reached[x as usize];
        *r = [
            r[0].min(b[0]),
            r[1].min(b[1]),
            r[2].max(b[2]),
            r[3].max(b[3]),
        ];
    }
}

/// Grows `b` to hold `uv` (a non-finite uv is left out: it shades nothing).
#[inline]
pub fn extend_uv_box(b: &mut UvBox, uv: glam::DVec2) {
    if uv.is_finite() {
        let (u, v) = (uv.x as f32, uv.y as f32);
        *b = [b[0].min(u), b[1].min(v), b[2].max(u), b[3].max(v)];
    }
}

/// What the light layout (`render::layers::Layers`) does to a film: the host's
/// `Film` and the GPU mode's film on the device.
pub trait LayeredFilm {
    fn layers(&self) -> usize;
    /// Forgets one layer's samples (its light moved).
    fn reset_layer(&mut self, layer: usize);
    /// Keeps layers `0..keep` and makes the rest, up to `layers`, empty.
    fn keep_layers(&mut self, layers: usize, keep: usize);
    /// Appends an empty layer (a light was added).
    fn push_layer(&mut self);
    /// Removes a layer (a light was removed); the others keep their samples.
    fn remove_layer(&mut self, layer: usize);
}

impl LayeredFilm for Film {
    fn layers(&self) -> usize {
        self.layers
    }
    fn reset_layer(&mut self, layer: usize) {
        Film::reset_layer(self, layer);
    }
    fn keep_layers(&mut self, layers: usize, keep: usize) {
        Film::keep_layers(self, layers, keep);
    }
    fn push_layer(&mut self) {
        Film::push_layer(self);
    }
    fn remove_layer(&mut self, layer: usize) {
        Film::remove_layer(self, layer);
    }
}

/// The bit of material `index` in a pixel's touched mask.
pub fn material_bit(index: usize) -> u64 {
    1 << (index % 64)
}

/// A film that would not fit in memory, refused before anything is allocated.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "a {width}x{height} film with {layers} layers needs {bytes} bytes ({:.2} GiB), more than the {limit} bytes ({:.2} GiB) allowed ({})",
    gib(*.bytes), gib(*.limit), LIMIT_RULE
)]
pub struct FilmTooLarge {
    pub width: u32,
    pub height: u32,
    pub layers: usize,
    pub bytes: u64,
    pub limit: u64,
}

fn gib(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 30) as f64
}

/// How `memory_limit_bytes` is chosen, for the error message and the docs.
pub const LIMIT_RULE: &str =
    "3/4 of MemAvailable in /proc/meminfo, or 8 GiB where it cannot be read";

/// The most bytes a film may take: three quarters of the memory the OS says is
/// available (`MemAvailable` in /proc/meminfo), or 8 GiB where that cannot be read.
pub fn memory_limit_bytes() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| mem_available_bytes(&text))
        .map_or(8 << 30, |b| b / 4 * 3)
}

/// `MemAvailable` of a /proc/meminfo text, in bytes.
fn mem_available_bytes(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

impl Film {
    /// `Film::new` if it fits within `limit` bytes; nothing is allocated otherwise.
    pub fn try_new(
        width: u32,
        height: u32,
        layers: usize,
        limit: u64,
    ) -> Result<Self, FilmTooLarge> {
        Self::check(width, height, layers, limit)?;
        Ok(Self::new(width, height, layers))
    }

    /// `Err` naming the bytes if a `width` x `height` film with `layers` layers would
    /// take more than `limit` bytes.
    pub fn check(width: u32, height: u32, layers: usize, limit: u64) -> Result<(), FilmTooLarge> {
        let bytes = Self::bytes_for(width, height, layers);
        if bytes > limit {
            Err(FilmTooLarge {
                width,
                height,
                layers,
                bytes,
                limit,
            })
        } else {
            Ok(())
        }
    }

    pub fn new(width: u32, height: u32, layers: usize) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            layers,
            sum: vec![[0.0; 3]; n * layers],
            count: vec![0; n * layers],
            touched: vec![0; n],
            reached: vec![EMPTY_UV_BOX; n],
            dropped: 0,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn layers(&self) -> usize {
        self.layers
    }

    /// Runs `f` on every row in parallel (rayon) and returns its results in row order;
    /// the rows' dropped samples are added to the film's count.
    pub fn par_rows<R, F>(&mut self, f: F) -> Vec<R>
    where
        R: Send,
        F: Fn(&mut FilmRow<'_>) -> R + Sync + Send,
    {
        self.par_rows_in(0..self.height, f)
    }

    /// `par_rows` over the rows `rows` only (a tile of a frame that yields between
    /// tiles); rows past the film's height are ignored.
    pub fn par_rows_in<R, F>(&mut self, rows: std::ops::Range<u32>, f: F) -> Vec<R>
    where
        R: Send,
        F: Fn(&mut FilmRow<'_>) -> R + Sync + Send,
    {
        let w = self.width as usize;
        let l = self.layers;
        let end = rows.end.min(self.height) as usize;
        let start = (rows.start as usize).min(end);
        if w == 0 || l == 0 || start == end {
            return Vec::new();
        }
        let rows: Vec<(R, u64)> = self.sum[start * w * l..end * w * l]
            .par_chunks_mut(w * l)
            .zip(self.count[start * w * l..end * w * l].par_chunks_mut(w * l))
            .zip(self.touched[start * w..end * w].par_chunks_mut(w))
            .zip(self.reached[start * w..end * w].par_chunks_mut(w))
            .enumerate()
            .map(|(i, (((sum, count), touched), reached))| {
                let mut row = FilmRow {
                    y: (start + i) as u32,
                    layers: l,
                    sum,
                    count,
                    touched,
                    reached,
                    dropped: 0,
                };
                let r = f(&mut row);
                (r, row.dropped)
            })
            .collect();
        self.dropped += rows.iter().map(|(_, d)| d).sum::<u64>();
        rows.into_iter().map(|(r, _)| r).collect()
    }

    /// Adds one sample of pixel `p` (row-major): `out[l]` to each of the `active`
    /// layers, the materials it shaded and their texture-coordinate box (what a row
    /// worker records, for one pixel rendered outside a whole frame).
    pub fn add_pixel_sample(
        &mut self,
        p: u32,
        active: &[usize],
        out: &[DVec3],
        mask: u64,
        reached: &UvBox,
    ) {
        let (w, l) = (self.width as usize, self.layers);
        let (y, x) = (p as usize / w, p as usize % w);
        let mut row = FilmRow {
            y: y as u32,
            layers: l,
            sum: &mut self.sum[y * w * l..(y + 1) * w * l],
            count: &mut self.count[y * w * l..(y + 1) * w * l],
            touched: &mut self.touched[y * w..(y + 1) * w],
            reached: &mut self.reached[y * w..(y + 1) * w],
            dropped: 0,
        };
        for &layer in active {
            row.add(x as u32, layer, out[layer]);
        }
        row.touch(x as u32, mask);
        row.reach_box(x as u32, reached);
        let dropped = row.dropped;
        self.dropped += dropped;
    }

    /// Samples dropped for being NaN or infinite since the film was made.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The fewest samples any pixel has in any of `layers` (all layers if empty).
    pub fn min_samples(&self, layers: &[usize]) -> u32 {
        let all: Vec<usize> = (0..self.layers).collect();
        let layers = if layers.is_empty() { &all[..] } else { layers };
        self.count
            .chunks(self.layers.max(1))
            .flat_map(|c| layers.iter().map(move |&l| c[l]))
            .min()
            .unwrap_or(0)
    }

    /// Where a mode with this film stands after `frames` frames, counting the samples
    /// of the `active` layers (`min_samples`).
    pub fn progress(&self, frames: u32, active: &[usize]) -> super::Progress {
        let min_samples = self.min_samples(active);
        super::Progress {
            frames,
            min_samples,
            shows_every_pixel: min_samples > 0,
            dropped: self.dropped,
            width: self.width,
            height: self.height,
            film_bytes: self.bytes(),
        }
    }

    /// A new image size; every sample is forgotten, the dropped count kept.
    pub fn resize(&mut self, width: u32, height: u32) {
        let dropped = self.dropped;
        *self = Self::new(width, height, self.layers);
        self.dropped = dropped;
    }

    /// Forgets every sample (a camera or geometry change).
    pub fn reset(&mut self) {
        self.sum.iter_mut().for_each(|s| *s = [0.0; 3]);
        self.count.iter_mut().for_each(|c| *c = 0);
        self.touched.iter_mut().for_each(|t| *t = 0);
        self.reached.iter_mut().for_each(|b| *b = EMPTY_UV_BOX);
    }

    /// Forgets one layer's samples (its light moved).
    pub fn reset_layer(&mut self, layer: usize) {
        for i in (layer..self.sum.len()).step_by(self.layers) {
            self.sum[i] = [0.0; 3];
            self.count[i] = 0;
        }
    }

    /// Forgets every sample of the pixels whose samples shaded a material in `mask`;
    /// returns how many pixels restart.
    pub fn reset_touching(&mut self, mask: u64) -> usize {
        self.reset_reaching(mask, |_| true)
    }

    /// Forgets every sample of the pixels whose samples shaded a material in `mask`
    /// and whose box of shaded texture coordinates passes `reaches` (a conservative
    /// test against the edited texels); returns how many pixels restart.
    pub fn reset_reaching(&mut self, mask: u64, reaches: impl Fn(&UvBox) -> bool) -> usize {
        self.reset_reaching_pixels(mask, reaches).len()
    }

    /// `reset_reaching`, returning the restarted pixels (row-major indices, in order).
    pub fn reset_reaching_pixels(
        &mut self,
        mask: u64,
        reaches: impl Fn(&UvBox) -> bool,
    ) -> Vec<u32> {
        let mut n = Vec::new();
        for (p, t) in self.touched.iter_mut().enumerate() {
            if *t & mask != 0 && reaches(&self.reached[p]) {
                *t = 0;
                self.reached[p] = EMPTY_UV_BOX;
                n.push(p as u32);
                let r = p * self.layers..(p + 1) * self.layers;
                self.sum[r.clone()].iter_mut().for_each(|s| *s = [0.0; 3]);
                self.count[r].iter_mut().for_each(|c| *c = 0);
            }
        }
        n
    }

    /// Keeps layers `0..keep` and makes the rest, up to `layers`, empty (the light
    /// layers were laid out again).
    pub fn keep_layers(&mut self, layers: usize, keep: usize) {
        self.relayer(layers, |l| (l < keep).then_some(l));
    }

    /// The bytes a `width` x `height` film with `layers` layers holds: per pixel and
    /// layer three f64 sums and a u32 count, per pixel a u64 material mask and a box
    /// of four f32 texture coordinates.
    pub fn bytes_for(width: u32, height: u32, layers: usize) -> u64 {
        let pixels = u64::from(width) * u64::from(height);
        pixels * (layers as u64 * (3 * 8 + 4) + 8 + 16)
    }

    /// The bytes this film's buffers hold.
    pub fn bytes(&self) -> u64 {
        (self.sum.capacity() * std::mem::size_of::<[f64; 3]>()
            + self.count.capacity() * std::mem::size_of::<u32>()
            + self.touched.capacity() * std::mem::size_of::<u64>()
            + self.reached.capacity() * std::mem::size_of::<UvBox>()) as u64
    }

    /// Appends an empty layer (a light was added).
    pub fn push_layer(&mut self) {
        let old = self.layers;
        self.relayer(old + 1, |l| (l < old).then_some(l));
    }

    /// Removes a layer (a light was removed); the others keep their samples.
    pub fn remove_layer(&mut self, layer: usize) {
        self.relayer(self.layers - 1, |l| Some(l + usize::from(l >= layer)));
    }

    /// Rebuilds the buffers with `layers` layers, new layer `l` copied from old layer
    /// `from(l)` (empty where `None`).
    fn relayer(&mut self, layers: usize, from: impl Fn(usize) -> Option<usize>) {
        let pixels = self.touched.len();
        let mut sum = vec![[0.0; 3]; pixels * layers];
        let mut count = vec![0; pixels * layers];
        for p in 0..pixels {
            for l in 0..layers {
                if let Some(old) = from(l) {
                    sum[p * layers + l] = self.sum[p * self.layers + old];
                    count[p * layers + l] = self.count[p * self.layers + old];
                }
            }
        }
        self.sum = sum;
        self.count = count;
        self.layers = layers;
    }

    /// The image: per pixel the sum over layers of `weights[layer]` times the layer's
    /// mean (a layer without samples yet adds nothing).
    pub fn resolve(&self, weights: &[DVec3]) -> Image {
        assert_eq!(weights.len(), self.layers, "one weight per layer");
        let mut img = Image::new(self.width, self.height);
        let l = self.layers;
        img.pixels_mut()
            .par_iter_mut()
            .zip(
                self.sum
                    .par_chunks(l.max(1))
                    .zip(self.count.par_chunks(l.max(1))),
            )
            .for_each(|(p, (sums, counts))| {
                let mut v = DVec3::ZERO;
                for ((s, &n), w) in sums.iter().zip(counts).zip(weights) {
                    if n > 0 && *w != DVec3::ZERO {
                        v += *w * DVec3::from_array(*s) / n as f64;
                    }
                }
                *p = [v.x as f32, v.y as f32, v.z as f32];
            });
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn add(film: &mut Film, x: u32, layer: usize, rgb: [f64; 3]) {
        film.par_rows(|row| {
            if row.y == 0 {
                row.add(x, layer, DVec3::from_array(rgb));
            }
        });
    }

    #[test]
    fn averages_and_drops_non_finite_samples() {
        let mut f = Film::new(2, 1, 1);
        add(&mut f, 0, 0, [1.0, 2.0, 3.0]);
        add(&mut f, 0, 0, [3.0, 2.0, 1.0]);
        add(&mut f, 0, 0, [f64::NAN, 0.0, 0.0]);
        add(&mut f, 1, 0, [0.0, f64::INFINITY, 0.0]);
        assert_eq!(f.dropped(), 2);
        let img = f.resolve(&[DVec3::ONE]);
        assert_eq!(img.get(0, 0), [2.0, 2.0, 2.0]);
        assert_eq!(img.get(1, 0), [0.0; 3], "no valid sample yet");
        assert_eq!(f.min_samples(&[]), 0);
        f.reset();
        assert_eq!(f.resolve(&[DVec3::ONE]).get(0, 0), [0.0; 3]);
    }

    #[test]
    fn layers_are_weighted_reset_added_and_removed_independently() {
        let mut f = Film::new(1, 1, 3);
        for (layer, v) in [(0, 1.0), (1, 10.0), (2, 100.0)] {
            add(&mut f, 0, layer, [v; 3]);
            add(&mut f, 0, layer, [3.0 * v; 3]);
        }
        let w = [DVec3::ONE, DVec3::new(2.0, 0.0, 1.0), DVec3::splat(0.5)];
        // 2 * 1 + 20 * (2, 0, 1) + 200 * 0.5
        assert_eq!(f.resolve(&w).get(0, 0), [142.0, 102.0, 122.0]);
        f.reset_layer(1);
        assert_eq!(f.resolve(&w).get(0, 0), [102.0; 3]);
        assert_eq!(f.min_samples(&[0, 2]), 2);
        assert_eq!(f.min_samples(&[]), 0);
        f.remove_layer(0);
        assert_eq!(f.layers(), 2);
        assert_eq!(f.resolve(&[DVec3::ZERO, DVec3::ONE]).get(0, 0), [200.0; 3]);
        f.push_layer();
        assert_eq!(f.layers(), 3);
        assert_eq!(
            f.resolve(&[DVec3::ZERO, DVec3::ONE, DVec3::ONE]).get(0, 0),
            [200.0; 3]
        );
    }

    #[test]
    fn a_material_edit_restarts_only_the_pixels_that_shaded_it() {
        let mut f = Film::new(3, 1, 1);
        f.par_rows(|row| {
            for x in 0..3 {
                row.add(x, 0, DVec3::ONE);
                row.touch(x, material_bit(x as usize));
            }
        });
        assert_eq!(f.reset_touching(material_bit(1) | material_bit(2)), 2);
        let img = f.resolve(&[DVec3::ONE]);
        assert_eq!(
            [img.get(0, 0)[0], img.get(1, 0)[0], img.get(2, 0)[0]],
            [1.0, 0.0, 0.0]
        );
        assert_eq!(f.reset_touching(material_bit(1)), 0, "the mask was cleared");
    }

    #[test]
    fn a_texel_edit_restarts_only_the_pixels_whose_uv_box_reaches_it() {
        let mut f = Film::new(3, 1, 1);
        f.par_rows(|row| {
            for x in 0..3 {
                row.add(x, 0, DVec3::ONE);
                row.touch(x, material_bit(0));
                // Pixel x saw u in [x / 3, x / 3 + 0.1]; pixel 2 also a non-finite uv.
                row.reach(x, glam::DVec2::new(x as f64 / 3.0, 0.5));
                row.reach(x, glam::DVec2::new(x as f64 / 3.0 + 0.1, 0.5));
            }
            row.reach(2, glam::DVec2::new(f64::NAN, 0.5));
        });
        // An edit of u in [0.35, 0.4]: only pixel 1's box [1/3, 0.433] reaches it.
        let n = f.reset_reaching(material_bit(0), |b| b[0] <= 0.4 && b[2] >= 0.35);
        assert_eq!(n, 1);
        let img = f.resolve(&[DVec3::ONE]);
        assert_eq!(
            [img.get(0, 0)[0], img.get(1, 0)[0], img.get(2, 0)[0]],
            [1.0, 0.0, 1.0]
        );
        assert_eq!(
            f.reset_reaching(material_bit(0), |b| b[0] > b[2]),
            0,
            "boxes stay"
        );
    }

    #[test]
    fn long_accumulation_does_not_drift() {
        // 10^6 samples of 0.1 (not exact in binary): an f32 running sum would be off by
        // ~1e-2 relative; the f64 sum stays within 1e-9.
        let mut f = Film::new(1, 1, 1);
        f.par_rows(|row| {
            for _ in 0..1_000_000 {
                row.add(0, 0, DVec3::new(0.1, 1e-3, 10.0));
            }
        });
        let m = f.resolve(&[DVec3::ONE]).get(0, 0);
        assert!(
            (m[0] as f64 - 0.1).abs() < 1e-8 && (m[2] as f64 - 10.0).abs() < 1e-6,
            "{m:?}"
        );
    }
}
