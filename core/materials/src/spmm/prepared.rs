//! Evaluation data for one render: built from a material for the clusters the render
//! uses, the residual switched on or off and N_PCA limited, so a render holds (and a
//! GPU would upload) only what it evaluates. Its size is reported by `bytes()`. The
//! residual tables are re-laid out cell-major ([cluster][light][view][mean, b_1..b_K]
//! x RGB) so one interpolation cell is one contiguous read, padded to whole cache
//! lines where that costs little (`cell_stride`), in half floats when the pack's values
//! are half floats (`Precision`: the same values, half the cache lines per cell).
//! The cell sums that read them are in `cells.rs`, texel and basis sampling in
//! `sampling.rs`.

use std::sync::{Arc, OnceLock};

use glam::{DVec2, DVec3};

use super::directions::DirectionTable;
use super::eval::TexelGrid;
use super::{EvalSettings, Residual, SpmmMaterial};
use crate::brdf::BasisFunction;

mod cells;
mod sampling;
use cells::{TableValue, add_cells, add_half_cells};
pub use sampling::{DEFENSIVE_SHARE, defensive_pdf, defensive_sample};

/// What a render will evaluate.
#[derive(Clone, Debug, PartialEq)]
pub struct PrepareRequest {
    /// `used[c]`: some visible surface shows a texel of cluster `c`; `None` means all.
    pub used_clusters: Option<Vec<bool>>,
    pub residual: bool,
    pub max_npca: usize,
}

impl PrepareRequest {
    /// True if the render evaluates texels of cluster `c`.
    pub fn uses_cluster(&self, c: usize) -> bool {
        self.used_clusters
            .as_ref()
            .is_none_or(|u| u.get(c).copied().unwrap_or(false))
    }
}

/// Bytes held by each part of the prepared data.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
pub struct PreparedBytes {
    pub bases: usize,
    pub weights: usize,
    pub residual: usize,
}

impl PreparedBytes {
    pub fn total(&self) -> usize {
        self.bases + self.weights + self.residual
    }
}

/// The residual as a render evaluates it. A cluster's tables are laid out the first
/// time a texel of it is evaluated (or when `make_resident` asks), so a render holds
/// the tables of the clusters its rays reach; every evaluation sees the same values
/// whichever thread laid them out, so images do not depend on it.
struct PreparedResidual {
    source: Arc<Residual>,
    lights: DirectionTable,
    views: DirectionTable,
    /// Components kept (<= the pack's N_PCA).
    k: usize,
    precision: Precision,
    /// Per cluster: `None` when unused or hidden, else its tables once laid out,
    /// `[light][view][1 + k][3]` with the mean first, each cell `cell_stride(k, _)`
    /// values from the start of a cache line, in `precision`.
    clusters: Vec<Option<OnceLock<Box<[CacheLine]>>>>,
    /// [texel][k]: only the kept components.
    coefficients: Vec<f32>,
}

impl PreparedResidual {
    /// Cluster `c`'s tables, laid out now if no evaluation needed them before (one
    /// thread lays them out, others needing them wait; later reads are one atomic load).
    fn cluster_lines(&self, c: usize) -> Option<&[CacheLine]> {
        let slot = self.clusters.get(c)?.as_ref()?;
        Some(slot.get_or_init(|| self.lay_out(c)))
    }

    fn lay_out(&self, c: usize) -> Box<[CacheLine]> {
        let (nl, nv) = (self.source.light_dirs.len(), self.source.view_dirs.len());
        let lines = table_lines(nl * nv, self.k, self.precision);
        let mut lines = vec![bytemuck::Zeroable::zeroed(); lines];
        match self.precision {
            Precision::Single => self.fill::<f32>(c, bytemuck::cast_slice_mut(&mut lines)),
            Precision::Half => self.fill::<u16>(c, bytemuck::cast_slice_mut(&mut lines)),
        }
        lines.into_boxed_slice()
    }

    /// Writes cluster `c`'s cells into `cells`.
    fn fill<T: TableValue>(&self, c: usize, cells: &mut [T]) {
        let r = &self.source;
        let (nl, nv, npca) = (r.light_dirs.len(), r.view_dirs.len(), r.npca);
        let stride = cell_stride(self.k, self.precision);
        let put = |at: &mut [T], from: &[f32]| {
            for (a, &x) in at.iter_mut().zip(from) {
                *a = T::from_f32(x);
            }
        };
        for l in 0..nl {
            for v in 0..nv {
                let cell = &mut cells[(l * nv + v) * stride..];
                let m = ((c * nl + l) * nv + v) * 3;
                put(&mut cell[..3], &r.mean[m..m + 3]);
                for kk in 0..self.k {
                    let b = (((c * npca + kk) * nl + l) * nv + v) * 3;
                    put(&mut cell[3 + 3 * kk..6 + 3 * kk], &r.components[b..b + 3]);
                }
            }
        }
    }

    /// `rgb` plus the residual of one cluster's `lines` at the interpolation `cells`
    /// (start in values, weight) of a texel with coefficients `coef`.
    fn add(
        &self,
        rgb: DVec3,
        lines: &[CacheLine],
        cells: &[(usize, f64); 9],
        coef: &[f32],
    ) -> DVec3 {
        match self.precision {
            Precision::Single => add_cells(rgb, bytemuck::cast_slice(lines), cells, coef),
            Precision::Half => add_half_cells(rgb, bytemuck::cast_slice(lines), cells, coef),
        }
    }

    /// Every used cluster's cells, unpadded, in the tables' own precision (laid out
    /// now where no evaluation reached them), and per cluster the offset of its cells:
    /// what a device uploads.
    fn unpadded_cells(&self) -> (ResidualCells, Vec<Option<usize>>) {
        match self.precision {
            Precision::Single => {
                let (cells, offsets) = self.unpadded::<f32>();
                (ResidualCells::F32(cells), offsets)
            }
            Precision::Half => {
                let (bits, offsets) = self.unpadded::<u16>();
                let cells = bits.into_iter().map(half::f16::from_bits).collect();
                (ResidualCells::F16(cells), offsets)
            }
        }
    }

    fn unpadded<T: TableValue + bytemuck::Pod>(&self) -> (Vec<T>, Vec<Option<usize>>) {
        let (values, stride) = ((1 + self.k) * 3, cell_stride(self.k, self.precision));
        let count = self.lights.len() * self.views.len();
        let mut cells = Vec::new();
        let offsets = (0..self.clusters.len())
            .map(|c| {
                self.cluster_lines(c).map(|lines| {
                    let offset = cells.len();
                    let table: &[T] = bytemuck::cast_slice(lines);
                    for cell in table.chunks(stride).take(count) {
                        cells.extend_from_slice(&cell[..values]);
                    }
                    offset
                })
            })
            .collect();
        (cells, offsets)
    }

    /// Bytes held now: the laid-out clusters' tables and the coefficients.
    fn bytes(&self) -> usize {
        let cells: usize = self
            .clusters
            .iter()
            .flatten()
            .filter_map(OnceLock::get)
            .map(|c| size_of_val(&**c))
            .sum();
        cells + self.coefficients.len() * 4
    }
}

const LINE_BYTES: usize = 64;

/// 64 bytes on a 64-byte boundary: the residual tables' storage unit.
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
struct CacheLine([u8; LINE_BYTES]);

/// How prepared residual tables hold their values: as half floats when every value of
/// the pack's residual is one (packs are stored so by default), else as f32. Both give
/// the same values, so the same images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Precision {
    Half,
    Single,
}

impl Precision {
    fn of(material: &SpmmMaterial) -> Self {
        if material.residual_is_half() {
            Self::Half
        } else {
            Self::Single
        }
    }

    fn bytes(self) -> usize {
        match self {
            Self::Half => 2,
            Self::Single => 4,
        }
    }
}

/// Lines one cluster's table of `cells` cells with `k` components takes; in half
/// floats one more, so `add_half_cells_avx` may read a fourth half after the last.
fn table_lines(cells: usize, k: usize, p: Precision) -> usize {
    (cells * cell_stride(k, p) * p.bytes()).div_ceil(LINE_BYTES) + usize::from(p == Precision::Half)
}

/// Values from one residual cell to the next with `k` components in precision `p`: the
/// cell's `(1 + k) x 3` values, rounded up to whole cache lines when that adds at most a
/// quarter. A cell then starts on a line and touches the fewest lines (N_PCA 8 in f32:
/// 27 values padded to 32 read two lines, where unpadded two cells in three straddle
/// three; in halves one line); when rounding would cost more (N_PCA 5 in f32: 18 values
/// to 32) cells stay packed.
fn cell_stride(k: usize, p: Precision) -> usize {
    let values = (1 + k) * 3;
    let padded = values.next_multiple_of(LINE_BYTES / p.bytes());
    if 4 * padded <= 5 * values {
        padded
    } else {
        values
    }
}

/// A read-only view of prepared data, laid out as `PreparedSpmm` holds it.
pub struct PreparedParts<'a> {
    pub width: u32,
    pub height: u32,
    /// Per cluster, its basis functions.
    pub bases: &'a [Vec<BasisFunction>],
    pub texel_cluster: &'a [u32],
    /// Per texel, the start of its weights in `basis` and `rgb` (one more than texels).
    pub offsets: &'a [u32],
    pub basis: &'a [u16],
    pub rgb: &'a [[f32; 3]],
    pub residual: Option<PreparedResidualParts<'a>>,
    /// Per cluster and basis, the albedo that sets how often `sample_texel` draws it.
    pub basis_albedo: &'a [Vec<f64>],
}

/// The prepared residual: cell-major tables `[used cluster][light][view][1 + k][3]`,
/// every used cluster's laid out (`PreparedSpmm::parts` lays out what no ray reached).
pub struct PreparedResidualParts<'a> {
    pub lights: &'a DirectionTable,
    pub views: &'a DirectionTable,
    pub k: usize,
    /// Per cluster, the offset of its tables in `cells` (`None`: not prepared).
    pub cluster_offset: Vec<Option<usize>>,
    pub cells: ResidualCells,
    /// `[texel][k]`.
    pub coefficients: &'a [f32],
}

/// Residual cells as the prepared tables hold them: half floats when every value of
/// the pack's residual is one (a device may store them in 16 bits and read the same
/// values), else f32.
#[derive(Clone, Debug, PartialEq)]
pub enum ResidualCells {
    F32(Vec<f32>),
    F16(Vec<half::f16>),
}

impl ResidualCells {
    pub fn len(&self) -> usize {
        match self {
            Self::F32(v) => v.len(),
            Self::F16(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i`, widened to f32 (exact).
    pub fn value(&self, i: usize) -> f32 {
        match self {
            Self::F32(v) => v[i],
            Self::F16(v) => v[i].to_f32(),
        }
    }
}

/// Evaluation data of one material for one render.
pub struct PreparedSpmm {
    grid: TexelGrid,
    bases: Vec<Vec<BasisFunction>>,
    texel_cluster: Vec<u32>,
    offsets: Vec<u32>,
    basis: Vec<u16>,
    rgb: Vec<[f32; 3]>,
    /// Shared with the data prepared after a weight or dictionary edit that kept the
    /// residual (a brush stroke step re-lays out no tables).
    residual: Option<Arc<PreparedResidual>>,
    clusters_used: usize,
    /// Per cluster and basis, the albedo that sets how often sampling chooses it.
    basis_albedo: Vec<Vec<f64>>,
}

impl SpmmMaterial {
    /// Which clusters the given texels (row-major indices) belong to.
    pub fn clusters_of_texels(&self, texels: impl IntoIterator<Item = usize>) -> Vec<bool> {
        let mut used = vec![false; self.clusters().len()];
        for t in texels {
            if let Some(&c) = self.texel_cluster().get(t) {
                used[c as usize] = true;
            }
        }
        used
    }

    /// The weights as the view shows them: hidden (muted, or not soloed) bases' weights
    /// are zero, so evaluation needs no per-entry check.
    fn viewed_rgb(&self) -> Vec<[f32; 3]> {
        let view = self.view();
        let mut rgb = self.weights().rgb.clone();
        if view.is_empty() {
            return rgb;
        }
        let w = self.weights();
        for (t, &c) in self.texel_cluster().iter().enumerate() {
            let range = w.offsets[t] as usize..w.offsets[t + 1] as usize;
            for (v, &j) in rgb[range.clone()].iter_mut().zip(&w.basis[range]) {
                if !view.shows(c as usize, usize::from(j)) {
                    *v = [0.0; 3];
                }
            }
        }
        rgb
    }

    /// True if `prepare(request)` keeps residual tables.
    pub fn prepares_residual(&self, request: &PrepareRequest) -> bool {
        request.residual && self.residual().is_some() && self.residual_tables().is_some()
    }

    /// What `prepare(request).bytes()` will be, without preparing: what a render
    /// that prepared this material would hold.
    pub fn prepared_bytes(&self, request: &PrepareRequest) -> PreparedBytes {
        let used = |c: usize| request.uses_cluster(c);
        let w = self.weights();
        let weights = self.texel_cluster().len() * 4
            + w.offsets.len() * 4
            + w.basis.len() * 2
            + w.rgb.len() * 12;
        let bases = self
            .clusters()
            .iter()
            .map(|c| c.bases.len() * size_of::<BasisFunction>())
            .sum();
        let residual = match self.residual().filter(|_| self.prepares_residual(request)) {
            Some(r) => {
                let k = r.npca.min(request.max_npca);
                let clusters = (0..self.clusters().len())
                    .filter(|&c| used(c) && self.view().shows_residual(c))
                    .count();
                let lines = table_lines(
                    r.light_dirs.len() * r.view_dirs.len(),
                    k,
                    Precision::of(self),
                );
                let coefficients = r.coefficients.len() / r.npca.max(1) * k;
                clusters * lines * LINE_BYTES + coefficients * 4
            }
            None => 0,
        };
        PreparedBytes {
            bases,
            weights,
            residual,
        }
    }

    /// `prepare`, reusing the residual tables of `previous` (prepared with the same
    /// request from `before`) when this material has the same residual and shows it
    /// for the same clusters: what an edit of weights or bases leaves, so a stroke step
    /// copies only the weights.
    pub fn prepare_after_edit(
        &self,
        request: &PrepareRequest,
        before: &SpmmMaterial,
        previous: &PreparedSpmm,
    ) -> PreparedSpmm {
        let clusters = self.clusters().len();
        let same_residual = clusters == before.clusters().len()
            && self.texel_cluster().len() == before.texel_cluster().len()
            && (0..clusters)
                .all(|c| self.view().shows_residual(c) == before.view().shows_residual(c))
            && self.residual() == before.residual();
        if !same_residual {
            return self.prepare(request);
        }
        self.prepared_with(request, previous.residual.clone())
    }

    /// Builds the evaluation data a render with these settings needs. The residual's
    /// tables of a cluster are laid out when a texel of it is first evaluated.
    pub fn prepare(&self, request: &PrepareRequest) -> PreparedSpmm {
        let residual = match (
            request.residual,
            self.shared_residual(),
            self.residual_tables(),
        ) {
            (true, Some(r), Some((lights, views))) => {
                let k = r.npca.min(request.max_npca);
                let clusters = (0..self.clusters().len())
                    .map(|c| {
                        (request.uses_cluster(c) && self.view().shows_residual(c))
                            .then(OnceLock::new)
                    })
                    .collect();
                let coefficients = r
                    .coefficients
                    .chunks_exact(r.npca.max(1))
                    .flat_map(|row| &row[..k])
                    .copied()
                    .collect();
                Some(Arc::new(PreparedResidual {
                    source: Arc::clone(r),
                    lights: lights.clone(),
                    views: views.clone(),
                    k,
                    precision: Precision::of(self),
                    clusters,
                    coefficients,
                }))
            }
            _ => None,
        };
        self.prepared_with(request, residual)
    }

    fn prepared_with(
        &self,
        request: &PrepareRequest,
        residual: Option<Arc<PreparedResidual>>,
    ) -> PreparedSpmm {
        let used = |c: usize| {
            request
                .used_clusters
                .as_ref()
                .is_none_or(|u| u.get(c).copied().unwrap_or(false))
        };
        let bases: Vec<Vec<BasisFunction>> =
            self.clusters().iter().map(|c| c.bases.clone()).collect();
        PreparedSpmm {
            grid: TexelGrid::of(self),
            basis_albedo: sampling::basis_albedos(&bases),
            bases,
            texel_cluster: self.texel_cluster().to_vec(),
            offsets: self.weights().offsets.clone(),
            basis: self.weights().basis.clone(),
            rgb: self.viewed_rgb(),
            residual,
            clusters_used: (0..self.clusters().len()).filter(|&c| used(c)).count(),
        }
    }
}

impl PreparedSpmm {
    /// BTF(t, wi, wo), RGB, as `SpmmMaterial::eval_texel` with the prepared settings.
    /// Texels of clusters not marked used get no residual.
    pub fn eval_texel(&self, t: usize, wi: DVec3, wo: DVec3) -> DVec3 {
        self.eval_texel_parts(t, wi, wo, Some(usize::MAX))
    }

    /// As `eval_texel`, with the residual's mean and at most `components` of its
    /// prepared components (`None`: no residual). Fewer components read fewer lines of
    /// a cell and sum the same terms in the same order, so the value is what tables
    /// prepared with that many components give, bit for bit.
    fn eval_texel_parts(&self, t: usize, wi: DVec3, wo: DVec3, components: Option<usize>) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let c = self.texel_cluster[t] as usize;
        // The residual's nine cells lie far apart in a table of megabytes: ask for all
        // of them first, so their cache misses overlap with each other and with the
        // basis sum instead of queueing after it (same arithmetic, same order).
        let cells = match (&self.residual, components) {
            (Some(r), Some(components)) => r.cluster_lines(c).map(|lines| {
                let k = components.min(r.k);
                let (values, stride) = ((1 + k) * 3, cell_stride(r.k, r.precision));
                let nv = r.views.len();
                let (lw, vw) = (r.lights.cosine_weights(wi), r.views.weights(wo));
                let mut cells = [(0usize, 0.0f64); 9];
                let bytes: &[u8] = bytemuck::cast_slice(lines);
                let size = r.precision.bytes();
                for (i, cell) in cells.iter_mut().enumerate() {
                    let (l, v) = (lw[i / 3], vw[i % 3]);
                    let start = (l.0 as usize * nv + v.0 as usize) * stride;
                    *cell = (start, l.1 * v.1);
                    prefetch(&bytes[start * size..(start + values) * size]);
                }
                (r, lines, cells, k)
            }),
            _ => None,
        };
        let bases = &self.bases[c];
        let mut rgb = DVec3::ZERO;
        for i in self.offsets[t] as usize..self.offsets[t + 1] as usize {
            let w = self.rgb[i];
            rgb += DVec3::new(w[0] as f64, w[1] as f64, w[2] as f64)
                * bases[usize::from(self.basis[i])].eval(wi, wo);
        }
        match cells {
            Some((r, lines, cells, k)) => {
                let coef = &r.coefficients[t * r.k..t * r.k + k];
                r.add(rgb, lines, &cells, coef)
            }
            None => rgb,
        }
    }

    /// BTF at a surface UV position with the settings' filter and tiling: the residual
    /// with at most `s.max_npca` of the components `prepare` kept, or none when
    /// `s.residual` is false.
    pub fn eval_uv(&self, uv: DVec2, wi: DVec3, wo: DVec3, s: &EvalSettings) -> DVec3 {
        let components = s.residual.then_some(s.max_npca);
        self.grid
            .filter(uv, s, |t| self.eval_texel_parts(t, wi, wo, components))
    }

    /// Components the residual is prepared with (0 without a residual).
    pub fn prepared_npca(&self) -> usize {
        self.residual.as_ref().map_or(0, |r| r.k)
    }

    /// Lays out now the residual tables of the clusters whose texels an evaluation at
    /// `uv` reads (what a primary ray's hit will shade), so the first frame does not
    /// wait for them. Values are unchanged: only when the work is done.
    pub fn make_resident_at(&self, uv: DVec2, s: &EvalSettings) {
        if let (Some(r), true) = (&self.residual, s.residual) {
            self.grid.filter(uv, s, |t| {
                r.cluster_lines(self.texel_cluster[t] as usize);
                DVec3::ZERO
            });
        }
    }

    /// Lays out every used cluster's residual tables (what preparing up front held).
    pub fn make_all_resident(&self) {
        if let Some(r) = &self.residual {
            (0..r.clusters.len()).for_each(|c| {
                r.cluster_lines(c);
            });
        }
    }

    /// Whether residual tables were prepared.
    pub fn has_residual(&self) -> bool {
        self.residual.is_some()
    }

    /// Clusters whose residual tables were kept.
    pub fn clusters_used(&self) -> usize {
        self.clusters_used
    }

    /// The prepared arrays as they are, for a device that uploads them (`gpu`).
    pub fn parts(&self) -> PreparedParts<'_> {
        PreparedParts {
            width: self.grid.width,
            height: self.grid.height,
            bases: &self.bases,
            texel_cluster: &self.texel_cluster,
            offsets: &self.offsets,
            basis: &self.basis,
            rgb: &self.rgb,
            residual: self.residual.as_ref().map(|r| {
                let (cells, cluster_offset) = r.unpadded_cells();
                PreparedResidualParts {
                    lights: &r.lights,
                    views: &r.views,
                    k: r.k,
                    cluster_offset,
                    cells,
                    coefficients: &r.coefficients,
                }
            }),
            basis_albedo: &self.basis_albedo,
        }
    }

    /// Memory held now, by part (residual tables of clusters no evaluation reached yet
    /// are not held).
    pub fn bytes(&self) -> PreparedBytes {
        let bases = self
            .bases
            .iter()
            .map(|b| b.len() * size_of::<BasisFunction>())
            .sum();
        let weights = self.texel_cluster.len() * 4
            + self.offsets.len() * 4
            + self.basis.len() * 2
            + self.rgb.len() * 12;
        let residual = self.residual.as_ref().map_or(0, |r| r.bytes());
        PreparedBytes {
            bases,
            weights,
            residual,
        }
    }
}

/// Hints the cache to load every cache line of `data`; no effect on results. A
/// packed residual cell can straddle three lines, so asking for the first and last
/// alone left the middle one to miss. The hint is T1 (second-level cache): with T0
/// the profile showed the time at the prefetches themselves, and T1 ran the spmm
/// bench about 9% faster (T0 and NTA measured alternately; NTA was slower).
#[inline(always)]
fn prefetch(data: &[u8]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T1, _mm_prefetch};
        const LINE: usize = 64;
        let base = data.as_ptr().cast::<i8>();
        let misalign = base as usize % LINE;
        let first_line = base.wrapping_sub(misalign);
        for offset in (0..misalign + std::mem::size_of_val(data)).step_by(LINE) {
            // SAFETY: prefetching is a hint; it never faults, whatever the address.
            unsafe { _mm_prefetch::<_MM_HINT_T1>(first_line.wrapping_add(offset)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

#[cfg(test)]
mod tests;
