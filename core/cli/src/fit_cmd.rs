//! `meso fit IN.btf -o OUT.spmm`: fit an SPMM pack to a BTF (core::fit), print the
//! fit report (text, or one JSON object with --json), optionally save it as JSON.
//! Ctrl-C stops between work items and leaves no output file.

use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::Args;
use meso_fit::{FitError, FitSettings};
use meso_materials::spmm::pack::{self, ResidualPrecision};

use crate::failure::{CliError, ResultExt};
use crate::progress::{ProgressLine, cancel_flag};

#[derive(Args, Debug)]
pub struct FitArgs {
    /// The BTF to fit (.btf).
    input: PathBuf,
    #[arg(short = 'o', long)]
    output: PathBuf,
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
    /// Name of the material (default: the BTF's).
    #[arg(long)]
    name: Option<String>,
    /// Write the report as JSON here as well.
    #[arg(long)]
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

pub fn run(args: &FitArgs) -> Result<(), CliError> {
    let btf = crate::btf_cmd::load(&args.input)?;
    let settings = FitSettings {
        clusters: args.clusters,
        subclusters: args.subclusters,
        max_bases: args.max_bases,
        npca: args.npca,
        seed: args.seed,
        fit_pairs: args.fit_pairs,
        max_bytes: args.max_bytes,
        precision: args.residual_precision(),
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
    let name = args.name.clone().unwrap_or_else(|| btf.name().to_string());
    let provenance = format!(
        "meso fit {} --clusters {} --subclusters {} --max-bases {} --npca {}{budget} --seed {}",
        file_name(&args.input),
        args.clusters,
        args.subclusters,
        args.max_bases,
        args.npca,
        args.seed
    );
    let bar = ProgressLine::new();
    let result = meso_fit::fit_btf(
        &btf,
        &name,
        &provenance,
        &settings,
        cancel_flag(),
        &|s, d, n| bar.update(s.name(), d, n),
    );
    bar.finish();
    let mut out = match result {
        Ok(o) => o,
        Err(FitError::Cancelled) => {
            return Err(CliError::failure(anyhow!(
                "cancelled (Ctrl-C); `{}` was not written",
                args.output.display()
            )));
        }
        Err(e @ (FitError::Setting { .. } | FitError::Budget(_))) => {
            return Err(CliError::bad_input(e));
        }
        Err(e) => return Err(CliError::failure(e)),
    };
    let bytes = pack::encode_pack(&out.material, args.residual_precision());
    out.report.set_pack_bytes(bytes.len() as u64);
    meso_materials::atomic::write_bytes_atomic(&args.output, &bytes)
        .failure_ctx(|| format!("writing `{}`", args.output.display()))?;
    let report_json = serde_json::to_value(&out.report)
        .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
    if let Some(path) = &args.report {
        let text = serde_json::to_string_pretty(&report_json)
            .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
        meso_materials::atomic::write_bytes_atomic(path, text.as_bytes())
            .failure_ctx(|| format!("writing `{}`", path.display()))?;
    }
    if args.json {
        let mut v = report_json;
        v["output"] = args.output.display().to_string().into();
        return crate::print_json(&v);
    }
    print!("{}", out.report.to_text());
    println!("wrote {}", args.output.display());
    Ok(())
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}
