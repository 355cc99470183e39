//! `meso`: the headless command line (docs/cli.md). Every subcommand prints one
//! `error:` line on failure and exits 2 for bad input or usage, 1 for anything else;
//! `--json` prints exactly one JSON object on stdout.

mod bench_btf;
mod bench_cmd;
mod bench_edits;
mod bench_frames;
mod bench_stroke;
mod brdf_cmd;
mod btf_cmd;
mod compare_cmd;
mod embree;
mod failure;
mod fit_cmd;
mod merl_cmd;
mod mode_args;
mod pack_cmd;
mod pack_edit_cmd;
mod plot;
mod precompute_cmd;
mod progress;
mod recover_cmd;
mod regress_cmd;
mod render_cmd;
mod report_cmd;
mod report_fit_cmd;
mod svg_chart;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use failure::CliError;

#[derive(Parser, Debug)]
#[command(
    name = "meso",
    version,
    about = "Meso: headless material rendering tools"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// The analytic BRDF dictionary: evaluate, measure albedo, plot lobes.
    Brdf {
        #[command(subcommand)]
        command: brdf_cmd::BrdfCommand,
    },
    /// Benchmarks on fixed inputs, comparable with other tools: ray throughput.
    Bench {
        #[command(subcommand)]
        command: bench_cmd::BenchCommand,
    },
    /// Image error of B against the reference A: RMSE, PSNR, MSSIM, largest pixel error.
    Compare(compare_cmd::CompareArgs),
    /// Bidirectional texture functions (.btf): synthesize, import, summarise, slice.
    Btf {
        #[command(subcommand)]
        command: btf_cmd::BtfCommand,
    },
    /// Fit an SPMM pack to a BTF (clusters, dictionaries, sparse weights, PCA residual).
    Fit(fit_cmd::FitArgs),
    /// Measured BRDFs in the MERL binary format: summarise, validate, evaluate, tabulate.
    Merl {
        #[command(subcommand)]
        command: merl_cmd::MerlCommand,
    },
    /// A render mode's precomputation (biscale: transfer matrices and biclusters).
    Precompute(precompute_cmd::PrecomputeArgs),
    /// Progressive render of a scene file in a render mode to EXR or PNG.
    Render(render_cmd::RenderArgs),
    /// The studio's recovery journals: list sessions, write a journal's pack, discard.
    Recover {
        #[command(subcommand)]
        command: recover_cmd::RecoverCommand,
    },
    /// Regression renders over a manifest, compared with goldens; `merge` joins shards.
    Regress(regress_cmd::RegressArgs),
    /// Reports: speed against error of the render modes.
    Report {
        #[command(subcommand)]
        command: report_cmd::ReportCommand,
    },
    /// SPMM material packs (.spmm): summarise, validate, build, preview, evaluate, edit.
    Pack {
        #[command(subcommand)]
        command: pack_cmd::PackCommand,
    },
}

fn main() -> ExitCode {
    restore_sigpipe();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(err) => return failure::report_clap_error(err),
    };
    let result = match cli.command {
        Command::Bench { command } => bench_cmd::run(command),
        Command::Brdf { command } => brdf_cmd::run(command),
        Command::Btf { command } => btf_cmd::run(command),
        Command::Fit(args) => fit_cmd::run(&args),
        Command::Compare(args) => compare_cmd::run(&args),
        Command::Merl { command } => merl_cmd::run(command),
        Command::Pack { command } => pack_cmd::run(command),
        Command::Precompute(args) => precompute_cmd::run(&args),
        Command::Render(args) => render_cmd::run(&args),
        Command::Recover { command } => recover_cmd::run(command),
        Command::Regress(args) => regress_cmd::run(&args),
        Command::Report { command } => report_cmd::run(command),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => failure::report(&err),
    }
}

/// Shared by subcommands: prints `value` as the one JSON object on stdout.
fn print_json(value: &serde_json::Value) -> Result<(), CliError> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| CliError::failure(anyhow::anyhow!("cannot encode the JSON report: {e}")))?;
    println!("{text}");
    Ok(())
}

/// Rust ignores SIGPIPE, so writing to a closed pipe (`meso pack info X | head`) would
/// make `println!` panic. Command-line tools end quietly instead: restore the default.
fn restore_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first thing in `main`, before any other thread exists; setting a
    // signal's disposition to its default has no other effect on the process.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
