//! A BTF ready to shade with (the scene's `btf` material): the reflectance of the
//! nearest texel (tiled like an SPMM pack), interpolated over the light and the view
//! direction sets exactly as an SPMM residual is (`spmm::directions`: each set
//! projected onto the unit disk, Delaunay-triangulated, barycentric weights in the
//! triangle holding the query's projection, the nearest hull point outside the hull),
//! so BTF(t, wi, wo) = sum_l sum_v w_l(wi) w_v(wo) table(t, l, v): at most 3 x 3 reads,
//! exact at tabulated pairs, continuous everywhere, values include the foreshortening
//! cosine like every SPMM basis. Values are held as f16 when that is lossless (every
//! value of the file is an f16, as `meso btf synth` writes them), halving the memory
//! (a 64x64 x 81x81 BTF: 161 MB instead of 322 MB); otherwise as f32.
//!
//! `BtfTable::open` reads a `.btf` within a memory bound: values that fit are held
//! whole, as `new` holds them; larger ones stay on disk and are read a block of rows
//! (one texel's values for one light) at a time through a bounded cache (`cache.rs`),
//! in the same precision, so both
//! shade bit-identically. Opening scans every value once either way (finite, and for
//! an F32 file whether all are f16), so a bad value is refused before shading starts.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec2, DVec3};
use half::f16;

use super::Btf;
use super::cache::{BLOCK_BYTES, Block, BlockCache, BlockSource, CacheShape};
use super::file::BtfFileError;
use super::lobe::{LobeSampler, PairSums};
use super::on_disk::OnDiskBtf;
use super::texels::TexelSource;
use crate::spmm::directions::{DirectionTable, DirectionTableError};
use crate::spmm::{DEFENSIVE_SHARE, TexelGrid, defensive_pdf, defensive_sample};

/// Precision the values are held in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Storage {
    F16,
    F32,
}

#[derive(Clone, Debug)]
enum Values {
    F16(Vec<f16>),
    F32(Vec<f32>),
    /// On disk, read through a bounded cache (values too large for the bound).
    Cached(Arc<BlockCache>),
}

/// One row of a texel's values (one light): `V * 3`, view-major, RGB.
enum TexelValues<'a> {
    F16(&'a [f16]),
    F32(&'a [f32]),
}

impl TexelValues<'_> {
    fn rgb(&self, i: usize) -> DVec3 {
        match self {
            TexelValues::F16(v) => DVec3::new(v[i].to_f64(), v[i + 1].to_f64(), v[i + 2].to_f64()),
            TexelValues::F32(v) => DVec3::new(v[i] as f64, v[i + 1] as f64, v[i + 2] as f64),
        }
    }
}

/// `BtfTable::open`'s default bound: 2 GiB (a 64x64 Bonn BTF, 161 MB, stays whole;
/// a 256x256 one, 2.6 GB as f16, is read on demand).
pub const DEFAULT_MAX_MEMORY: u64 = 2 << 30;
/// Bytes of values read at once while opening.
const SCAN_BYTES: usize = 16 << 20;

/// How much of a BTF's values `BtfTable::open` may hold: values up to `max_bytes`
/// (in the precision held) are held whole, larger ones through a cache of blocks of
/// about `block_bytes` whose resident blocks and those in flight in `threads`
/// shading workers (with the blocks' overhead and the index) stay within
/// `max_bytes`. Blocks smaller than a texel are runs of rows (one texel's values for
/// one light) where the source reads rows (a file), else one texel; larger ones are
/// whole texels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryBound {
    pub max_bytes: u64,
    pub block_bytes: u64,
    pub threads: usize,
}

impl MemoryBound {
    /// `max_bytes` with the default block size, for rayon's worker count.
    pub fn new(max_bytes: u64) -> Self {
        Self {
            max_bytes,
            block_bytes: BLOCK_BYTES,
            threads: rayon::current_num_threads(),
        }
    }
}

impl Default for MemoryBound {
    fn default() -> Self {
        Self::new(DEFAULT_MAX_MEMORY)
    }
}

/// Why `BtfTable::open` cannot shade a `.btf`: the file (naming it and the part), its
/// directions, or a bound too small for the cache.
#[derive(Debug, thiserror::Error)]
pub enum BtfOpenError {
    #[error(transparent)]
    File(#[from] BtfFileError),
    #[error("{}: {source}", path.display())]
    Table {
        path: PathBuf,
        source: BtfTableError,
    },
    #[error("{}: {problem}", path.display())]
    Memory { path: PathBuf, problem: String },
    /// A value the scan refused, as the reader names it (file and texel).
    #[error("{0}")]
    Values(String),
}

/// Why `BtfTable::from_source` cannot shade a source's values.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error(transparent)]
    Table(BtfTableError),
    #[error("{0}")]
    Values(String),
    #[error("{0}")]
    Memory(String),
}

/// Why a BTF cannot be shaded with.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum BtfTableError {
    #[error("{part}: {source} (a BTF needs at least 3 directions per set to interpolate)")]
    Directions {
        part: &'static str,
        source: DirectionTableError,
    },
}

/// A read-only view of a `BtfTable` (`BtfTable::parts`).
pub struct BtfTableParts<'a> {
    pub width: u32,
    pub height: u32,
    pub lights: &'a DirectionTable,
    pub views: &'a DirectionTable,
    pub values: BtfValues<'a>,
}

/// The values of a `BtfTableParts`, in the precision they are held in.
pub enum BtfValues<'a> {
    F16(&'a [f16]),
    F32(&'a [f32]),
}

/// A BTF prepared for shading: values, texel grid and the two interpolation tables.
#[derive(Clone, Debug)]
pub struct BtfTable {
    name: String,
    /// The file opened (`open`); None when built from a `Btf` in memory.
    path: Option<PathBuf>,
    grid: TexelGrid,
    lights: DirectionTable,
    views: DirectionTable,
    light_dirs: Vec<DVec3>,
    view_dirs: Vec<DVec3>,
    values: Values,
    /// Draws light directions from the texel-mean lobe (`lobe.rs`).
    lobe: LobeSampler,
}

impl BtfTable {
    /// Builds the interpolation tables; values become f16 when every one is exactly
    /// an f16 (no value changes), else stay f32.
    pub fn new(btf: &Btf) -> Result<Self, BtfTableError> {
        let table = |part, dirs: &[DVec3]| {
            DirectionTable::new(dirs).map_err(|source| BtfTableError::Directions { part, source })
        };
        let lights = table("light_dirs", btf.light_dirs())?;
        let views = table("view_dirs", btf.view_dirs())?;
        let lossless = btf.data().iter().all(|&x| f16::from_f32(x).to_f32() == x);
        let mut sums = PairSums::new(btf.light_dirs().len() * btf.view_dirs().len());
        sums.add(btf.data());
        let lobe = LobeSampler::new(&lights, btf.view_dirs().len(), &sums);
        let values = if lossless {
            Values::F16(btf.data().iter().map(|&x| f16::from_f32(x)).collect())
        } else {
            Values::F32(btf.data().to_vec())
        };
        Ok(Self {
            name: btf.name().to_string(),
            path: None,
            grid: TexelGrid {
                width: btf.width(),
                height: btf.height(),
            },
            lights,
            views,
            light_dirs: btf.light_dirs().to_vec(),
            view_dirs: btf.view_dirs().to_vec(),
            values,
            lobe,
        })
    }

    /// Opens `path` within `bound` (see the module comment): the values held whole
    /// when they fit, else read through a cache; the same values either way.
    pub fn open(path: &Path, bound: MemoryBound) -> Result<Self, BtfOpenError> {
        let disk = OnDiskBtf::open(path)?;
        let mut table = Self::from_source(Box::new(disk), bound).map_err(|e| match e {
            SourceError::Table(source) => BtfOpenError::Table {
                path: path.to_path_buf(),
                source,
            },
            // The on-disk reader's messages name the file and the texel.
            SourceError::Values(problem) => BtfOpenError::Values(problem),
            SourceError::Memory(problem) => BtfOpenError::Memory {
                path: path.to_path_buf(),
                problem,
            },
        })?;
        table.path = Some(path.to_path_buf());
        Ok(table)
    }

    /// A table of `source`'s values within `bound`, as `open` makes of a file:
    /// every value read once to check it and choose f16 or f32 as `new` does, then
    /// held whole if it fits, else read again block by block as shaded.
    pub fn from_source(source: BlockSource, bound: MemoryBound) -> Result<Self, SourceError> {
        let table = |part, dirs: &[DVec3]| {
            DirectionTable::new(dirs)
                .map_err(|source| SourceError::Table(BtfTableError::Directions { part, source }))
        };
        let lights = table("light_dirs", source.light_dirs())?;
        let views = table("view_dirs", source.view_dirs())?;
        let name = source.name().to_string();
        let grid = TexelGrid {
            width: source.width(),
            height: source.height(),
        };
        let (light_dirs, view_dirs) = (source.light_dirs().to_vec(), source.view_dirs().to_vec());
        let per_texel = source.pairs() * 3;
        let count = source.texels() * per_texel;
        let chunk = (SCAN_BYTES / (per_texel * 4)).max(1);
        let f32_bytes = count as u64 * 4;
        // The texel-mean lobe, summed in each branch's first read.
        let mut sums = PairSums::new(source.pairs());
        let values = if source.values_are_f16() && count as u64 * 2 <= bound.max_bytes {
            // Values that are f16 already (an F16 file): held as f16, read once.
            let mut halves: Vec<f16> = Vec::with_capacity(count);
            Self::for_blocks(&*source, chunk, |block| {
                sums.add(block);
                halves.extend(block.iter().map(|&x| f16::from_f32(x)));
            })?;
            Values::F16(halves)
        } else if !source.values_are_f16() && f32_bytes <= bound.max_bytes {
            // Read once (a computed source is costly to read twice); when every value
            // is an f16 the f32 copy briefly sits beside the f16 one (1.5 times the
            // values, within 1.5 times the bound).
            let mut values = Vec::with_capacity(count);
            Self::for_blocks(&*source, chunk, |block| {
                sums.add(block);
                values.extend_from_slice(block);
            })?;
            if values.iter().all(|&x| f16::from_f32(x).to_f32() == x) {
                Values::F16(values.iter().map(|&x| f16::from_f32(x)).collect())
            } else {
                Values::F32(values)
            }
        } else {
            // Out of core. The scan reads every value once (the source checks each
            // finite) and, unless they are known f16, finds whether all are.
            let mut lossless = true;
            Self::for_blocks(&*source, chunk, |block| {
                sums.add(block);
                if lossless && !source.values_are_f16() {
                    lossless = block.iter().all(|&x| f16::from_f32(x).to_f32() == x);
                }
            })?;
            let (storage, size) = if lossless {
                (Storage::F16, 2)
            } else {
                (Storage::F32, 4)
            };
            if count as u64 * size <= bound.max_bytes {
                // All f16 after all, and they fit as such: held whole.
                let mut halves: Vec<f16> = Vec::with_capacity(count);
                Self::for_blocks(&*source, chunk, |block| {
                    halves.extend(block.iter().map(|&x| f16::from_f32(x)));
                })?;
                Values::F16(halves)
            } else {
                // Blocks of rows where the source reads rows (a file) and blocks smaller
                // than a texel are asked for, else whole texels.
                let lights = source.light_dirs().len();
                let shape = CacheShape::fit(
                    (source.view_dirs().len() * 3) as u64 * size,
                    if source.reads_rows() && bound.block_bytes < per_texel as u64 * size {
                        1
                    } else {
                        lights
                    },
                    source.texels() * lights,
                    bound.max_bytes,
                    bound.block_bytes,
                    bound.threads,
                )
                .map_err(|problem| {
                    SourceError::Memory(format!(
                        "its {} bytes of values exceed the memory bound, and {problem}",
                        count as u64 * size
                    ))
                })?;
                Values::Cached(Arc::new(BlockCache::new(
                    source,
                    storage,
                    shape,
                    bound.threads,
                )))
            }
        };
        let lobe = LobeSampler::new(&lights, view_dirs.len(), &sums);
        Ok(Self {
            name,
            path: None,
            grid,
            lights,
            views,
            light_dirs,
            view_dirs,
            values,
            lobe,
        })
    }

    /// Reads every texel of `source` in order, `chunk` texels at a time.
    fn for_blocks(
        source: &dyn TexelSource,
        chunk: usize,
        mut f: impl FnMut(&[f32]),
    ) -> Result<(), SourceError> {
        let per_texel = source.pairs() * 3;
        let mut buf = vec![0.0f32; chunk.min(source.texels()) * per_texel];
        for first in (0..source.texels()).step_by(chunk) {
            let n = chunk.min(source.texels() - first);
            let block = &mut buf[..n * per_texel];
            source
                .read_texels(first, block)
                .map_err(SourceError::Values)?;
            f(block);
        }
        Ok(())
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    /// The file it was opened from, if any.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }
    /// Whether every value is held in memory (else read through a cache).
    pub fn is_resident(&self) -> bool {
        !matches!(self.values, Values::Cached(_))
    }
    /// The cache an out-of-core table reads through.
    pub fn cache(&self) -> Option<&BlockCache> {
        match &self.values {
            Values::Cached(c) => Some(c),
            _ => None,
        }
    }
    /// The first block that could not be read while shading (the file changed after
    /// opening): its texels shaded as 0, so a render that used it is wrong.
    pub fn read_error(&self) -> Option<&str> {
        self.cache().and_then(BlockCache::error)
    }
    pub fn width(&self) -> u32 {
        self.grid.width
    }
    pub fn height(&self) -> u32 {
        self.grid.height
    }
    pub fn light_dirs(&self) -> &[DVec3] {
        &self.light_dirs
    }
    pub fn view_dirs(&self) -> &[DVec3] {
        &self.view_dirs
    }
    pub fn storage(&self) -> Storage {
        match &self.values {
            Values::F16(_) => Storage::F16,
            Values::F32(_) => Storage::F32,
            Values::Cached(c) => c.storage(),
        }
    }
    /// Bytes of the values held in memory: all of them, or at most the cache's bound.
    pub fn bytes(&self) -> usize {
        match &self.values {
            Values::F16(v) => v.len() * 2,
            Values::F32(v) => v.len() * 4,
            Values::Cached(c) => c.bytes() as usize,
        }
    }
    /// Bytes of all the values in the precision held, resident or not.
    pub fn value_bytes(&self) -> u64 {
        let n = self.grid.width as u64 * self.grid.height as u64;
        let size = match self.storage() {
            Storage::F16 => 2,
            Storage::F32 => 4,
        };
        n * (self.lights.len() * self.views.len() * 3) as u64 * size
    }

    /// BTF(t, wi, wo), RGB, for texel `t` (row-major), unit `wi`, `wo` in the tangent
    /// frame; 0 unless both lie above the surface.
    ///
    /// One routine for every way the values are held, so they shade bit-identically:
    /// each light of the interpolation reads its row of the texel (`V * 3` values),
    /// from memory or through the cache (at most 3 rows, not the whole texel).
    pub fn eval_texel(&self, t: usize, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let (nl, nv) = (self.lights.len(), self.views.len());
        let row_len = nv * 3;
        let vw = self.views.weights(wo);
        let mut rgb = DVec3::ZERO;
        for (l, wl) in self.lights.cosine_weights(wi) {
            if wl == 0.0 {
                continue;
            }
            let row = t * nl + l as usize;
            let held;
            let values = match &self.values {
                Values::F16(v) => TexelValues::F16(&v[row * row_len..][..row_len]),
                Values::F32(v) => TexelValues::F32(&v[row * row_len..][..row_len]),
                Values::Cached(c) => match c.row(row) {
                    Some((block, at)) => {
                        held = block;
                        match &*held {
                            Block::F16(v) => TexelValues::F16(&v[at..][..row_len]),
                            Block::F32(v) => TexelValues::F32(&v[at..][..row_len]),
                        }
                    }
                    // Unreadable (kept in `read_error`, which the renderer reports).
                    None => return DVec3::ZERO,
                },
            };
            for &(v, wv) in &vw {
                let w = wl * wv;
                if w != 0.0 {
                    rgb += w * values.rgb(v as usize * 3);
                }
            }
        }
        rgb
    }

    /// A light direction drawn for view `wo` (tangent frame) from two uniform numbers,
    /// and its solid-angle pdf (`pdf`): with `DEFENSIVE_SHARE` the defensive mixture,
    /// else the texel-mean lobe of `wo` (`lobe.rs`); the first number picks and,
    /// rescaled, drives the strategy. `None` for a view below the surface (the BTF is 0
    /// there) or a direction on the horizon.
    pub fn sample(&self, wo: DVec3, u: DVec2) -> Option<(DVec3, f64)> {
        if wo.z.is_nan() || wo.z <= 0.0 {
            return None;
        }
        let view = self.views.weights(wo);
        let wi = if u.x < DEFENSIVE_SHARE {
            defensive_sample(DVec2::new(u.x / DEFENSIVE_SHARE, u.y))
        } else {
            let x = (u.x - DEFENSIVE_SHARE) / (1.0 - DEFENSIVE_SHARE);
            self.lobe.sample(view, DVec2::new(x, u.y))?
        };
        let pdf = self.mixture_pdf(wi, view);
        (wi.z > 0.0 && pdf > 0.0).then_some((wi, pdf))
    }

    /// The pdf with which `sample` draws `wi` for `wo` (0 below the surface).
    pub fn pdf(&self, wi: DVec3, wo: DVec3) -> f64 {
        if wo.z.is_nan() || wo.z <= 0.0 {
            return 0.0;
        }
        self.mixture_pdf(wi, self.views.weights(wo))
    }

    /// `pdf` for a view with interpolation weights `view`.
    fn mixture_pdf(&self, wi: DVec3, view: [(u32, f64); 3]) -> f64 {
        DEFENSIVE_SHARE * defensive_pdf(wi) + (1.0 - DEFENSIVE_SHARE) * self.lobe.pdf(view, wi)
    }

    /// The lobe sampler (for a device that uploads it).
    pub fn lobe(&self) -> &LobeSampler {
        &self.lobe
    }

    /// BTF at a surface UV position: nearest texel after tiling by `uv_scale`
    /// (wrapping, row 0 at the top, as SPMM packs); 0 for a non-finite UV.
    pub fn eval_uv(&self, uv: DVec2, uv_scale: DVec2, wi: DVec3, wo: DVec3) -> DVec3 {
        if !uv.is_finite() {
            return DVec3::ZERO;
        }
        self.eval_texel(self.grid.nearest(uv, uv_scale), wi, wo)
    }

    /// The tables and values as they are held, for a device that uploads them
    /// (`gpu`): the texel grid, the light and view interpolation tables, and the
    /// values `[texel][light][view][rgb]` as f16 bits or f32; None when the values
    /// are not held in memory (`is_resident`).
    pub fn parts(&self) -> Option<BtfTableParts<'_>> {
        Some(BtfTableParts {
            width: self.grid.width,
            height: self.grid.height,
            lights: &self.lights,
            views: &self.views,
            values: match &self.values {
                Values::F16(v) => BtfValues::F16(v),
                Values::F32(v) => BtfValues::F32(v),
                Values::Cached(_) => return None,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;
    use crate::btf::directions::{Layout, bonn81, rings};
    use crate::rng::SampleStream;

    /// A 2x1 BTF: texel 0 is Lambertian `albedo / pi * cos_i`, texel 1 is
    /// twice that, on the given direction set (same for light and view).
    fn lambertian_btf(dirs: Vec<DVec3>, albedo: f64) -> Btf {
        let mut data = Vec::new();
        for t in 0..2 {
            for l in &dirs {
                for _ in &dirs {
                    let f = (t + 1) as f64 * albedo / PI * l.z;
                    data.extend([f as f32, (0.5 * f) as f32, (0.25 * f) as f32]);
                }
            }
        }
        Btf::new(
            "lambert".into(),
            "test".into(),
            2,
            1,
            dirs.clone(),
            dirs,
            data,
        )
        .expect("valid BTF")
    }

    #[test]
    fn exact_at_tabulated_pairs_and_zero_below_the_surface() {
        let dirs = bonn81();
        let btf = lambertian_btf(dirs.clone(), 0.8);
        let table = BtfTable::new(&btf).expect("shadeable");
        for t in 0..2 {
            for (l, wl) in dirs.iter().enumerate().step_by(7) {
                for (v, wv) in dirs.iter().enumerate().step_by(5) {
                    let got = table.eval_texel(t, *wl, *wv);
                    let want = btf.value(t, l, v);
                    for c in 0..3 {
                        assert_eq!(got[c] as f32, want[c], "t {t} l {l} v {v}");
                    }
                }
            }
        }
        let below = DVec3::new(0.0, 0.6, -0.8);
        assert_eq!(table.eval_texel(0, below, DVec3::Z), DVec3::ZERO);
        assert_eq!(table.eval_texel(0, DVec3::Z, below), DVec3::ZERO);
    }

    /// Interpolating value / cos theta_l on the light side makes a Lambertian table
    /// the Lambertian BRDF everywhere, up to its f32 storage: between the rings
    /// (where interpolating the value itself is off by the cosine's curvature) and
    /// beyond the Bonn set's last ring at 75 degrees, down to the horizon (where it
    /// held the ring's value, up to 15 times too bright at 89 degrees).
    #[test]
    fn a_lambertian_btf_is_the_lambertian_brdf_over_the_whole_hemisphere() {
        // Both of Bonn's layouts: UBO2003's 81 directions and UBO2014's 151, whose
        // last ring is at 75 degrees too.
        for layout in Layout::ALL {
            lambertian_over_the_hemisphere(layout.directions());
        }
    }

    fn lambertian_over_the_hemisphere(dirs: Vec<DVec3>) {
        let albedo = 0.8;
        let btf = lambertian_btf(dirs, albedo);
        let table = BtfTable::new(&btf).expect("shadeable");
        let mut beyond = 0;
        for k in 0..4000u64 {
            let mut s = SampleStream::new(&[41, k]);
            // Uniform in cos theta_i: a quarter of the lights lie beyond 75 degrees.
            let wi = crate::brdf::warp::spherical(s.next().max(1e-6), 2.0 * PI * s.next());
            let wo = crate::brdf::warp::spherical(0.2 + 0.8 * s.next(), 2.0 * PI * s.next());
            let got = table.eval_texel(1, wi, wo);
            let want = 2.0 * albedo / PI * wi.z;
            // The table's f32 storage: 2^-24 relative, with margin for the f64 arithmetic.
            assert!(
                (got.x - want).abs() <= want * 2e-7,
                "wi {wi}: {} vs {want}",
                got.x
            );
            assert!((got.y - 0.5 * got.x).abs() <= 1e-7 * want);
            assert!((got.z - 0.25 * got.x).abs() <= 1e-7 * want);
            // The view does not matter for a Lambertian table.
            let other = table.eval_texel(1, wi, DVec3::Z);
            assert!((other.x - got.x).abs() <= 1e-7 * want);
            beyond += usize::from(wi.z < 75f64.to_radians().cos());
        }
        assert!(beyond > 500, "{beyond} lights beyond the last ring");
    }

    #[test]
    fn tiles_like_an_spmm_pack_and_stores_f16_only_when_lossless() {
        let btf = lambertian_btf(bonn81(), 0.5);
        let table = BtfTable::new(&btf).expect("shadeable");
        // 0.5/pi * z is not an f16 in general: kept as f32.
        assert_eq!(table.storage(), Storage::F32);
        assert_eq!(table.bytes(), btf.data().len() * 4);
        // u in [0, 0.5) is texel 0, [0.5, 1) texel 1; uv_scale 2 repeats it twice.
        let (wi, wo) = (DVec3::Z, DVec3::Z);
        let t0 = table.eval_uv(DVec2::new(0.2, 0.5), DVec2::ONE, wi, wo);
        let t1 = table.eval_uv(DVec2::new(0.7, 0.5), DVec2::ONE, wi, wo);
        assert!((t1.x - 2.0 * t0.x).abs() < 1e-6);
        let tiled = table.eval_uv(DVec2::new(0.3, 0.5), DVec2::splat(2.0), wi, wo);
        assert_eq!(tiled, t1);
        let wrapped = table.eval_uv(DVec2::new(-0.8, 3.5), DVec2::ONE, wi, wo);
        assert_eq!(wrapped, t0);
        assert_eq!(
            table.eval_uv(DVec2::new(f64::NAN, 0.0), DVec2::ONE, wi, wo),
            DVec3::ZERO
        );
        // Values that are f16 already are held as f16, unchanged.
        let dirs = bonn81();
        let n = 2 * dirs.len() * dirs.len() * 3;
        let data: Vec<f32> = (0..n)
            .map(|i| half::f16::from_f32(0.001 * (i % 977) as f32).to_f32())
            .collect();
        let halves = Btf::new(
            "h".into(),
            "t".into(),
            2,
            1,
            dirs.clone(),
            dirs.clone(),
            data,
        )
        .expect("valid");
        let table = BtfTable::new(&halves).expect("shadeable");
        assert_eq!(table.storage(), Storage::F16);
        assert_eq!(table.bytes(), n * 2);
        assert_eq!(
            table
                .eval_texel(1, dirs[30], dirs[60])
                .to_array()
                .map(|x| x as f32),
            halves.value(1, 30, 60)
        );
    }

    #[test]
    fn too_few_directions_are_refused_naming_the_set() {
        let few = rings(&[(0.0, 1), (30.0, 2)]);
        let btf = Btf::new(
            "few".into(),
            "t".into(),
            1,
            1,
            few.clone(),
            bonn81(),
            vec![0.1; few.len() * 81 * 3],
        )
        .expect("a valid BTF");
        let e = BtfTable::new(&btf).expect_err("cannot interpolate 3 collinear lights");
        assert!(e.to_string().starts_with("light_dirs:"), "{e}");
    }
}
