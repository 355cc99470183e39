//! The per-texel half of a fit: each texel's cluster (nearest centroid), its sparse
//! weights against that cluster's dictionary and its residual coefficients, from its
//! own values and the shared model only (`model.rs`). No texel's fit reads another's,
//! so texels may be fitted in any blocks, on any machine, in any order, and give the
//! same bits. `fit_range` streams a range of texels through blocks sized to the
//! memory budget.

use std::ops::Range;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use rayon::prelude::*;

use crate::model::Model;
use crate::{FitError, Progress, Stage, lasso};
use meso_materials::btf::texels::TexelSource;

/// One texel's fit: what the pack stores of it and what the report sums.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct TexelFit {
    pub cluster: u32,
    /// (basis in its cluster, RGB weight) as the pack stores them.
    pub weights: Vec<(u16, [f32; 3])>,
    /// Its coefficient on each of its cluster's components (the pack keeps them as f32).
    pub coefficients: Vec<f64>,
    /// Squared error of the basis sum alone.
    pub sse_basis: f64,
    /// Squared error with the cluster's residual mean (before any component).
    pub sse_mean: f64,
    /// Sum of the texel's values (the report's mean reflectance).
    pub value_sum: f64,
}

/// `row`'s values at the feature pairs (RGB), scaled to unit length: clusters group
/// apparent BRDFs of one shape, the weights carry brightness.
pub(crate) fn feature(row: &[f32], feature_pairs: &[usize], out: &mut [f32]) {
    for (o, &p) in out.chunks_exact_mut(3).zip(feature_pairs) {
        o.copy_from_slice(&row[p * 3..p * 3 + 3]);
    }
    let norm = out
        .iter()
        .map(|x| f64::from(*x).powi(2))
        .sum::<f64>()
        .sqrt();
    let scale = if norm > 0.0 { (1.0 / norm) as f32 } else { 0.0 };
    out.iter_mut().for_each(|x| *x *= scale);
}

/// The nearest of `k` centroids (the lowest index on a tie).
pub(crate) fn nearest(f: &[f32], centroids: &[f32], k: usize) -> usize {
    let dim = f.len();
    let mut best = (0, f64::INFINITY);
    for c in 0..k {
        let d: f64 = f
            .iter()
            .zip(&centroids[c * dim..(c + 1) * dim])
            .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
            .sum();
        if d < best.1 {
            best = (c, d);
        }
    }
    best.0
}

/// Reused buffers of one worker.
#[derive(Default)]
pub(crate) struct Scratch {
    feature: Vec<f32>,
    residual: Vec<f64>,
}

/// The sparse weights of `row` against cluster `c`'s dictionary at every pair, each
/// basis's weight capped.
pub(crate) fn weights(
    model: &Model,
    c: usize,
    row: &[f32],
    max_bases: usize,
) -> Vec<(usize, [f64; 3])> {
    let cols = &model.columns[model.first_col[c]..model.first_col[c + 1]];
    let b: Vec<[f64; 3]> = cols
        .iter()
        .map(|col| {
            let mut s = [0.0; 3];
            for (p, a) in col.iter().enumerate() {
                for (ch, sc) in s.iter_mut().enumerate() {
                    *sc += a * f64::from(row[p * 3 + ch]);
                }
            }
            s
        })
        .collect();
    lasso::texel_weights(
        &model.grams[c],
        &b,
        max_bases,
        &model.caps[model.first_col[c]..model.first_col[c + 1]],
    )
}

/// `row` minus the basis sum of weights `w` (cluster `c`), into `out`.
pub(crate) fn basis_residual(
    model: &Model,
    c: usize,
    row: &[f32],
    w: &[(usize, [f64; 3])],
    out: &mut [f64],
) {
    let cols = &model.columns[model.first_col[c]..model.first_col[c + 1]];
    for (o, v) in out.iter_mut().zip(row) {
        *o = f64::from(*v);
    }
    for &(j, wj) in w {
        for (p, a) in cols[j].iter().enumerate() {
            for ch in 0..3 {
                out[p * 3 + ch] -= wj[ch] * a;
            }
        }
    }
}

/// The fit of one texel with values `row`.
pub(crate) fn fit_texel(
    model: &Model,
    row: &[f32],
    max_bases: usize,
    scratch: &mut Scratch,
) -> TexelFit {
    let mut f = std::mem::take(&mut scratch.feature);
    f.resize(model.feature_pairs.len() * 3, 0.0);
    feature(row, &model.feature_pairs, &mut f);
    let c = nearest(&f, &model.centroids, model.k());
    scratch.feature = f;
    let w = weights(model, c, row, max_bases);
    let mut r = std::mem::take(&mut scratch.residual);
    r.resize(row.len(), 0.0);
    basis_residual(model, c, row, &w, &mut r);
    let sse_basis: f64 = r.iter().map(|x| x * x).sum();
    for (x, m) in r.iter_mut().zip(&model.means[c]) {
        *x -= m;
    }
    let sse_mean: f64 = r.iter().map(|x| x * x).sum();
    let coefficients = model.components[c]
        .iter()
        .map(|comp| comp.iter().zip(&r).map(|(a, b)| a * b).sum())
        .collect();
    scratch.residual = r;
    TexelFit {
        cluster: c as u32,
        weights: w
            .into_iter()
            .map(|(j, rgb)| (j as u16, rgb.map(|x| x as f32)))
            .collect(),
        coefficients,
        sse_basis,
        sse_mean,
        value_sum: row.iter().map(|&x| f64::from(x)).sum(),
    }
}

/// Fits texels `range` of `src`, reading `block` texels at a time (the block's fits run
/// on every thread); progress counts texels of the range.
pub(crate) fn fit_range(
    src: &dyn TexelSource,
    model: &Model,
    range: Range<usize>,
    block: usize,
    max_bases: usize,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Vec<TexelFit>, FitError> {
    let per = src.pairs() * 3;
    let total = range.len();
    let block = block.max(1);
    let mut buf = vec![0.0f32; block.min(total).max(1) * per];
    let mut fits = Vec::with_capacity(total);
    let done = AtomicUsize::new(0);
    let mut first = range.start;
    while first < range.end {
        if cancel.load(Ordering::Relaxed) {
            return Err(FitError::Cancelled);
        }
        let n = block.min(range.end - first);
        let rows = &mut buf[..n * per];
        src.read_texels(first, rows).map_err(FitError::Input)?;
        // Cancelling is seen per texel, not only between blocks (a block may be
        // thousands of texels).
        let part: Vec<Option<TexelFit>> = rows
            .par_chunks(per)
            .map_init(Scratch::default, |scratch, row| {
                if cancel.load(Ordering::Relaxed) {
                    return None;
                }
                let fit = fit_texel(model, row, max_bases, scratch);
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                if d.is_multiple_of(64) || d == total {
                    progress(Stage::Weights, d, total);
                }
                Some(fit)
            })
            .collect();
        if cancel.load(Ordering::Relaxed) {
            return Err(FitError::Cancelled);
        }
        fits.extend(part.into_iter().flatten());
        first += n;
    }
    Ok(fits)
}
