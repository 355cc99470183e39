//! Fitting SPMM materials to BTFs, the pipeline of Wu et al. 2011 as Silva & Santos
//! 2013 (section 3) describe it: k-means of the texels' apparent BRDFs into clusters
//! (`kmeans.rs`; each texel's values scaled to unit length, so clusters share a
//! shape and weights carry brightness), sub-clusters whose means are representatives, a dictionary per
//! cluster fitted to them by nonlinear least squares over each analytic model's
//! parameters and normal (`dictionary.rs`), sparse non-negative RGB weights per texel
//! on the lasso path (`lasso.rs`), and a per-cluster mean + PCA residual
//! (`residual.rs`). `report.rs` measures the result.
//!
//! Out of core and splittable: the clusters, dictionaries and residual tables come
//! from a seeded sample of texels (`model.rs`); each texel's fit then reads only its
//! own values and that model (`texel_fit.rs`), streamed in blocks sized to
//! `--max-memory` (`memory.rs`) from any `TexelSource` (a `.btf` on disk included).
//! `assemble.rs` makes the pack and report from the model and every texel's fit; a
//! fit split into shards writes parts (`part.rs`) that `merge` assembles the same
//! way, so the merged pack is the unsharded one bit for bit. Deterministic for a seed
//! and independent of the thread count and the memory budget. The nonlinear stages
//! see a seeded subset of the direction pairs; the weights and the residual use every pair.

mod assemble;
pub mod budget;
mod codec;
pub mod dictionary;
pub mod kmeans;
pub mod lasso;
pub mod memory;
mod model;
pub mod model_file;
pub mod part;
pub mod report;
pub mod residual;
mod texel_fit;

#[cfg(test)]
mod split_tests;
#[cfg(test)]
mod tests;

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use dictionary::DictionarySettings;
use meso_materials::btf::texels::TexelSource;
pub use meso_materials::spmm::pack::ResidualPrecision;
use meso_materials::spmm::{SpmmError, SpmmMaterial};
pub use model_file::{FitModel, ModelFileError};
pub use part::{MergeError, Part, Shard};
pub use report::{ClusterReport, ErrorRow, FitReport, StageSeconds};

/// The knobs of `meso fit`.
#[derive(Clone, Copy, Debug, PartialEq)]
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
    /// Texels of the seeded sample the clusters and dictionaries are found on.
    pub sample_texels: usize,
    /// Sample texels per cluster at most that its residual mean and PCA are found on.
    pub residual_texels: usize,
    /// Peak memory the fit keeps within (bytes); sizes the texel blocks only, never
    /// the result.
    pub max_memory: u64,
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
            sample_texels: 4096,
            residual_texels: 512,
            max_memory: memory::DEFAULT_MAX_MEMORY,
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
    #[error("{0}")]
    Memory(String),
    #[error("reading the BTF: {0}")]
    Input(String),
    /// A model file that cannot be used for this fit (`model_file.rs`).
    #[error("{0}")]
    Model(String),
    #[error("the fitted material is invalid: {0}")]
    Material(#[from] SpmmError),
}

/// The fitted material and its report.
pub struct FitOutput {
    pub material: SpmmMaterial,
    pub report: FitReport,
    /// The precision the pack is to be written at (`FitSettings::precision`).
    pub precision: ResidualPrecision,
}

impl FitSettings {
    /// Every setting that shapes the result, as text: shards of one fit must agree
    /// on it (`--max-memory` and the shard are not in it; they change nothing).
    pub fn options_text(&self) -> String {
        let d = &self.dictionary;
        format!(
            "clusters {} subclusters {} max-bases {} npca {} seed {} feature-pairs {} fit-pairs {} sample-texels {} residual-texels {} max-bytes {:?} precision {} hemisphere-bound {} dictionary {}/{}/{}",
            self.clusters,
            self.subclusters,
            self.max_bases,
            self.npca,
            self.seed,
            self.feature_pairs,
            self.fit_pairs,
            self.sample_texels,
            self.residual_texels,
            self.max_bytes,
            self.precision.name(),
            self.hemisphere_bound,
            d.max_rounds,
            d.min_gain,
            d.iterations
        )
    }
}

/// Rejects settings outside their documented ranges.
fn check_settings(settings: &FitSettings) -> Result<(), FitError> {
    let check = |name: &'static str, value: usize, lo: usize, hi: usize, rule: &'static str| {
        if (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(FitError::Setting { name, value, rule })
        }
    };
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
    check(
        "sample-texels",
        settings.sample_texels,
        1,
        usize::MAX,
        "must be at least 1",
    )?;
    check(
        "residual-texels",
        settings.residual_texels,
        1,
        usize::MAX,
        "must be at least 1",
    )?;
    Ok(())
}

/// Where a fit's model comes from.
pub enum ModelFrom<'a> {
    /// Found now on `src`'s seeded sample (the model stages).
    Sample,
    /// A model file (`find_model`'s, read with `FitModel::read`) at this path: used
    /// only when it was found with the same options on the same input.
    File(Box<FitModel>, &'a std::path::Path),
}

/// The model of `src` (found, or a model file's checked and attached) and the block
/// size of `settings`' budget.
fn model_of(
    src: &dyn TexelSource,
    settings: &FitSettings,
    from: ModelFrom,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<(model::Model, usize), FitError> {
    check_settings(settings)?;
    let block = memory::block_texels(settings, src.texels(), src.pairs())?;
    let model = match from {
        ModelFrom::Sample => model::fit_model(src, settings, block, cancel, progress)?,
        ModelFrom::File(m, path) => m.attach(src, settings, block, path)?,
    };
    Ok((model, block))
}

/// Finds the model of a fit of `src` with `settings` (the stages every shard would
/// repeat) to write as a model file; `input` names the input in it.
pub fn find_model(
    src: &dyn TexelSource,
    input: &str,
    settings: &FitSettings,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<FitModel, FitError> {
    let (model, _) = model_of(src, settings, ModelFrom::Sample, cancel, progress)?;
    Ok(FitModel {
        input: input.to_string(),
        options: settings.options_text(),
        model,
    })
}

/// Fits an SPMM to `src` (in memory or on disk), within `settings.max_memory`.
/// `cancel` is polled between work items.
pub fn fit_btf(
    src: &dyn TexelSource,
    name: &str,
    provenance: &str,
    settings: &FitSettings,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<FitOutput, FitError> {
    fit_btf_from(
        src,
        (name, provenance),
        settings,
        ModelFrom::Sample,
        cancel,
        progress,
    )
}

/// `fit_btf` with the model from `from`.
pub fn fit_btf_from(
    src: &dyn TexelSource,
    (name, provenance): (&str, &str),
    settings: &FitSettings,
    from: ModelFrom,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<FitOutput, FitError> {
    let (model, block) = model_of(src, settings, from, cancel, progress)?;
    let t0 = Instant::now();
    let fits = texel_fit::fit_range(
        src,
        &model,
        0..src.texels(),
        block,
        settings.max_bases,
        cancel,
        progress,
    )?;
    let seconds = t0.elapsed().as_secs_f64();
    let tables = assemble::Tables::new(&model, (name, provenance), src, settings);
    drop(model);
    assemble::assemble(&tables, &fits, seconds)
}

/// Fits shard `shard` of `src`'s texels: the shared model, then this shard's texels.
/// `input` names the input in the part (for messages).
pub fn fit_part(
    src: &dyn TexelSource,
    names: (&str, &str, &str),
    settings: &FitSettings,
    shard: Shard,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Part, FitError> {
    fit_part_from(
        src,
        names,
        settings,
        shard,
        ModelFrom::Sample,
        cancel,
        progress,
    )
}

/// `fit_part` with the model from `from`: a model file spares each shard the model
/// stages.
pub fn fit_part_from(
    src: &dyn TexelSource,
    (name, provenance, input): (&str, &str, &str),
    settings: &FitSettings,
    shard: Shard,
    from: ModelFrom,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Part, FitError> {
    let (model, block) = model_of(src, settings, from, cancel, progress)?;
    let t0 = Instant::now();
    let fits = texel_fit::fit_range(
        src,
        &model,
        shard.texels(src.texels()),
        block,
        settings.max_bases,
        cancel,
        progress,
    )?;
    Ok(Part {
        shard,
        input: input.to_string(),
        options: settings.options_text(),
        input_hash: model.input_hash,
        tables: assemble::Tables::new(&model, (name, provenance), src, settings),
        fits,
        texel_seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Merges the part files at `paths` (every shard of one fit, in any order) into the
/// pack the unsharded fit makes. Parts are read one at a time and keep their texel
/// fits only: the model's tables, the same in every part (their hash is checked), are
/// held once, so memory is the fits plus one part's tables however many shards.
pub fn merge(paths: &[PathBuf]) -> Result<FitOutput, MergeFailure> {
    let mut tables = None;
    let mut parts = Vec::with_capacity(paths.len());
    for path in paths {
        let mut part = Part::read(path)?;
        let model = part.tables.take_model();
        tables.get_or_insert(model);
        parts.push((path.clone(), part));
    }
    assemble_parts(parts, tables)
}

/// `merge` of parts already read (with the paths their messages name).
pub fn merge_parts(parts: Vec<(PathBuf, Part)>) -> Result<FitOutput, MergeFailure> {
    assemble_parts(parts, None)
}

/// Checks the parts belong together and assembles the pack, with the model's tables
/// taken from `tables` or else from the first shard.
fn assemble_parts(
    parts: Vec<(PathBuf, Part)>,
    tables: Option<assemble::Tables>,
) -> Result<FitOutput, MergeFailure> {
    let parts = part::check_parts(parts)?;
    let seconds: f64 = parts.iter().map(|(_, p)| p.texel_seconds).sum();
    let mut parts = parts.into_iter().map(|(_, p)| p);
    let Some(mut first) = parts.next() else {
        return Err(part::MergeError::NoParts.into());
    };
    for p in parts {
        first.fits.extend(p.fits);
    }
    let tables = tables.unwrap_or(first.tables);
    Ok(assemble::assemble(&tables, &first.fits, seconds)?)
}

/// Why a merge failed: the parts (named), or the assembly of the pack.
#[derive(Debug, thiserror::Error)]
pub enum MergeFailure {
    #[error(transparent)]
    Parts(#[from] MergeError),
    #[error(transparent)]
    Fit(#[from] FitError),
}
