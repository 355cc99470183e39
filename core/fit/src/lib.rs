//! Fitting SPMM materials to BTFs, the pipeline of Wu et al. 2011 as Silva & Santos
//! 2013 (section 3) describe it: k-means of the texels' apparent BRDFs into clusters
//! (`kmeans.rs`; each texel's values scaled to unit length, so clusters share a
//! shape and weights carry brightness), sub-clusters whose means are representatives, a dictionary per
//! cluster fitted to them by nonlinear least squares over each analytic model's
//! parameters and normal (`dictionary.rs`), sparse non-negative RGB weights per texel
//! on the lasso path (`lasso.rs`), and a per-cluster mean + PCA residual
//! (`residual.rs`). `report.rs` measures the result. The stages run in `stages.rs`,
//! this root holds their order and the lobe bound's retries (`fit_btf`). Deterministic for a seed and
//! independent of the thread count. The nonlinear stages see a seeded subset of the
//! direction pairs; the weights and the residual use every pair.

pub mod budget;
pub mod dictionary;
pub mod kmeans;
pub mod lasso;
pub mod report;
pub mod residual;
mod stages;

#[cfg(test)]
mod tests;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use dictionary::DictionarySettings;
use meso_materials::btf::Btf;
use meso_materials::rng::SampleStream;
use meso_materials::spmm::pack::ResidualPrecision;
use meso_materials::spmm::{SpmmError, SpmmMaterial, lobe_bound};
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

/// Fits an SPMM to `btf`. `cancel` is polled between work items. The stages are in
/// `stages.rs`; this is their order, the lobe bound's retries and the timing.
pub fn fit_btf(
    btf: &Btf,
    name: &str,
    provenance: &str,
    settings: &FitSettings,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<FitOutput, FitError> {
    stages::check_settings(settings)?;
    let cancelled = || cancel.load(Ordering::Relaxed);
    let t_all = Instant::now();
    let m = btf.light_dirs().len() * btf.view_dirs().len();
    let order = permutation(m, settings.seed);
    let mut feature_pairs: Vec<usize> = order[..settings.feature_pairs.min(m)].to_vec();
    feature_pairs.sort_unstable();
    let mut fit_pairs: Vec<usize> = order[..settings.fit_pairs.min(m)].to_vec();
    fit_pairs.sort_unstable();

    // 1. Texel clusters from their apparent BRDFs at the feature pairs (RGB).
    let t0 = Instant::now();
    progress(Stage::Clustering, 0, 1);
    let tc = stages::cluster_texels(btf, &feature_pairs, settings);
    progress(Stage::Clustering, 1, 1);
    if cancelled() {
        return Err(FitError::Cancelled);
    }
    let s_cluster = t0.elapsed().as_secs_f64();

    // 2. Representatives (sub-cluster means) and their fitted bases.
    let t0 = Instant::now();
    let clusters = stages::fit_dictionaries(btf, &tc, &fit_pairs, settings, cancel, progress)?;
    let s_dict = t0.elapsed().as_secs_f64();

    // 3. and 4. Weights and residual, again with smaller caps while the lobe bound fails.
    let mut s_weights = 0.0;
    let mut s_residual = 0.0;
    let design = stages::design(btf, &clusters);
    // The lobe bound's second half (spmm::lobe_bound): each basis times its weight
    // stays within HEMISPHERE_MULTIPLE times the pack's largest tabulated value
    // anywhere on the hemisphere down to 88.2 degrees. The weights are capped at that
    // relative to the BTF's maximum (which the pack's maximum approximates); if the
    // finished pack's own maximum is lower, the caps shrink by the shortfall and the
    // weights and residual are fitted again.
    let peaks = stages::hemisphere_peaks(&clusters);
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
        let assignment = &tc.clustering.assignment;
        let weights =
            stages::fit_weights(btf, assignment, &design, &caps, settings, cancel, progress)?;
        s_weights += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let residuals = stages::fit_residuals(
            btf,
            &tc.members,
            &design,
            &weights,
            settings,
            cancel,
            progress,
        )?;
        s_residual += t0.elapsed().as_secs_f64();

        let mut material = stages::material(
            btf,
            (name, provenance),
            &clusters,
            &tc,
            &weights,
            &residuals,
            settings.npca,
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
        btf,
        &material,
        &tc.members,
        &residuals,
        &weights,
        settings,
        seconds,
    );
    if let Some(counts) = cluster_npca {
        report.set_cluster_npca(&residuals, counts);
    }
    Ok(FitOutput { material, report })
}
