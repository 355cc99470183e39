//! `meso regress merge`: joins the report folders of shard runs into one report (page,
//! summary, report.json, and the caller's JUnit file). The shards must come from the
//! same manifest (same digest) and Meso version, be of one split `N`, and be complete
//! (every `K` of `1..=N` once); no case may appear twice.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use super::RegressError;
use super::golden::utc_timestamp;
use super::report::{REPORT_FORMAT, REPORT_VERSION, Report};
use meso_materials::atomic::write_bytes_atomic;

/// Reads the reports in `dirs`, checks they are the shards of one run, copies their
/// pictures into `out` and writes the merged report there. `command` is recorded.
pub fn merge(dirs: &[PathBuf], out: &Path, command: &str) -> Result<Report, RegressError> {
    if dirs.is_empty() {
        return Err(RegressError::Usage(
            "merge needs at least one report folder".into(),
        ));
    }
    let bad = |message: String| RegressError::Merge(message);
    let mut reports = Vec::new();
    for dir in dirs {
        reports.push(Report::read(dir).map_err(|e| bad(e.to_string()))?);
    }
    let first = &reports[0];
    for (dir, r) in dirs.iter().zip(&reports).skip(1) {
        if r.manifest_digest != first.manifest_digest {
            return Err(bad(format!(
                "`{}` comes from another manifest (digest {}) than `{}` (digest {}): shards must render the same manifest",
                dir.display(),
                r.manifest_digest,
                dirs[0].display(),
                first.manifest_digest
            )));
        }
        if r.meso_version != first.meso_version {
            return Err(bad(format!(
                "`{}` was rendered by Meso {}, `{}` by Meso {}",
                dir.display(),
                r.meso_version,
                dirs[0].display(),
                first.meso_version
            )));
        }
    }
    let mut shards = Vec::new();
    for (dir, r) in dirs.iter().zip(&reports) {
        let Some(s) = r.shard else {
            return Err(bad(format!(
                "`{}` is not a shard report (it was run without --shard)",
                dir.display()
            )));
        };
        if let Some(other) = shards
            .iter()
            .find(|o: &&super::shard::Shard| o.count != s.count)
        {
            return Err(bad(format!(
                "`{}` is shard {s} but another folder is shard {other}: one split N per merge",
                dir.display()
            )));
        }
        if shards.contains(&s) {
            return Err(bad(format!(
                "shard {s} is given twice (again in `{}`)",
                dir.display()
            )));
        }
        shards.push(s);
    }
    shards.sort_by_key(|s| s.index);
    let count = shards[0].count;
    let missing: Vec<String> = (1..=count)
        .filter(|k| !shards.iter().any(|s| s.index == *k))
        .map(|k| format!("{k}/{count}"))
        .collect();
    if !missing.is_empty() {
        return Err(bad(format!("shard(s) {} missing", missing.join(", "))));
    }
    let mut cases = Vec::new();
    let mut from: Vec<(&str, &Path)> = Vec::new();
    for (dir, r) in dirs.iter().zip(&reports) {
        for c in &r.cases {
            if let Some((_, d)) = from.iter().find(|(n, _)| *n == c.name) {
                return Err(bad(format!(
                    "case `{}` is in both `{}` and `{}`",
                    c.name,
                    d.display(),
                    dir.display()
                )));
            }
            from.push((&c.name, dir));
            cases.push(c.clone());
        }
    }
    std::fs::create_dir_all(out.join(super::report::IMAGES_DIR)).map_err(|e| {
        RegressError::Output {
            what: format!("the report folder `{}`", out.display()),
            message: e.to_string(),
        }
    })?;
    for (dir, r) in dirs.iter().zip(&reports) {
        for c in &r.cases {
            for rel in [&c.golden_png, &c.new_png, &c.diff_png]
                .into_iter()
                .flatten()
            {
                // Read whole, then write atomically: safe even when `out` is `dir`.
                let src = dir.join(rel);
                let bytes = std::fs::read(&src)
                    .map_err(|e| bad(format!("`{}` of case `{}`: {e}", src.display(), c.name)))?;
                write_bytes_atomic(&out.join(rel), &bytes).map_err(|e| RegressError::Output {
                    what: format!("`{}`", out.join(rel).display()),
                    message: e.to_string(),
                })?;
            }
        }
    }
    let mut merged = Report {
        format: REPORT_FORMAT.into(),
        version: REPORT_VERSION,
        meso_version: first.meso_version.clone(),
        manifest: first.manifest.clone(),
        manifest_digest: first.manifest_digest.clone(),
        shard: None,
        merged_shards: shards,
        date_utc: utc_timestamp(SystemTime::now()),
        command: command.to_string(),
        wall_seconds: reports.iter().map(|r| r.wall_seconds).fold(0.0, f64::max),
        jobs: first.jobs,
        threads: first.threads,
        cases,
    };
    merged.sort();
    merged.write(out).map_err(|e| RegressError::Output {
        what: format!("the report in `{}`", out.display()),
        message: e.to_string(),
    })?;
    Ok(merged)
}
