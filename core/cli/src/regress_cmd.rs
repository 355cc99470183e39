//! `meso regress MANIFEST` (docs/regress.md): renders the manifest's cases, compares
//! each with its golden, writes the report (HTML, Markdown, report.json) and JUnit;
//! exit 0 when all pass, 1 when any fails, 2 on bad input. `meso regress merge`
//! joins shard reports. The work is `meso_reports::regress`.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::{Args, Subcommand};
use meso_materials::atomic::write_bytes_atomic;
use meso_reports::regress::{
    self, CaseReport, Pattern, RegressError, Report, RunRequest, Shard, UpdateRequest,
    report::junit,
};
use serde_json::json;

use crate::failure::CliError;

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct RegressArgs {
    #[command(subcommand)]
    command: Option<RegressCommand>,
    /// The manifest (docs/regress.md).
    #[arg(required = true)]
    manifest: Option<PathBuf>,
    /// Rewrite the goldens of the selected cases (atomically), logging --reason.
    #[arg(long)]
    update: bool,
    /// Why the goldens change (required with --update; recorded in the goldens' LOG.md).
    #[arg(long)]
    reason: Option<String>,
    /// Only cases whose name matches: globs with `*` and `?`, comma-separated.
    #[arg(long)]
    only: Option<String>,
    /// Cases rendered at once; each render uses the threads left.
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Threads in all (default: the machine's).
    #[arg(long)]
    threads: Option<usize>,
    /// Render only shard K of N (by hash of the case name): K/N, 1 <= K <= N.
    #[arg(long)]
    shard: Option<String>,
    /// Report folder: index.html, summary.md, report.json, images/.
    #[arg(short = 'o', long = "output")]
    report_dir: Option<PathBuf>,
    /// JUnit XML file for CI systems.
    #[arg(long)]
    junit: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand, Debug)]
enum RegressCommand {
    /// Join shard report folders into one report (and one JUnit file).
    Merge(MergeArgs),
}

#[derive(Args, Debug)]
struct MergeArgs {
    /// The shard runs' report folders.
    #[arg(required = true)]
    reports: Vec<PathBuf>,
    /// The merged report folder.
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
    #[arg(long)]
    junit: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

fn regress_error(e: RegressError) -> CliError {
    if e.is_bad_input() {
        CliError::bad_input(anyhow!(e))
    } else {
        CliError::failure(anyhow!(e))
    }
}

/// The command line as typed, quoted where a shell would need it (for logs).
fn command_line() -> String {
    std::env::args()
        .enumerate()
        .map(|(i, a)| {
            let a = if i == 0 { "meso".to_string() } else { a };
            if !a.is_empty()
                && a.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c))
            {
                a
            } else {
                format!("'{}'", a.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

pub fn run(args: &RegressArgs) -> Result<(), CliError> {
    if let Some(RegressCommand::Merge(m)) = &args.command {
        return merge(m);
    }
    let manifest_path = args.manifest.as_ref().expect("clap requires it");
    if args.jobs == 0 {
        return Err(CliError::bad_input(anyhow!("--jobs must be at least 1")));
    }
    if args.threads == Some(0) {
        return Err(CliError::bad_input(anyhow!("--threads must be at least 1")));
    }
    let update = match (args.update, &args.reason) {
        (true, Some(r)) if !r.trim().is_empty() => Some(UpdateRequest {
            reason: r.trim().to_string(),
            command: command_line(),
        }),
        (true, _) => {
            return Err(CliError::bad_input(anyhow!(
                "--update needs --reason TEXT (recorded in the goldens' LOG.md)"
            )));
        }
        (false, Some(_)) => {
            return Err(CliError::bad_input(anyhow!(
                "--reason only goes with --update"
            )));
        }
        (false, None) => None,
    };
    let only = args
        .only
        .as_deref()
        .map(Pattern::parse)
        .transpose()
        .map_err(|e| CliError::bad_input(anyhow!("--only {e}")))?;
    let shard = args
        .shard
        .as_deref()
        .map(Shard::parse)
        .transpose()
        .map_err(|e| CliError::bad_input(anyhow!("--shard {e}")))?;
    let manifest = regress::load_manifest(manifest_path).map_err(CliError::bad_input)?;
    let threads = args.threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let progress = std::io::stderr().is_terminal() && !args.json;
    let on_case = |c: &CaseReport, done: usize, total: usize| {
        if progress {
            eprintln!(
                "[{done}/{total}] {:7} {}{}",
                c.status.name().to_uppercase(),
                c.name,
                c.seconds
                    .map(|s| format!(" ({s:.2} s)"))
                    .unwrap_or_default()
            );
        }
    };
    let report = regress::run_manifest(
        &manifest,
        &RunRequest {
            only: only.as_ref(),
            shard,
            jobs: args.jobs,
            threads,
            update: update.as_ref(),
            report_dir: args.report_dir.as_deref(),
            command: command_line(),
            on_case: &on_case,
        },
    )
    .map_err(regress_error)?;
    if let Some(path) = &args.junit {
        write_junit(path, &report)?;
    }
    finish(
        &report,
        args.report_dir.as_deref(),
        args.junit.as_deref(),
        args.json,
    )
}

fn merge(args: &MergeArgs) -> Result<(), CliError> {
    let report = regress::merge::merge(&args.reports, &args.output, &command_line())
        .map_err(regress_error)?;
    if let Some(path) = &args.junit {
        write_junit(path, &report)?;
    }
    finish(
        &report,
        Some(&args.output),
        args.junit.as_deref(),
        args.json,
    )
}

fn write_junit(path: &Path, report: &Report) -> Result<(), CliError> {
    write_bytes_atomic(path, junit::render(report).as_bytes())
        .map_err(|e| CliError::failure(anyhow!(e).context("writing the JUnit file")))
}

/// Prints the outcome and turns failed cases into exit 1.
fn finish(
    report: &Report,
    report_dir: Option<&Path>,
    junit: Option<&Path>,
    as_json: bool,
) -> Result<(), CliError> {
    let c = report.counts();
    if as_json {
        crate::print_json(&json!({
            "manifest": report.manifest,
            "shard": report.shard.map(|s| s.to_string()),
            "merged_shards": report.merged_shards.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
            "total": c.total,
            "failed": c.failed,
            "skipped": c.skipped,
            "updated": c.updated,
            "passed": c.passed,
            "wall_seconds": report.wall_seconds,
            "report_dir": report_dir.map(|d| d.display().to_string()),
            "junit": junit.map(|d| d.display().to_string()),
            "cases": report.cases,
        }))?;
    } else {
        for case in &report.cases {
            if matches!(
                case.status,
                regress::Status::Fail | regress::Status::Skipped
            ) {
                println!(
                    "{:7} {}: {}",
                    case.status.name().to_uppercase(),
                    case.name,
                    case.message.as_deref().unwrap_or("")
                );
            }
        }
        println!(
            "{} cases: {} failed, {} skipped, {} updated, {} passed ({:.1} s){}",
            c.total,
            c.failed,
            c.skipped,
            c.updated,
            c.passed,
            report.wall_seconds,
            report_dir
                .map(|d| format!(
                    "; report {}",
                    d.join(regress::report::REPORT_HTML).display()
                ))
                .unwrap_or_default()
        );
    }
    if c.failed > 0 {
        let names: Vec<&str> = report
            .cases
            .iter()
            .filter(|c| c.status == regress::Status::Fail)
            .map(|c| c.name.as_str())
            .collect();
        // The first ten by name; the report lists them all.
        const SHOWN: usize = 10;
        let more = names.len().saturating_sub(SHOWN);
        return Err(CliError::failure(anyhow!(
            "{} of {} cases failed: {}{}",
            c.failed,
            c.total,
            names[..names.len().min(SHOWN)].join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        )));
    }
    Ok(())
}
