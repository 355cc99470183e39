//! The stages of `fit_btf`, one function each in the pipeline's order: texel
//! clustering, per-cluster dictionaries, the design matrices the weights are solved
//! against, sparse weights per texel, the residual per cluster, and the material they
//! make. Its own module so the crate root reads as the pipeline (the order, the lobe
//! bound's retries, the timing) while each stage's arithmetic stays as it was.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::DVec3;
use nalgebra::DMatrix;
use rayon::prelude::*;

use crate::dictionary::{self, Pairs};
use crate::kmeans::{self, Clustering};
use crate::{FitError, FitSettings, Progress, Stage, lasso, residual};
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use meso_materials::btf::Btf;
use meso_materials::spmm::{Cluster, Residual, SparseWeights, SpmmMaterial, lobe_bound};

/// A texel's non-zero weights: (basis in its cluster, RGB).
pub(crate) type TexelWeights = Vec<(usize, [f64; 3])>;

/// The light and view direction of direction pair `p` of `btf`.
fn pair_dirs(btf: &Btf, p: usize) -> (DVec3, DVec3) {
    let nv = btf.view_dirs().len();
    (btf.light_dirs()[p / nv], btf.view_dirs()[p % nv])
}

/// Rejects settings outside their documented ranges.
pub(crate) fn check_settings(settings: &FitSettings) -> Result<(), FitError> {
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
    Ok(())
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

/// The texels' clustering and the features it was made from.
pub(crate) struct TexelClusters {
    /// Per texel its apparent BRDF at the feature pairs (RGB), scaled to unit length.
    pub features: Vec<f32>,
    /// Values per texel in `features`.
    pub dim: usize,
    pub clustering: Clustering,
    /// Per cluster its texels.
    pub members: Vec<Vec<usize>>,
}

/// Stage 1, texel clusters from their apparent BRDFs at the feature pairs (RGB).
pub(crate) fn cluster_texels(
    btf: &Btf,
    feature_pairs: &[usize],
    settings: &FitSettings,
) -> TexelClusters {
    let texels = btf.texels();
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
    TexelClusters {
        features,
        dim,
        clustering,
        members,
    }
}

/// Stage 2, representatives (sub-cluster means) and their fitted bases: per cluster a
/// dictionary within the lobe bound, without near duplicates, never empty.
pub(crate) fn fit_dictionaries(
    btf: &Btf,
    tc: &TexelClusters,
    fit_pairs: &[usize],
    settings: &FitSettings,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Vec<Cluster>, FitError> {
    let cancelled = || cancel.load(Ordering::Relaxed);
    let TexelClusters {
        features,
        dim,
        clustering,
        members,
    } = tc;
    let (dim, n_clusters) = (*dim, clustering.k);
    let mut pairs = Pairs::default();
    for &p in fit_pairs {
        let (wi, wo) = pair_dirs(btf, p);
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
    Ok(clusters)
}

/// What the weights of every texel are solved against: per basis its values at every
/// direction pair (`columns`, cluster by cluster from `first_col`), per cluster the
/// Gram matrix of its bases.
pub(crate) struct Design {
    pub columns: Vec<Vec<f64>>,
    pub first_col: Vec<usize>,
    pub grams: Vec<DMatrix<f64>>,
}

/// The design of `clusters`' dictionaries over every direction pair of `btf`.
pub(crate) fn design(btf: &Btf, clusters: &[Cluster]) -> Design {
    let m = btf.light_dirs().len() * btf.view_dirs().len();
    let n_clusters = clusters.len();
    let columns: Vec<Vec<f64>> = clusters
        .par_iter()
        .flat_map_iter(|c| {
            c.bases.iter().map(|b| {
                (0..m)
                    .map(|p| {
                        let (wi, wo) = pair_dirs(btf, p);
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
    let grams: Vec<DMatrix<f64>> = (0..n_clusters)
        .map(|c| {
            let cols = &columns[first_col[c]..first_col[c + 1]];
            DMatrix::from_fn(cols.len(), cols.len(), |i, j| {
                cols[i].iter().zip(&cols[j]).map(|(a, b)| a * b).sum()
            })
        })
        .collect();
    Design {
        columns,
        first_col,
        grams,
    }
}

/// Per basis, in cluster order, its peak over the hemisphere (`lobe_bound`).
pub(crate) fn hemisphere_peaks(clusters: &[Cluster]) -> Vec<f64> {
    clusters
        .par_iter()
        .flat_map_iter(|c| c.bases.iter())
        .collect::<Vec<_>>()
        .par_iter()
        .map(|b| lobe_bound::hemisphere_peak(b).0)
        .collect()
}

/// Stage 3, sparse weights per texel against its cluster's dictionary, every pair, each
/// basis's weight capped by `caps`.
pub(crate) fn fit_weights(
    btf: &Btf,
    assignment: &[u32],
    design: &Design,
    caps: &[f64],
    settings: &FitSettings,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Vec<TexelWeights>, FitError> {
    let cancelled = || cancel.load(Ordering::Relaxed);
    let texels = btf.texels();
    let Design {
        columns,
        first_col,
        grams,
    } = design;
    let done = AtomicUsize::new(0);
    let weights: Vec<Option<TexelWeights>> = (0..texels)
        .into_par_iter()
        .map(|t| {
            if cancelled() {
                return None;
            }
            let c = assignment[t] as usize;
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
    Ok(weights.into_iter().map(Option::unwrap_or_default).collect())
}

/// Stage 4, the residual per cluster: mean + PCA over all pairs of what the weights leave.
pub(crate) fn fit_residuals(
    btf: &Btf,
    members: &[Vec<usize>],
    design: &Design,
    weights: &[TexelWeights],
    settings: &FitSettings,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Vec<residual::ClusterResidual>, FitError> {
    let cancelled = || cancel.load(Ordering::Relaxed);
    let m = btf.light_dirs().len() * btf.view_dirs().len();
    let n_clusters = members.len();
    let Design {
        columns, first_col, ..
    } = design;
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
    Ok(residuals.into_iter().flatten().collect())
}

/// The material of the fitted clusters, weights and residuals with N_PCA `k`, named
/// `(name, provenance)`.
pub(crate) fn material(
    btf: &Btf,
    (name, provenance): (&str, &str),
    clusters: &[Cluster],
    tc: &TexelClusters,
    weights: &[TexelWeights],
    residuals: &[residual::ClusterResidual],
    k: usize,
) -> Result<SpmmMaterial, FitError> {
    let texels = btf.texels();
    let d = btf.light_dirs().len() * btf.view_dirs().len() * 3;
    let n_clusters = clusters.len();
    let (clustering, members) = (&tc.clustering, &tc.members);
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
    for w in weights {
        for &(j, rgb) in w {
            sparse.basis.push(j as u16);
            sparse.rgb.push(rgb.map(|x| x as f32));
        }
        sparse.offsets.push(sparse.basis.len() as u32);
    }
    Ok(SpmmMaterial::new(
        name.to_string(),
        provenance.to_string(),
        btf.width(),
        btf.height(),
        clusters.to_vec(),
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
    )?)
}
