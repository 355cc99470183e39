//! The residual's cell sums, the innermost loop of an SPMM evaluation: per texel the
//! nine interpolation cells' `w * (mean + sum_k a_k b_k)`, portable and 4-wide (AVX,
//! F16C for half-float tables) with the same bits. Its own module: the unsafe SIMD
//! code and its contracts apart from the layout of the prepared tables.

use glam::DVec3;

/// `rgb` plus the residual's interpolation `cells` (start in `table`, weight) of a
/// texel with coefficients `coef`: per cell `w * (mean + sum_k a_k b_k)`, added in
/// this order channel by channel, in f64.
#[inline]
pub(super) fn add_cells(
    rgb: DVec3,
    table: &[f32],
    cells: &[(usize, f64); 9],
    coef: &[f32],
) -> DVec3 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX (checked above).
        return unsafe { add_cells_avx(rgb, table, cells, coef) };
    }
    add_cells_portable(rgb, table, cells, coef)
}

pub(super) fn add_cells_portable<T: TableValue>(
    mut rgb: DVec3,
    table: &[T],
    cells: &[(usize, f64); 9],
    coef: &[f32],
) -> DVec3 {
    let values = (1 + coef.len()) * 3;
    for &(start, w) in cells {
        if w == 0.0 {
            continue;
        }
        let cell = &table[start..][..values];
        let mut e = T::triple(cell);
        for (k, &a) in coef.iter().enumerate() {
            e += a as f64 * T::triple(&cell[3 + 3 * k..]);
        }
        rgb += w * e;
    }
    rgb
}

/// A value as a residual table stores it: an f32, or a half float's bits (only ever
/// made from values that are half floats exactly, so both widen back exactly).
pub(super) trait TableValue: Copy {
    fn from_f32(x: f32) -> Self;
    fn to_f32(self) -> f32;
    /// The first three values of `at`, widened to f64.
    fn triple(at: &[Self]) -> DVec3 {
        DVec3::from_array([0, 1, 2].map(|i| f64::from(at[i].to_f32())))
    }
}

impl TableValue for f32 {
    fn from_f32(x: f32) -> Self {
        x
    }
    fn to_f32(self) -> f32 {
        self
    }
}

impl TableValue for u16 {
    fn from_f32(x: f32) -> Self {
        half::f16::from_f32(x).to_bits()
    }
    fn to_f32(self) -> f32 {
        half::f16::from_bits(self).to_f32()
    }
}

/// `add_cells_portable` with the three channels in one 4-wide register: the same
/// multiplies and adds per channel in the same order (no fused multiply-add), so the
/// same bits, one instruction per step for the three channels.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
pub(super) fn add_cells_avx(
    rgb: DVec3,
    table: &[f32],
    cells: &[(usize, f64); 9],
    coef: &[f32],
) -> DVec3 {
    use std::arch::x86_64::{_mm_maskload_ps, _mm_setr_epi32, _mm256_cvtps_pd};
    // SAFETY: the load reads the first three floats at `from` (the fourth lane is masked
    // out, never read), so it reads no value past the triple.
    unsafe {
        sum_cells_avx(rgb, table, cells, coef, 0, |from: *const f32| {
            _mm256_cvtps_pd(_mm_maskload_ps(from, _mm_setr_epi32(-1, -1, -1, 0)))
        })
    }
}

/// Coefficients broadcast to 4-wide registers once per texel, before the cell loop (a
/// texel's nine cells use the same ones); components past this many are broadcast
/// where they are used.
#[cfg(target_arch = "x86_64")]
const HOISTED_COEFFICIENTS: usize = 16;

/// The 4-wide cell sum of both table kinds, given how to read a value triple into the
/// first three lanes (the fourth zero). The bounds are checked once per cell for all
/// of its reads, which are then plain loads (a check per read, and a broadcast of each
/// coefficient per cell, had cost about a tenth of the spmm bench's time).
///
/// # Safety
/// `load3(p)` may read at most `3 + over_read` values from `p` (which is then in bounds).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
unsafe fn sum_cells_avx<T>(
    rgb: DVec3,
    table: &[T],
    cells: &[(usize, f64); 9],
    coef: &[f32],
    over_read: usize,
    load3: impl Fn(*const T) -> std::arch::x86_64::__m256d,
) -> DVec3 {
    use std::arch::x86_64::{
        _mm256_add_pd, _mm256_mul_pd, _mm256_set1_pd, _mm256_setr_pd, _mm256_setzero_pd,
        _mm256_storeu_pd,
    };
    let values = (1 + coef.len()) * 3;
    let mut hoisted = [_mm256_setzero_pd(); HOISTED_COEFFICIENTS];
    for (slot, &a) in hoisted.iter_mut().zip(coef) {
        *slot = _mm256_set1_pd(f64::from(a));
    }
    let mut acc = _mm256_setr_pd(rgb.x, rgb.y, rgb.z, 0.0);
    // Three cells side by side (a light direction's three view cells): each cell's sum
    // is a chain of dependent adds, and three independent chains in one loop ran the
    // spmm bench 1.01-1.09x faster than one cell at a time. The adds into `acc` stay in
    // the cells' order, so the same bits.
    for group in cells.chunks_exact(3) {
        let cell: [*const T; 3] = std::array::from_fn(|i| {
            let start = group[i].0;
            // Every read of this cell lies in `table`: the last triple starts at
            // `start + values - 3` and `load3` reads at most `3 + over_read` from there.
            assert!(start + values + over_read <= table.len());
            table[start..].as_ptr()
        });
        // SAFETY: in bounds (asserted above), per `load3`'s contract.
        let mut e = cell.map(&load3);
        for (k, &a) in coef.iter().enumerate() {
            let a = match hoisted.get(k) {
                Some(&a) => a,
                None => _mm256_set1_pd(f64::from(a)),
            };
            for (e, cell) in e.iter_mut().zip(cell) {
                // SAFETY: as above: the triple at `3 + 3k` ends inside the cell.
                let b = load3(unsafe { cell.add(3 + 3 * k) });
                *e = _mm256_add_pd(*e, _mm256_mul_pd(a, b));
            }
        }
        // A cell of weight zero is read but not added, as the portable sum skips it.
        for (&(_, w), e) in group.iter().zip(e) {
            if w != 0.0 {
                acc = _mm256_add_pd(acc, _mm256_mul_pd(_mm256_set1_pd(w), e));
            }
        }
    }
    let mut out = [0.0; 4];
    // SAFETY: `out` holds four doubles.
    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), acc) };
    DVec3::new(out[0], out[1], out[2])
}

/// `add_cells` for tables of half floats: each value widened to f32 (exact) and then
/// to f64, as `add_cells` widens the same values held as f32, so the same bits.
#[inline]
pub(super) fn add_half_cells(
    rgb: DVec3,
    table: &[u16],
    cells: &[(usize, f64); 9],
    coef: &[f32],
) -> DVec3 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") && std::arch::is_x86_feature_detected!("f16c") {
        // SAFETY: the CPU has AVX and F16C (checked above).
        return unsafe { add_half_cells_avx(rgb, table, cells, coef) };
    }
    add_cells_portable(rgb, table, cells, coef)
}

/// `add_cells_portable` of half floats, 4-wide: each triple read as four halves (the
/// table ends with a spare line, so the read of the last cell's last triple stays inside
/// it), the fourth zeroed, converted by F16C; then `sum_cells_avx` as for f32 tables.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,f16c")]
pub(super) fn add_half_cells_avx(
    rgb: DVec3,
    table: &[u16],
    cells: &[(usize, f64); 9],
    coef: &[f32],
) -> DVec3 {
    use std::arch::x86_64::{
        __m128i, _mm_and_si128, _mm_cvtph_ps, _mm_loadl_epi64, _mm_set_epi64x, _mm256_cvtps_pd,
    };
    let low_three = _mm_set_epi64x(0, 0x0000_ffff_ffff_ffff);
    // SAFETY: the load reads four halves (eight bytes, no alignment needed) at `from`:
    // one value past the triple.
    unsafe {
        sum_cells_avx(rgb, table, cells, coef, 1, |from: *const u16| {
            let four = _mm_loadl_epi64(from.cast::<__m128i>());
            _mm256_cvtps_pd(_mm_cvtph_ps(_mm_and_si128(four, low_three)))
        })
    }
}
