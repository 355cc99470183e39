//! Fitting SPMM materials to BTFs, the pipeline of Wu et al. 2011 as Silva & Santos
//! 2013 (section 3) describe it: k-means of the texels' apparent BRDFs into clusters
//! (`kmeans.rs`; each texel's values scaled to unit length, so clusters share a
//! shape and weights carry brightness), sub-clusters whose means are representatives, a dictionary per
//! cluster fitted to them by nonlinear least squares over each analytic model's
//! parameters and normal (`dictionary.rs`), sparse non-negative RGB weights per texel
//! on the lasso path (`lasso.rs`), and a per-cluster mean + PCA residual
//! (`residual.rs`). `report.rs` measures the result. Deterministic for a seed and
//! independent of the thread count. The nonlinear stages see a seeded subset of the
//! direction pairs; the weights and the residual use every pair.

pub mod budget;
pub mod dictionary;
pub mod kmeans;
pub mod lasso;
pub mod report;
pub mod residual;

#[cfg(test)]
mod tests;

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;

use glam::DVec3;
use nalgebra::DMatrix;
use rayon::prelude::*;

use dictionary::{DictionarySettings, Pairs};
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use meso_materials::btf::Btf;
use meso_materials::rng::SampleStream;
use meso_materials::spmm::pack::ResidualPrecision;
use meso_materials::spmm::{Cluster, Residual, SparseWeights, SpmmError, SpmmMaterial, lobe_bound};
pub use report::{ClusterReport, ErrorRow, FitReport, StageSeconds};

/// The knobs of `meso fit`.
#[derive(Clone, Copy, Debug)]
pub struct FitSettings {
    /// k of the texel k-means (the seed used 32).
    pub clusters: usize,
    /// Representatives per cluster (the seed used 8).
    pub subclusters: usize,
    /// Largest number of non-zero weights per texel (the seed had 3 to 9 on average).
    pub max_bases: usize,
    /// Principal components of the residual per cluster.
    pub npca: usize,
    pub seed: u64,
    /// Direction pairs the k-means features use (all when the BTF has fewer).
    pub feature_pairs: usize,
    /// Direction pairs the nonlinear dictionary fits use.
    pub fit_pairs: usize,
    pub dictionary: DictionarySettings,
    /// Caps the weights so that no basis exceeds the lobe bound's hemisphere multiple
    /// of the BTF's maximum (spmm::lobe_bound); off only to test exact recovery.
    pub hemisphere_bound: bool,
    /// A byte budget for the pack file at `precision`: `npca` becomes each cluster's
    /// most, and the components kept over all clusters are those that remove the
    /// most table error until the file reaches the budget (`budget.rs`).
    pub max_bytes: Option<u64>,
    /// Precision of the residual tables the budget counts.
    pub precision: ResidualPrecision,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            clusters: 32,
            subclusters: 8,
            max_bases: 9,
            npca: 8,
            seed: 0,
            feature_pairs: 512,
            fit_pairs: 6561,
            dictionary: DictionarySettings::default(),
            hemisphere_bound: true,
            max_bytes: None,
            precision: ResidualPrecision::F16,
        }
    }
}

/// The stages, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Clustering,
    Dictionary,
    Weights,
    Residual,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::Clustering => "clustering",
            Stage::Dictionary => "dictionaries",
            Stage::Weights => "weights",
            Stage::Residual => "residual",
        }
    }
}

/// (stage, work items done, work items in the stage).
pub type Progress<'a> = &'a (dyn Fn(Stage, usize, usize) + Sync);

#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("`--{name}` = {value}: {rule}")]
    Setting {
        name: &'static str,
        value: usize,
        rule: &'static str,
    },
    #[error("cancelled")]
    Cancelled,
    #[error(
        "the fitted weights could not be brought within the lobe bound in 4 attempts (a bug: please report it)"
    )]
    LobeBound,
    #[error("--max-bytes: {0}")]
    Budget(String),
    #[error("the fitted material is invalid: {0}")]
    Material(#[from] SpmmError),
}

/// The fitted material and its report.
pub struct FitOutput {
    pub material: SpmmMaterial,
    pub report: FitReport,
}

fn check(
    name: &'static str,
    value: usize,
    lo: usize,
    hi: usize,
    rule: &'static str,
) -> Result<(), FitError> {
    if (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(FitError::Setting { name, value, rule })
    }
}

/// A seeded permutation of 0..n (Fisher-Yates on `SampleStream`).
fn permutation(n: usize, seed: u64) -> Vec<usize> {
    let mut p: Vec<usize> = (0..n).collect();
    let s = SampleStream::new(&[seed, 0x7065_726d]);
    for i in (1..n).rev() {
        let j = ((s.at(i as u64) * (i + 1) as f64) as usize).min(i);
        p.swap(i, j);
    }
    p
}

/// Fits an SPMM to `btf`. `cancel` is polled between work items.
pub fn fit_btf(
    btf: &Btf,
    name: &str,
    provenance: &str,
    settings: &FitSettings,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<FitOutput, FitError> {
    check("clusters", settings.clusters, 1, 255, "must be in 1..=255")?;
    check(
        "subclusters",
        settings.subclusters,
        1,
        64,
        "must be in 1..=64",
    )?;
    check("max-bases", settings.max_bases, 1, 64, "must be in 1..=64")?;
    check("npca", settings.npca, 0, 256, "must be in 0..=256")?;
    check(
        "fit-pairs",
        settings.fit_pairs,
        16,
        usize::MAX,
        "must be at least 16",
    )?;
    let cancelled = || cancel.load(Ordering::Relaxed);
    let t_all = Instant::now();
    let texels = btf.texels();
    let (nl, nv) = (btf.light_dirs().len(), btf.view_dirs().len());
    let m = nl * nv;
    let order = permutation(m, settings.seed);
    let mut feature_pairs: Vec<usize> = order[..settings.feature_pairs.min(m)].to_vec();
    feature_pairs.sort_unstable();
    let mut fit_pairs: Vec<usize> = order[..settings.fit_pairs.min(m)].to_vec();
    fit_pairs.sort_unstable();
    let pair_dirs = |p: usize| (btf.light_dirs()[p / nv], btf.view_dirs()[p % nv]);

    // 1. Texel clusters from their apparent BRDFs at the feature pairs (RGB).
    let t0 = Instant::now();
    progress(Stage::Clustering, 0, 1);
    let dim = feature_pairs.len() * 3;
    // Each texel's feature is scaled to unit length: clusters group apparent BRDFs of
    // one shape (one dictionary serves them), the weights carry brightness.
    let features: Vec<f32> = (0..texels)
        .into_par_iter()
        .flat_map_iter(|t| {
            let row = btf.texel(t);
            let f: Vec<f32> = feature_pairs
                .iter()
                .flat_map(|&p| [row[p * 3], row[p * 3 + 1], row[p * 3 + 2]])
                .collect();
            let norm = f.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
            let scale = if norm > 0.0 { (1.0 / norm) as f32 } else { 0.0 };
            f.into_iter().map(move |x| x * scale)
        })
        .collect();
    let clustering = kmeans::kmeans(&features, dim, settings.clusters, settings.seed, 60);
    let n_clusters = clustering.k;
    let members: Vec<Vec<usize>> = (0..n_clusters)
        .map(|c| {
            (0..texels)
                .filter(|&t| clustering.assignment[t] as usize == c)
                .collect()
        })
        .collect();
    progress(Stage::Clustering, 1, 1);
    if cancelled() {
        return Err(FitError::Cancelled);
    }
    let s_cluster = t0.elapsed().as_secs_f64();

    // 2. Representatives (sub-cluster means) and their fitted bases.
    let t0 = Instant::now();
    let mut pairs = Pairs::default();
    for &p in &fit_pairs {
        let (wi, wo) = pair_dirs(p);
        pairs.wi.push(wi);
        pairs.wo.push(wo);
    }
    let mut jobs: Vec<(usize, Vec<f64>)> = Vec::new();
    for (c, mem) in members.iter().enumerate() {
        let feats: Vec<f32> = mem
            .iter()
            .flat_map(|&t| features[t * dim..(t + 1) * dim].iter().copied())
            .collect();
        let sub = kmeans::kmeans(
            &feats,
            dim,
            settings.subclusters,
            settings.seed ^ (c as u64 + 1),
            60,
        );
        for r in 0..sub.k {
            let group: Vec<usize> = mem
                .iter()
                .zip(&sub.assignment)
                .filter(|(_, a)| **a as usize == r)
                .map(|(t, _)| *t)
                .collect();
            if group.is_empty() {
                continue;
            }
            let y: Vec<f64> = fit_pairs
                .iter()
                .map(|&p| {
                    group
                        .iter()
                        .map(|&t| {
                            let v = &btf.texel(t)[p * 3..p * 3 + 3];
                            (f64::from(v[0]) + f64::from(v[1]) + f64::from(v[2])) / 3.0
                        })
                        .sum::<f64>()
                        / group.len() as f64
                })
                .collect();
            jobs.push((c, y));
        }
    }
    let done = AtomicUsize::new(0);
    let fitted: Vec<Option<Vec<BasisFunction>>> = jobs
        .par_iter()
        .map(|(_, y)| {
            if cancelled() {
                return None;
            }
            let bases = dictionary::fit_representative(y, &pairs, &settings.dictionary);
            progress(
                Stage::Dictionary,
                done.fetch_add(1, Ordering::Relaxed) + 1,
                jobs.len(),
            );
            Some(bases)
        })
        .collect();
    if cancelled() {
        return Err(FitError::Cancelled);
    }
    let mut clusters: Vec<Cluster> = vec![Cluster { bases: Vec::new() }; n_clusters];
    for ((c, _), bases) in jobs.iter().zip(fitted) {
        for b in bases.into_iter().flatten() {
            // The lobe bound (spmm::lobe_bound): a basis peaking between the tabulated
            // directions far above its values there is dropped; the weights and the
            // residual are fitted without it.
            if !lobe_bound::within_bound(&b, btf.light_dirs(), btf.view_dirs()) {
                continue;
            }
            if !clusters[*c]
                .bases
                .iter()
                .any(|e| dictionary::near_duplicate(e, &b))
            {
                clusters[*c].bases.push(b);
            }
        }
    }
    for c in clusters.iter_mut() {
        if c.bases.is_empty() {
            // A black cluster: a Lambertian keeps the dictionary usable for editing.
            c.bases.push(
                BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
                    .expect("+z is a valid normal"),
            );
        }
    }
    let s_dict = t0.elapsed().as_secs_f64();

    // 3. Sparse weights per texel against its cluster's dictionary, every pair.
    let mut s_weights = 0.0;
    let mut s_residual = 0.0;
    let columns: Vec<Vec<f64>> = clusters
        .par_iter()
        .flat_map_iter(|c| {
            c.bases.iter().map(|b| {
                (0..m)
                    .map(|p| {
                        let (wi, wo) = pair_dirs(p);
                        b.eval(wi, wo)
                    })
                    .collect::<Vec<f64>>()
            })
        })
        .collect();
    let mut first_col = vec![0usize];
    for c in &clusters {
        first_col.push(first_col.last().copied().unwrap_or(0) + c.bases.len());
    }
    let grams: Vec<DMatrix<f64>> = (0..n_clusters)
        .map(|c| {
            let cols = &columns[first_col[c]..first_col[c + 1]];
            DMatrix::from_fn(cols.len(), cols.len(), |i, j| {
                cols[i].iter().zip(&cols[j]).map(|(a, b)| a * b).sum()
            })
        })
        .collect();
    // The lobe bound's second half (spmm::lobe_bound): each basis times its weight
    // stays within HEMISPHERE_MULTIPLE times the pack's largest tabulated value
    // anywhere on the hemisphere down to 88.2 degrees. The weights are capped at that
    // relative to the BTF's maximum (which the pack's maximum approximates); if the
    // finished pack's own maximum is lower, the caps shrink by the shortfall and the
    // weights and residual are fitted again.
    let peaks: Vec<f64> = clusters
        .par_iter()
        .flat_map_iter(|c| c.bases.iter())
        .collect::<Vec<_>>()
        .par_iter()
        .map(|b| lobe_bound::hemisphere_peak(b).0)
        .collect();
    let btf_max = btf.data().iter().fold(0.0f64, |a, &x| a.max(f64::from(x)));
    // A margin below the validator's multiple for the f32/f16 rounding of the file.
    let target = lobe_bound::HEMISPHERE_MULTIPLE * 0.97;
    let mut reference = btf_max;
    let mut attempt = 0;
    let (material, weights, residuals, cluster_npca) = loop {
        attempt += 1;
        let caps: Vec<f64> = peaks
            .iter()
            .map(|&p| {
                if p > 0.0 && settings.hemisphere_bound {
                    target * reference / p
                } else {
                    f64::INFINITY
                }
            })
            .collect();
        let t0 = Instant::now();
        let done = AtomicUsize::new(0);
        type TexelWeights = Vec<(usize, [f64; 3])>;
        let weights: Vec<Option<TexelWeights>> = (0..texels)
            .into_par_iter()
            .map(|t| {
                if cancelled() {
                    return None;
                }
                let c = clustering.assignment[t] as usize;
                let cols = &columns[first_col[c]..first_col[c + 1]];
                let row = btf.texel(t);
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
                let w = lasso::texel_weights(
                    &grams[c],
                    &b,
                    settings.max_bases,
                    &caps[first_col[c]..first_col[c + 1]],
                );
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                if d.is_multiple_of(64) || d == texels {
                    progress(Stage::Weights, d, texels);
                }
                Some(w)
            })
            .collect();
        if cancelled() {
            return Err(FitError::Cancelled);
        }
        let weights: Vec<Vec<(usize, [f64; 3])>> =
            weights.into_iter().map(Option::unwrap_or_default).collect();
        s_weights += t0.elapsed().as_secs_f64();

        // 4. Residual per cluster: mean + PCA over all pairs.
        let t0 = Instant::now();
        let d = m * 3;
        let done = AtomicUsize::new(0);
        let residuals: Vec<Option<residual::ClusterResidual>> = (0..n_clusters)
            .into_par_iter()
            .map(|c| {
                if cancelled() {
                    return None;
                }
                let cols = &columns[first_col[c]..first_col[c + 1]];
                let mut rows = vec![0.0f64; members[c].len() * d];
                for (i, &t) in members[c].iter().enumerate() {
                    let out = &mut rows[i * d..(i + 1) * d];
                    for (o, v) in out.iter_mut().zip(btf.texel(t)) {
                        *o = f64::from(*v);
                    }
                    for &(j, w) in &weights[t] {
                        for (p, a) in cols[j].iter().enumerate() {
                            for ch in 0..3 {
                                out[p * 3 + ch] -= w[ch] * a;
                            }
                        }
                    }
                }
                let r = residual::fit_cluster_residual(&rows, d, settings.npca);
                progress(
                    Stage::Residual,
                    done.fetch_add(1, Ordering::Relaxed) + 1,
                    n_clusters,
                );
                Some(r)
            })
            .collect();
        if cancelled() {
            return Err(FitError::Cancelled);
        }
        let residuals: Vec<residual::ClusterResidual> = residuals.into_iter().flatten().collect();
        s_residual += t0.elapsed().as_secs_f64();

        // The material.
        let k = settings.npca;
        let mut mean = vec![0.0f32; n_clusters * d];
        let mut components = vec![0.0f32; n_clusters * k * d];
        let mut coefficients = vec![0.0f32; texels * k];
        for (c, r) in residuals.iter().enumerate() {
            for (dst, src) in mean[c * d..(c + 1) * d].iter_mut().zip(&r.mean) {
                *dst = *src as f32;
            }
            for (kk, comp) in r.components.iter().enumerate() {
                let at = (c * k + kk) * d;
                for (dst, src) in components[at..at + d].iter_mut().zip(comp) {
                    *dst = *src as f32;
                }
            }
            for (i, &t) in members[c].iter().enumerate() {
                for (kk, v) in r.coefficients[i].iter().enumerate() {
                    coefficients[t * k + kk] = *v as f32;
                }
            }
        }
        let mut sparse = SparseWeights {
            offsets: vec![0],
            basis: Vec::new(),
            rgb: Vec::new(),
        };
        for w in &weights {
            for &(j, rgb) in w {
                sparse.basis.push(j as u16);
                sparse.rgb.push(rgb.map(|x| x as f32));
            }
            sparse.offsets.push(sparse.basis.len() as u32);
        }
        let mut material = SpmmMaterial::new(
            name.to_string(),
            provenance.to_string(),
            btf.width(),
            btf.height(),
            clusters.clone(),
            clustering.assignment.clone(),
            sparse,
            Some(Residual {
                light_dirs: btf.light_dirs().to_vec(),
                view_dirs: btf.view_dirs().to_vec(),
                npca: k,
                mean,
                components,
                coefficients,
            }),
        )?;
        let mut cluster_npca = None;
        if let Some(max_bytes) = settings.max_bytes {
            let trimmed = budget::trim_to_bytes(&material, max_bytes, settings.precision)?;
            material = trimmed.material;
            cluster_npca = Some(trimmed.cluster_npca);
        }
        let pack_max = lobe_bound::tabulated_maximum(&material);
        let largest = lobe_bound::largest_weights(&material);
        let worst = largest
            .iter()
            .flatten()
            .zip(&peaks)
            .map(|(w, p)| w * p)
            .fold(0.0f64, f64::max);
        if worst <= target * pack_max || !settings.hemisphere_bound {
            break (material, weights, residuals, cluster_npca);
        }
        if attempt == 4 {
            return Err(FitError::LobeBound);
        }
        // The pack's maximum fell short of the BTF's: shrink the caps by the shortfall.
        reference *= (target * pack_max / worst).min(0.99);
    };
    let seconds = StageSeconds {
        clustering: s_cluster,
        dictionary: s_dict,
        weights: s_weights,
        residual: s_residual,
        total: t_all.elapsed().as_secs_f64(),
    };
    let mut report = report::build(
        btf, &material, &members, &residuals, &weights, settings, seconds,
    );
    if let Some(counts) = cluster_npca {
        report.set_cluster_npca(&residuals, counts);
    }
    Ok(FitOutput { material, report })
}
