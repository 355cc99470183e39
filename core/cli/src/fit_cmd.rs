//! `meso fit IN.btf -o OUT.spmm`: fit an SPMM pack to a BTF (core::fit), print the
//! fit report (text, or one JSON object with --json), optionally save it as JSON.
//! The BTF is read from disk block by block within `--max-memory`; `--shard K/N`
//! fits one part of the texels and `meso fit merge` joins the parts into the pack the
//! unsharded fit writes; `--model-only` writes the fit's model once, and `--model`
//! spares each shard finding it again. Ctrl-C stops between work items and leaves no output file.

use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::{Args, Subcommand};
use meso_fit::{FitError, FitOutput, FitSettings, MergeFailure, Shard};
use meso_materials::btf::on_disk::OnDiskBtf;
use meso_materials::btf::texels::TexelSource;
use meso_materials::spmm::pack::{self, ResidualPrecision};

use crate::failure::{CliError, ResultExt};
use crate::progress::{ProgressLine, cancel_flag};

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct FitArgs {
    #[command(subcommand)]
    command: Option<FitCommand>,
    /// The BTF to fit (.btf).
    #[arg(required = true)]
    input: Option<PathBuf>,
    /// The pack (.spmm), or with --shard the part file.
    #[arg(short = 'o', long, required = true)]
    output: Option<PathBuf>,
    /// Texel clusters (k-means).
    #[arg(long, default_value_t = 32)]
    clusters: usize,
    /// Representatives per cluster (sub-clusters).
    #[arg(long, default_value_t = 8)]
    subclusters: usize,
    /// Non-zero weights per texel at most.
    #[arg(long, default_value_t = 9)]
    max_bases: usize,
    /// Principal components of the residual per cluster (0: mean only).
    #[arg(long, default_value_t = 8)]
    npca: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Direction pairs the nonlinear dictionary fits see (a seeded subset; default all of the Bonn layout).
    #[arg(long, default_value_t = 6561)]
    fit_pairs: usize,
    /// Texels of the seeded sample the clusters and dictionaries are found on.
    #[arg(long, default_value_t = 4096)]
    sample_texels: usize,
    /// Sample texels per cluster at most that its residual mean and PCA are found on.
    #[arg(long, default_value_t = 512)]
    residual_texels: usize,
    /// Peak memory: B, KB, MB, GB or TB (powers of 1024), e.g. 256MB. Sizes the
    /// blocks of texels read at once; the result does not depend on it.
    #[arg(long, default_value = "2GB")]
    max_memory: String,
    /// Fit only shard K of N (1 <= K <= N) of the texels and write a part file to
    /// -o; `meso fit merge` joins every shard's part into the pack.
    #[arg(long)]
    shard: Option<String>,
    /// Only find the fit's model (clusters, dictionaries, residual tables: the stages
    /// every shard repeats) and write it to -o, for `--model`.
    #[arg(long, conflicts_with_all = ["shard", "model", "report"])]
    model_only: bool,
    /// Use this model file (from `--model-only` with the same options on the same
    /// BTF) instead of finding the model again.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Name of the material (default: the BTF's).
    #[arg(long)]
    name: Option<String>,
    /// Write the report as JSON here as well.
    #[arg(long, conflicts_with = "shard")]
    report: Option<PathBuf>,
    /// A byte budget for the pack: --npca becomes each cluster's most, and the
    /// components kept over all clusters are those that remove the most table error
    /// until the file reaches the budget (per-cluster N_PCA).
    #[arg(long)]
    max_bytes: Option<u64>,
    /// Precision of the residual tables in the file: f16, f32, or i8 (8-bit
    /// components with a power-of-two scale per component and light direction; half
    /// the bytes of f16 per component). A byte budget counts this precision.
    #[arg(long, value_enum, default_value_t = PrecisionArg::F16, conflicts_with = "f32")]
    precision: PrecisionArg,
    /// The same as --precision f32.
    #[arg(long)]
    f32: bool,
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand, Debug)]
enum FitCommand {
    /// Join the part files of every shard into the pack the unsharded fit writes.
    Merge(MergeArgs),
}

#[derive(Args, Debug)]
struct MergeArgs {
    /// The shards' part files, in any order.
    #[arg(required = true)]
    parts: Vec<PathBuf>,
    /// The pack (.spmm).
    #[arg(short = 'o', long)]
    output: PathBuf,
    /// Write the report as JSON here as well.
    #[arg(long)]
    report: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

/// `--precision` of `meso fit` and `meso pack trim`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum PrecisionArg {
    F16,
    F32,
    I8,
}

impl From<PrecisionArg> for ResidualPrecision {
    fn from(p: PrecisionArg) -> Self {
        match p {
            PrecisionArg::F16 => ResidualPrecision::F16,
            PrecisionArg::F32 => ResidualPrecision::F32,
            PrecisionArg::I8 => ResidualPrecision::I8,
        }
    }
}

impl FitArgs {
    fn residual_precision(&self) -> ResidualPrecision {
        if self.f32 {
            ResidualPrecision::F32
        } else {
            self.precision.into()
        }
    }
}

fn fit_error(e: FitError, output: &Path) -> CliError {
    match e {
        FitError::Cancelled => CliError::failure(anyhow!(
            "cancelled (Ctrl-C); `{}` was not written",
            output.display()
        )),
        e @ (FitError::Setting { .. } | FitError::Budget(_) | FitError::Memory(_)) => {
            CliError::bad_input(e)
        }
        e @ (FitError::Input(_) | FitError::Model(_)) => CliError::bad_input(e),
        e => CliError::failure(e),
    }
}

pub fn run(args: &FitArgs) -> Result<(), CliError> {
    if let Some(FitCommand::Merge(m)) = &args.command {
        return merge(m);
    }
    let (Some(input), Some(output)) = (&args.input, &args.output) else {
        return Err(CliError::bad_input(anyhow!(
            "meso fit needs IN.btf and -o OUT"
        )));
    };
    let max_memory = meso_fit::memory::parse_bytes(&args.max_memory)
        .map_err(|e| CliError::bad_input(anyhow!("--max-memory {e}")))?;
    let shard = args
        .shard
        .as_deref()
        .map(Shard::parse)
        .transpose()
        .map_err(|e| CliError::bad_input(anyhow!("--shard {e}")))?;
    let btf = OnDiskBtf::open(input).map_err(CliError::bad_input)?;
    let settings = FitSettings {
        clusters: args.clusters,
        subclusters: args.subclusters,
        max_bases: args.max_bases,
        npca: args.npca,
        seed: args.seed,
        fit_pairs: args.fit_pairs,
        max_bytes: args.max_bytes,
        precision: args.residual_precision(),
        sample_texels: args.sample_texels,
        residual_texels: args.residual_texels,
        max_memory,
        ..FitSettings::default()
    };
    let budget = args
        .max_bytes
        .map(|b| format!(" --max-bytes {b}"))
        .unwrap_or_default();
    let budget = match args.residual_precision() {
        ResidualPrecision::I8 => format!("{budget} --precision i8"),
        _ => budget,
    };
    let name = args
        .name
        .clone()
        .unwrap_or_else(|| TexelSource::name(&btf).to_string());
    let provenance = format!(
        "meso fit {} --clusters {} --subclusters {} --max-bases {} --npca {}{budget} --seed {}",
        file_name(input),
        args.clusters,
        args.subclusters,
        args.max_bases,
        args.npca,
        args.seed
    );
    let bar = ProgressLine::new();
    let progress = |s: meso_fit::Stage, d, n| bar.update(s.name(), d, n);
    if args.model_only {
        let result =
            meso_fit::find_model(&btf, &file_name(input), &settings, cancel_flag(), &progress);
        bar.finish();
        let model = result.map_err(|e| fit_error(e, output))?;
        let bytes = model.encode();
        meso_materials::atomic::write_bytes_atomic(output, &bytes)
            .failure_ctx(|| format!("writing `{}`", output.display()))?;
        if args.json {
            return crate::print_json(&serde_json::json!({
                "output": output.display().to_string(),
                "bytes": bytes.len(),
            }));
        }
        println!(
            "wrote {} (the fit's model, {} bytes); fit with `--model {}` and the same options",
            output.display(),
            bytes.len(),
            output.display()
        );
        return Ok(());
    }
    let model = args
        .model
        .as_deref()
        .map(|path| {
            meso_fit::FitModel::read(path)
                .map(|m| (m, path))
                .map_err(CliError::bad_input)
        })
        .transpose()?;
    let from = || match &model {
        Some((m, path)) => meso_fit::ModelFrom::File(Box::new(m.clone()), path),
        None => meso_fit::ModelFrom::Sample,
    };
    if let Some(shard) = shard {
        let result = meso_fit::fit_part_from(
            &btf,
            (&name, &provenance, &file_name(input)),
            &settings,
            shard,
            from(),
            cancel_flag(),
            &progress,
        );
        bar.finish();
        let part = result.map_err(|e| fit_error(e, output))?;
        let bytes = part.encode();
        meso_materials::atomic::write_bytes_atomic(output, &bytes)
            .failure_ctx(|| format!("writing `{}`", output.display()))?;
        let texels = shard.texels(btf.texels());
        if args.json {
            return crate::print_json(&serde_json::json!({
                "output": output.display().to_string(),
                "shard": shard.to_string(),
                "texels": [texels.start, texels.end],
                "bytes": bytes.len(),
                "texel_seconds": part.texel_seconds,
            }));
        }
        println!(
            "wrote {} (shard {shard}: texels {}..{} of {}, {} bytes); join every shard with `meso fit merge`",
            output.display(),
            texels.start,
            texels.end,
            btf.texels(),
            bytes.len()
        );
        return Ok(());
    }
    let result = meso_fit::fit_btf_from(
        &btf,
        (&name, &provenance),
        &settings,
        from(),
        cancel_flag(),
        &progress,
    );
    bar.finish();
    let out = result.map_err(|e| fit_error(e, output))?;
    write_pack(out, output, args.report.as_deref(), args.json)
}

/// `meso fit merge PART... -o OUT.spmm`.
fn merge(args: &MergeArgs) -> Result<(), CliError> {
    let out = meso_fit::merge(&args.parts).map_err(|e| match e {
        MergeFailure::Parts(p) => CliError::bad_input(p),
        MergeFailure::Fit(f) => fit_error(f, &args.output),
    })?;
    write_pack(out, &args.output, args.report.as_deref(), args.json)
}

/// Writes the pack atomically, then the report (JSON file, stdout).
fn write_pack(
    mut out: FitOutput,
    output: &Path,
    report: Option<&Path>,
    json: bool,
) -> Result<(), CliError> {
    let bytes = pack::encode_pack(&out.material, out.precision);
    out.report.set_pack_bytes(bytes.len() as u64);
    meso_materials::atomic::write_bytes_atomic(output, &bytes)
        .failure_ctx(|| format!("writing `{}`", output.display()))?;
    let report_json = serde_json::to_value(&out.report)
        .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
    if let Some(path) = report {
        let text = serde_json::to_string_pretty(&report_json)
            .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
        meso_materials::atomic::write_bytes_atomic(path, text.as_bytes())
            .failure_ctx(|| format!("writing `{}`", path.display()))?;
    }
    if json {
        let mut v = report_json;
        v["output"] = output.display().to_string().into();
        return crate::print_json(&v);
    }
    print!("{}", out.report.to_text());
    println!("wrote {}", output.display());
    Ok(())
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}
