//! Scripted regression renders (docs/regress.md): a manifest of scenes x material
//! substitutions x modes x devices (`manifest`, `case`), selected by pattern and shard
//! (`select`, `shard`), rendered and compared with golden EXRs (`run`, `golden`), and
//! reported as HTML, Markdown and JUnit (`report`); shard reports join with `merge`.
//! The `meso regress` command is a thin shell over `run_manifest` and `merge::merge`.

pub mod case;
pub mod golden;
pub mod manifest;
pub mod merge;
pub mod report;
pub mod run;
pub mod select;
pub mod shard;

use std::path::Path;
use std::time::{Instant, SystemTime};

pub use case::{Case, Tolerance};
pub use golden::UpdateRequest;
pub use manifest::{Manifest, ManifestError, load_manifest};
pub use report::{CaseReport, Report, Status};
pub use select::Pattern;
pub use shard::Shard;

/// Why a regression run could not be made (not: a case failed, which is a report).
#[derive(Debug, thiserror::Error)]
pub enum RegressError {
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    /// A case whose inputs do not load (scene, substitution, replaced material).
    #[error("case `{case}` ({origin}): {message}")]
    Case {
        case: String,
        origin: String,
        message: String,
    },
    #[error("{0}")]
    Usage(String),
    /// Report folders that cannot be merged.
    #[error("{0}")]
    Merge(String),
    /// Something could not be written (goldens, report).
    #[error("cannot write {what}: {message}")]
    Output { what: String, message: String },
}

impl RegressError {
    /// True for bad input or usage (exit 2); false for failures to write (exit 1).
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, RegressError::Output { .. })
    }
}

/// What to run and how.
pub struct RunRequest<'a> {
    pub only: Option<&'a Pattern>,
    pub shard: Option<Shard>,
    pub jobs: usize,
    pub threads: usize,
    pub update: Option<&'a UpdateRequest>,
    pub report_dir: Option<&'a Path>,
    /// The command line, recorded in the report.
    pub command: String,
    pub on_case: &'a (dyn Fn(&CaseReport, usize, usize) + Sync),
}

/// Runs the selected cases of `manifest` and returns the sorted report (also written
/// to `report_dir` when given). A pattern that selects nothing is a usage error; a
/// shard may hold no case.
pub fn run_manifest(manifest: &Manifest, request: &RunRequest) -> Result<Report, RegressError> {
    let start = Instant::now();
    let selected = select::select(&manifest.cases, request.only, request.shard);
    if let Some(p) = request.only
        && select::select(&manifest.cases, request.only, None).is_empty()
    {
        return Err(RegressError::Usage(format!(
            "--only `{p}` matches no case of `{}` (its cases: {})",
            manifest.path.display(),
            manifest
                .cases
                .iter()
                .map(|c| c.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    let cases = run::run(
        manifest,
        &selected,
        &run::RunOptions {
            jobs: request.jobs,
            threads: request.threads,
            update: request.update,
            report_dir: request.report_dir,
            on_case: request.on_case,
        },
    )?;
    let mut report = Report {
        format: report::REPORT_FORMAT.into(),
        version: report::REPORT_VERSION,
        meso_version: env!("CARGO_PKG_VERSION").into(),
        manifest: manifest.path.display().to_string(),
        manifest_digest: manifest.digest.clone(),
        shard: request.shard,
        merged_shards: Vec::new(),
        date_utc: golden::utc_timestamp(SystemTime::now()),
        command: request.command.clone(),
        wall_seconds: start.elapsed().as_secs_f64(),
        jobs: request.jobs.max(1),
        threads: request.threads.max(1),
        cases,
    };
    report.sort();
    if let Some(dir) = request.report_dir {
        report.write(dir).map_err(|e| RegressError::Output {
            what: format!("the report in `{}`", dir.display()),
            message: e.to_string(),
        })?;
    }
    Ok(report)
}
