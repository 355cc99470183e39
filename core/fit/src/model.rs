//! The shared half of a fit, found on a seeded sample of texels only: the texel
//! clusters (k-means centroids), each cluster's dictionary, the design the weights are
//! solved against with each basis's weight cap, and each cluster's residual mean and
//! principal components. Every shard of a split fit computes this same model from the
//! same sample (nothing here depends on which texels a shard fits, on `--max-memory`
//! or on the thread count), so the per-texel fits (`texel_fit.rs`) that follow are
//! the same numbers whether one process fits every texel or N processes a part each.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::DVec3;
use nalgebra::DMatrix;
use rayon::prelude::*;

use crate::dictionary::{self, Pairs};
use crate::texel_fit;
use crate::{FitError, FitSettings, Progress, Stage, kmeans, residual};
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use meso_materials::btf::texels::TexelSource;
use meso_materials::hash::Fnv1a;
use meso_materials::rng::SampleStream;
use meso_materials::spmm::{Cluster, lobe_bound};

/// A seeded permutation of 0..n (Fisher-Yates on `SampleStream`), `tag` telling the
/// uses apart.
pub(crate) fn permutation(n: usize, seed: u64, tag: u64) -> Vec<usize> {
    let mut p: Vec<usize> = (0..n).collect();
    let s = SampleStream::new(&[seed, tag]);
    for i in (1..n).rev() {
        let j = ((s.at(i as u64) * (i + 1) as f64) as usize).min(i);
        p.swap(i, j);
    }
    p
}

/// The pair permutation's tag (the one the fitter has always used for pairs).
const PAIRS_TAG: u64 = 0x7065_726d;
/// The texel sample's tag.
const TEXELS_TAG: u64 = 0x7465_786c;

/// What every texel's fit is solved against.
#[derive(Clone, Debug)]
pub(crate) struct Model {
    /// Direction pairs of the clustering features, ascending.
    pub feature_pairs: Vec<usize>,
    /// Centroids of the texel clusters (`k x 3 * feature_pairs`), unit-length features.
    pub centroids: Vec<f32>,
    pub clusters: Vec<Cluster>,
    /// Per basis (cluster by cluster) its values at every pair.
    pub columns: Vec<Vec<f64>>,
    /// Start of each cluster's bases in `columns`, and one past the last.
    pub first_col: Vec<usize>,
    /// Per cluster the Gram matrix of its bases.
    pub grams: Vec<DMatrix<f64>>,
    /// Per basis its largest allowed weight (the lobe bound's hemisphere check).
    pub caps: Vec<f64>,
    /// Per basis its peak over the hemisphere.
    pub peaks: Vec<f64>,
    /// Per cluster its residual mean (`L * V * 3` values).
    pub means: Vec<Vec<f64>>,
    /// Per cluster its orthonormal components (at most N_PCA).
    pub components: Vec<Vec<Vec<f64>>>,
    /// Hash of the input as the sample saw it (grid, directions, the sample's values).
    pub input_hash: u64,
    /// Seconds of the clustering, dictionary and residual stages.
    pub seconds: [f64; 3],
}

impl Model {
    pub fn k(&self) -> usize {
        self.clusters.len()
    }

    /// A hash of every number the texel fits use: parts fitted against different
    /// models must not be merged.
    pub fn hash(&self) -> u64 {
        let mut h = Fnv1a::default();
        h.word(self.input_hash);
        let f64s = |h: &mut Fnv1a, v: &[f64]| v.iter().for_each(|x| h.word(x.to_bits()));
        h.word(self.feature_pairs.len() as u64);
        self.feature_pairs.iter().for_each(|&p| h.word(p as u64));
        self.centroids
            .iter()
            .for_each(|x| h.word(u64::from(x.to_bits())));
        for c in &self.clusters {
            h.word(c.bases.len() as u64);
            for b in &c.bases {
                h.word(u64::from(meso_materials::spmm::pack::model_id(
                    b.brdf().model(),
                )));
                f64s(&mut h, &b.brdf().param_values());
                f64s(&mut h, &b.normal().to_array());
            }
        }
        f64s(&mut h, &self.caps);
        for (m, comps) in self.means.iter().zip(&self.components) {
            f64s(&mut h, m);
            h.word(comps.len() as u64);
            comps.iter().for_each(|c| f64s(&mut h, c));
        }
        h.finish()
    }
}

/// The light and view direction of direction pair `p`.
pub(crate) fn pair_dirs(src: &dyn TexelSource, p: usize) -> (DVec3, DVec3) {
    let nv = src.view_dirs().len();
    (src.light_dirs()[p / nv], src.view_dirs()[p % nv])
}

/// Reads `texels` (ascending) into `out` (`texels.len()` texels), a run of consecutive
/// texels per read.
fn read_into(src: &dyn TexelSource, texels: &[usize], out: &mut [f32]) -> Result<(), FitError> {
    let per = src.pairs() * 3;
    let mut i = 0;
    while i < texels.len() {
        let mut n = 1;
        while i + n < texels.len() && texels[i + n] == texels[i] + n {
            n += 1;
        }
        src.read_texels(texels[i], &mut out[i * per..(i + n) * per])
            .map_err(FitError::Input)?;
        i += n;
    }
    Ok(())
}

/// Calls `f(i, texel values)` for each of `texels` (ascending), reading up to `block`
/// texels at a time.
pub(crate) fn for_each_texel(
    src: &dyn TexelSource,
    texels: &[usize],
    block: usize,
    mut f: impl FnMut(usize, &[f32]),
) -> Result<(), FitError> {
    let per = src.pairs() * 3;
    let block = block.max(1);
    let mut buf = vec![0.0f32; block.min(texels.len()) * per];
    for (g, group) in texels.chunks(block).enumerate() {
        let rows = &mut buf[..group.len() * per];
        read_into(src, group, rows)?;
        for (j, row) in rows.chunks_exact(per).enumerate() {
            f(g * block + j, row);
        }
    }
    Ok(())
}

/// The model of `src`'s seeded texel sample. `block` bounds the texels read at once.
pub(crate) fn fit_model(
    src: &dyn TexelSource,
    settings: &FitSettings,
    block: usize,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Model, FitError> {
    let cancelled = || cancel.load(Ordering::Relaxed);
    let t0 = std::time::Instant::now();
    let m = src.pairs();
    let texels = src.texels();
    let order = permutation(m, settings.seed, PAIRS_TAG);
    let mut feature_pairs: Vec<usize> = order[..settings.feature_pairs.min(m)].to_vec();
    feature_pairs.sort_unstable();
    let mut fit_pairs: Vec<usize> = order[..settings.fit_pairs.min(m)].to_vec();
    fit_pairs.sort_unstable();
    let sample = sample_of(texels, settings);
    let sample_texels: Vec<usize> = sample.iter().map(|s| s.0).collect();

    // 1. Features of the sample, its brightest value and the input's hash.
    progress(Stage::Clustering, 0, 1);
    let dim = feature_pairs.len() * 3;
    let mut features = vec![0.0f32; sample.len() * dim];
    let mut reference = 0.0f64;
    let mut h = input_hasher(src);
    for_each_texel(src, &sample_texels, block, |i, row| {
        texel_fit::feature(row, &feature_pairs, &mut features[i * dim..(i + 1) * dim]);
        for x in row {
            h.bytes(&x.to_le_bytes());
            reference = reference.max(f64::from(*x));
        }
    })?;
    let clustering = kmeans::kmeans(&features, dim, settings.clusters, settings.seed, 60);
    let centroids = clustering.centroids;
    let k = clustering.k;
    // Each sample texel's cluster is its nearest centroid, the rule every texel's fit
    // uses (not the k-means labels of the last iteration, which may lag a centroid).
    let label: Vec<usize> = (0..sample.len())
        .into_par_iter()
        .map(|i| texel_fit::nearest(&features[i * dim..(i + 1) * dim], &centroids, k))
        .collect();
    let members: Vec<Vec<usize>> = (0..k)
        .map(|c| (0..sample.len()).filter(|&i| label[i] == c).collect())
        .collect();
    progress(Stage::Clustering, 1, 1);
    if cancelled() {
        return Err(FitError::Cancelled);
    }
    let s_cluster = t0.elapsed().as_secs_f64();

    // 2. Representatives: each cluster's sample texels k-means'd again; a group's mean
    // (mono) at the fit pairs is fitted with bases. A cluster no sample texel is
    // nearest to has no representative (it gets the Lambertian below).
    let t0 = std::time::Instant::now();
    let mut group_of = vec![usize::MAX; sample.len()];
    let mut job_cluster: Vec<usize> = Vec::new();
    for (c, mem) in members.iter().enumerate() {
        if mem.is_empty() {
            continue;
        }
        let feats: Vec<f32> = mem
            .iter()
            .flat_map(|&i| features[i * dim..(i + 1) * dim].iter().copied())
            .collect();
        let sub = kmeans::kmeans(
            &feats,
            dim,
            settings.subclusters,
            settings.seed ^ (c as u64 + 1),
            60,
        );
        let first_job = job_cluster.len();
        let mut used = vec![usize::MAX; sub.k];
        for (&i, &a) in mem.iter().zip(&sub.assignment) {
            let slot = &mut used[a as usize];
            if *slot == usize::MAX {
                *slot = job_cluster.len();
                job_cluster.push(c);
            }
            group_of[i] = *slot;
        }
        debug_assert!(job_cluster.len() > first_job);
    }
    drop(features);
    let mut sums = vec![vec![0.0f64; fit_pairs.len()]; job_cluster.len()];
    let mut counts = vec![0usize; job_cluster.len()];
    for_each_texel(src, &sample_texels, block, |i, row| {
        let j = group_of[i];
        counts[j] += 1;
        for (s, &p) in sums[j].iter_mut().zip(&fit_pairs) {
            let v = &row[p * 3..p * 3 + 3];
            *s += (f64::from(v[0]) + f64::from(v[1]) + f64::from(v[2])) / 3.0;
        }
    })?;
    for (s, &n) in sums.iter_mut().zip(&counts) {
        s.iter_mut().for_each(|x| *x /= n.max(1) as f64);
    }
    let mut pairs = Pairs::default();
    for &p in &fit_pairs {
        let (wi, wo) = pair_dirs(src, p);
        pairs.wi.push(wi);
        pairs.wo.push(wo);
    }
    let done = AtomicUsize::new(0);
    let fitted: Vec<Option<Vec<BasisFunction>>> = sums
        .par_iter()
        .map(|y| {
            if cancelled() {
                return None;
            }
            let bases = dictionary::fit_representative(y, &pairs, &settings.dictionary);
            progress(
                Stage::Dictionary,
                done.fetch_add(1, Ordering::Relaxed) + 1,
                sums.len(),
            );
            Some(bases)
        })
        .collect();
    if cancelled() {
        return Err(FitError::Cancelled);
    }
    let mut clusters: Vec<Cluster> = vec![Cluster { bases: Vec::new() }; k];
    for (&c, bases) in job_cluster.iter().zip(fitted) {
        for b in bases.into_iter().flatten() {
            // The lobe bound (spmm::lobe_bound): a basis peaking between the tabulated
            // directions far above its values there is dropped.
            if !lobe_bound::within_bound(&b, src.light_dirs(), src.view_dirs()) {
                continue;
            }
            if !clusters[c]
                .bases
                .iter()
                .any(|e| dictionary::near_duplicate(e, &b))
            {
                clusters[c].bases.push(b);
            }
        }
    }
    for c in clusters.iter_mut() {
        if c.bases.is_empty() {
            // A black or unsampled cluster: a Lambertian keeps the dictionary usable.
            c.bases.push(
                BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
                    .expect("+z is a valid normal"),
            );
        }
    }
    let (columns, first_col, grams) = basis_tables(src, &clusters);
    // The lobe bound's second half: each basis times its weight stays within the
    // hemisphere multiple of the pack's brightest tabulated value (a margin below the
    // validator's multiple for the file's rounding). That value is the sample's
    // brightest at first, then what the fit reproduces of it (below).
    let peaks: Vec<f64> = clusters
        .iter()
        .flat_map(|c| c.bases.iter())
        .collect::<Vec<_>>()
        .par_iter()
        .map(|b| lobe_bound::hemisphere_peak(b).0)
        .collect();
    let target = lobe_bound::HEMISPHERE_MULTIPLE * 0.97;
    let caps_for = |reference: f64| -> Vec<f64> {
        peaks
            .iter()
            .map(|&p| {
                if p > 0.0 && settings.hemisphere_bound {
                    target * reference / p
                } else {
                    f64::INFINITY
                }
            })
            .collect()
    };
    let s_dict = t0.elapsed().as_secs_f64();

    // 3. The residual per cluster: mean + PCA of what the weights leave, over at most
    // `residual_texels` of the cluster's sample texels (the first in the seeded order).
    let t0 = std::time::Instant::now();
    let mut model = Model {
        feature_pairs,
        centroids,
        clusters,
        columns,
        first_col,
        grams,
        caps: caps_for(reference),
        peaks: peaks.clone(),
        means: Vec::new(),
        components: Vec::new(),
        input_hash: h.finish(),
        seconds: [s_cluster, s_dict, 0.0],
    };
    let chosen: Vec<Vec<usize>> = members
        .iter()
        .map(|mem| {
            let mut chosen: Vec<usize> = mem.clone();
            chosen.sort_by_key(|&i| sample[i].1);
            chosen.truncate(settings.residual_texels);
            let mut texels: Vec<usize> = chosen.iter().map(|&i| sample[i].0).collect();
            texels.sort_unstable();
            texels
        })
        .collect();
    // The caps hold every weight within the bound relative to `reference`; the bound
    // itself is relative to the pack's maximum, at least what the fit reproduces at
    // the sample's texels (they are fitted alike in every pack). Where that falls short
    // of the reference, the reference drops to it and the weights and residual are
    // fitted again; past the 4th attempt the assembly lowers the weights over the bound.
    for attempt in 1..=4 {
        fit_residual_model(src, &mut model, &chosen, settings, block, cancel, progress)?;
        if !settings.hemisphere_bound || attempt == 4 {
            break;
        }
        let reproduced = reproduced_maximum(src, &model, &sample_texels, settings, block)?;
        if reference <= reproduced {
            break;
        }
        reference = reproduced * 0.99;
        model.caps = caps_for(reference);
    }
    model.seconds[2] = t0.elapsed().as_secs_f64();
    Ok(model)
}

/// The seeded sample of `texels` texels (all of them when there are few) as (texel,
/// rank), in ascending texel order: `rank` keeps each one's place in the seeded order.
fn sample_of(texels: usize, settings: &FitSettings) -> Vec<(usize, usize)> {
    let drawn = permutation(texels, settings.seed, TEXELS_TAG);
    let mut sample: Vec<(usize, usize)> = drawn[..settings.sample_texels.min(texels)]
        .iter()
        .enumerate()
        .map(|(rank, &t)| (t, rank))
        .collect();
    sample.sort_unstable();
    sample
}

/// The input hash's start: the grid and the directions; the sample's values follow.
fn input_hasher(src: &dyn TexelSource) -> Fnv1a {
    let mut h = Fnv1a::default();
    h.word(u64::from(src.width()));
    h.word(u64::from(src.height()));
    for d in src.light_dirs().iter().chain(src.view_dirs()) {
        d.to_array().iter().for_each(|x| h.word(x.to_bits()));
    }
    h
}

/// The hash of `src` as `settings`' sample sees it (`Model::input_hash`): a model
/// file is used only on the input it was found on.
pub(crate) fn input_hash(
    src: &dyn TexelSource,
    settings: &FitSettings,
    block: usize,
) -> Result<u64, FitError> {
    let texels: Vec<usize> = sample_of(src.texels(), settings)
        .iter()
        .map(|s| s.0)
        .collect();
    let mut h = input_hasher(src);
    for_each_texel(src, &texels, block, |_, row| {
        row.iter().for_each(|x| h.bytes(&x.to_le_bytes()));
    })?;
    Ok(h.finish())
}

/// Per basis (cluster by cluster) its values at every direction pair of `src`, where
/// each cluster's bases start, and each cluster's Gram matrix: what the weights are
/// solved against, a function of the dictionaries and the directions alone.
pub(crate) fn basis_tables(
    src: &dyn TexelSource,
    clusters: &[Cluster],
) -> (Vec<Vec<f64>>, Vec<usize>, Vec<DMatrix<f64>>) {
    let m = src.pairs();
    let columns: Vec<Vec<f64>> = clusters
        .par_iter()
        .flat_map_iter(|c| {
            c.bases.iter().map(|b| {
                (0..m)
                    .map(|p| {
                        let (wi, wo) = pair_dirs(src, p);
                        b.eval(wi, wo)
                    })
                    .collect::<Vec<f64>>()
            })
        })
        .collect();
    let mut first_col = vec![0usize];
    for c in clusters {
        first_col.push(first_col.last().copied().unwrap_or(0) + c.bases.len());
    }
    let grams: Vec<DMatrix<f64>> = (0..clusters.len())
        .map(|c| {
            let cols = &columns[first_col[c]..first_col[c + 1]];
            DMatrix::from_fn(cols.len(), cols.len(), |i, j| {
                cols[i].iter().zip(&cols[j]).map(|(a, b)| a * b).sum()
            })
        })
        .collect();
    (columns, first_col, grams)
}

/// Calls `f` on each of `texels` (ascending) in parallel, reading up to `block` at a
/// time into one buffer; the results in order.
fn map_texels<T: Send>(
    src: &dyn TexelSource,
    texels: &[usize],
    block: usize,
    f: impl Fn(&[f32]) -> T + Sync,
) -> Result<Vec<T>, FitError> {
    let per = src.pairs() * 3;
    let block = block.max(1);
    let mut out = Vec::with_capacity(texels.len());
    let mut buf = vec![0.0f32; block.min(texels.len()) * per];
    for group in texels.chunks(block) {
        let rows = &mut buf[..group.len() * per];
        read_into(src, group, rows)?;
        out.extend(rows.par_chunks(per).map(&f).collect::<Vec<T>>());
    }
    Ok(out)
}

/// Each cluster's residual mean and components from its `chosen` sample texels, against
/// the model's current caps.
fn fit_residual_model(
    src: &dyn TexelSource,
    model: &mut Model,
    chosen: &[Vec<usize>],
    settings: &FitSettings,
    block: usize,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<(), FitError> {
    let d = src.pairs() * 3;
    model.means.clear();
    model.components.clear();
    let k = chosen.len();
    for (c, texels) in chosen.iter().enumerate() {
        if cancel.load(Ordering::Relaxed) {
            return Err(FitError::Cancelled);
        }
        let m: &Model = model;
        let weights = map_texels(src, texels, block, |row| {
            texel_fit::weights(m, c, row, settings.max_bases)
        })?;
        // One column per texel, written in place (no second copy of the matrix).
        let mut xc = DMatrix::<f64>::zeros(d, texels.len());
        for_each_texel(src, texels, block, |i, row| {
            texel_fit::basis_residual(m, c, row, &weights[i], xc.column_mut(i).as_mut_slice());
        })?;
        let r = residual::fit_columns(xc, settings.npca);
        model.means.push(r.mean);
        model.components.push(r.components);
        progress(Stage::Residual, c + 1, k);
    }
    Ok(())
}

/// The largest value the pack will tabulate at the sample's texels, whatever a byte
/// budget keeps of the residual: the lower of the maxima of their basis sums (weights
/// as the pack stores them) plus the residual mean, with and without the components.
/// The same with or without a budget, so a budget does not change the weights.
fn reproduced_maximum(
    src: &dyn TexelSource,
    model: &Model,
    sample_texels: &[usize],
    settings: &FitSettings,
    block: usize,
) -> Result<f64, FitError> {
    let maxima = map_texels(src, sample_texels, block, |row| {
        let fit = texel_fit::fit_texel(model, row, settings.max_bases, &mut Default::default());
        let c = fit.cluster as usize;
        let cols = &model.columns[model.first_col[c]..model.first_col[c + 1]];
        let mut v = model.means[c].clone();
        for &(j, rgb) in &fit.weights {
            for (p, a) in cols[j as usize].iter().enumerate() {
                for ch in 0..3 {
                    v[p * 3 + ch] += f64::from(rgb[ch]) * a;
                }
            }
        }
        let mean_only = v.iter().copied().fold(0.0f64, f64::max);
        for (comp, coef) in model.components[c].iter().zip(&fit.coefficients) {
            v.iter_mut().zip(comp).for_each(|(a, b)| *a += coef * b);
        }
        (mean_only, v.into_iter().fold(0.0f64, f64::max))
    })?;
    let (a, b) = maxima
        .into_iter()
        .fold((0.0f64, 0.0f64), |(a, b), (x, y)| (a.max(x), b.max(y)));
    Ok(a.min(b))
}
