//! The regression report: one record per case (status, metrics, times, its images),
//! kept as `report.json` in the report folder so shard reports can be merged, and
//! rendered from that record alone as a static HTML page (`html`), a Markdown summary
//! (`markdown`) and JUnit XML (`junit`). Thumbnails and heat maps are PNGs under
//! `images/` (`images`).

pub mod html;
pub mod images;
pub mod junit;
pub mod markdown;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::case::Tolerance;
use super::shard::Shard;
use meso_materials::atomic::write_bytes_atomic;

/// `format` of every report.json.
pub const REPORT_FORMAT: &str = "meso-regress-report";
pub const REPORT_VERSION: u32 = 1;
/// File names inside a report folder.
pub const REPORT_JSON: &str = "report.json";
pub const REPORT_HTML: &str = "index.html";
pub const REPORT_MARKDOWN: &str = "summary.md";
pub const IMAGES_DIR: &str = "images";

/// How a case ended. The order is the report's: failures first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Outside its tolerance, no golden, or a golden it cannot be compared with.
    Fail,
    /// Not rendered: the mode is not built, or cannot render the case (no golden yet).
    Skipped,
    /// Rendered with `--update`: its golden was rewritten.
    Updated,
    Pass,
}

impl Status {
    pub fn name(self) -> &'static str {
        match self {
            Status::Fail => "fail",
            Status::Skipped => "skipped",
            Status::Updated => "updated",
            Status::Pass => "pass",
        }
    }
}

/// The error of the new render against the golden.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CaseMetrics {
    pub rmse: f64,
    /// RMSE over the golden's mean over pixels and channels; `None` for a black
    /// golden with a non-black render (infinite).
    pub relative_rmse: Option<f64>,
    /// `None` when the images are identical (infinite PSNR).
    pub psnr_db: Option<f64>,
    pub mssim: f64,
    pub max_abs_error: f64,
    /// Bit for bit the same pixels.
    pub identical: bool,
}

/// One case's row.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CaseReport {
    pub name: String,
    pub scene: String,
    pub material: String,
    pub mode: String,
    pub device: String,
    /// Size and frames rendered (0 when the case was skipped before the scene said).
    pub width: u32,
    pub height: u32,
    pub frames: u32,
    pub status: Status,
    /// Why it failed or was skipped; notes (dropped samples) otherwise.
    pub message: Option<String>,
    pub tolerance: Tolerance,
    pub metrics: Option<CaseMetrics>,
    /// Preparation plus frames, and the frames alone.
    pub seconds: Option<f64>,
    pub trace_seconds: Option<f64>,
    pub rays: Option<u64>,
    pub nonfinite_dropped: Option<u64>,
    /// Paths relative to the report folder.
    pub golden_png: Option<String>,
    pub new_png: Option<String>,
    pub diff_png: Option<String>,
    /// The per-pixel error the top of the heat map's colour scale stands for.
    pub diff_scale: Option<f64>,
}

/// A whole run (or a merge of shard runs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub format: String,
    pub version: u32,
    pub meso_version: String,
    /// The manifest as named on the command line.
    pub manifest: String,
    pub manifest_digest: String,
    /// The shard this run rendered; `None` for a whole run or a merge.
    pub shard: Option<Shard>,
    /// The shards a merged report joins (empty otherwise).
    pub merged_shards: Vec<Shard>,
    pub date_utc: String,
    pub command: String,
    /// Wall-clock time of the run (of the longest shard for a merge).
    pub wall_seconds: f64,
    pub jobs: usize,
    pub threads: usize,
    /// Sorted: failures first, then skipped, updated, passed; by name within each.
    pub cases: Vec<CaseReport>,
}

/// Case counts by status.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub total: usize,
    pub failed: usize,
    pub skipped: usize,
    pub updated: usize,
    pub passed: usize,
}

/// Speed and error of one mode and device over the cases it rendered.
#[derive(Clone, Debug, PartialEq)]
pub struct ModeSummary {
    pub mode: String,
    pub device: String,
    pub rendered: usize,
    pub total_seconds: f64,
    pub mean_seconds: f64,
    /// Rays per second over the frames of every case (modes that trace rays).
    pub mrays_per_second: Option<f64>,
    pub mean_relative_rmse: Option<f64>,
    pub worst_relative_rmse: Option<f64>,
    pub worst_mssim: Option<f64>,
}

impl Report {
    /// Orders the cases as reports show them: failures first.
    pub fn sort(&mut self) {
        self.cases
            .sort_by(|a, b| (a.status, &a.name).cmp(&(b.status, &b.name)));
    }

    pub fn counts(&self) -> Counts {
        let mut c = Counts {
            total: self.cases.len(),
            ..Counts::default()
        };
        for case in &self.cases {
            match case.status {
                Status::Fail => c.failed += 1,
                Status::Skipped => c.skipped += 1,
                Status::Updated => c.updated += 1,
                Status::Pass => c.passed += 1,
            }
        }
        c
    }

    /// Speed against error per mode and device, in name order.
    pub fn mode_summaries(&self) -> Vec<ModeSummary> {
        let mut groups: BTreeMap<(&str, &str), Vec<&CaseReport>> = BTreeMap::new();
        for c in &self.cases {
            if c.seconds.is_some() {
                groups.entry((&c.mode, &c.device)).or_default().push(c);
            }
        }
        groups
            .into_iter()
            .map(|((mode, device), cases)| {
                let total: f64 = cases.iter().filter_map(|c| c.seconds).sum();
                let trace: f64 = cases.iter().filter_map(|c| c.trace_seconds).sum();
                let rays: u64 = cases.iter().filter_map(|c| c.rays).sum();
                let rel: Vec<f64> = cases
                    .iter()
                    .filter_map(|c| c.metrics.and_then(|m| m.relative_rmse))
                    .collect();
                let mssim: Vec<f64> = cases
                    .iter()
                    .filter_map(|c| c.metrics.map(|m| m.mssim))
                    .collect();
                ModeSummary {
                    mode: mode.to_string(),
                    device: device.to_string(),
                    rendered: cases.len(),
                    total_seconds: total,
                    mean_seconds: total / cases.len() as f64,
                    mrays_per_second: (rays > 0 && trace > 0.0).then(|| rays as f64 / trace / 1e6),
                    mean_relative_rmse: (!rel.is_empty())
                        .then(|| rel.iter().sum::<f64>() / rel.len() as f64),
                    worst_relative_rmse: rel.iter().copied().reduce(f64::max),
                    worst_mssim: mssim.iter().copied().reduce(f64::min),
                }
            })
            .collect()
    }

    /// Reads a report folder's `report.json`, checking its format and version.
    pub fn read(dir: &Path) -> Result<Report, ReportError> {
        let path = dir.join(REPORT_JSON);
        let text = std::fs::read_to_string(&path).map_err(|source| ReportError::Read {
            path: path.clone(),
            source,
        })?;
        let report: Report = serde_json::from_str(&text).map_err(|e| ReportError::Parse {
            path: path.clone(),
            message: e.to_string(),
        })?;
        if report.format != REPORT_FORMAT || report.version != REPORT_VERSION {
            return Err(ReportError::Parse {
                path,
                message: format!(
                    "format `{}` version {}: expected `{REPORT_FORMAT}` version {REPORT_VERSION}",
                    report.format, report.version
                ),
            });
        }
        Ok(report)
    }

    /// Writes `report.json`, the HTML page and the Markdown summary into `dir` (the
    /// images are already there), each atomically.
    pub fn write(&self, dir: &Path) -> Result<(), ReportError> {
        std::fs::create_dir_all(dir).map_err(|source| ReportError::Folder {
            path: dir.to_path_buf(),
            source,
        })?;
        let json = serde_json::to_string_pretty(self).expect("a report always encodes");
        write_bytes_atomic(&dir.join(REPORT_JSON), json.as_bytes())?;
        write_bytes_atomic(&dir.join(REPORT_HTML), html::render(self).as_bytes())?;
        write_bytes_atomic(
            &dir.join(REPORT_MARKDOWN),
            markdown::render(self).as_bytes(),
        )?;
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("cannot read the report `{}`: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("`{}` is not a regression report: {message}", path.display())]
    Parse { path: PathBuf, message: String },
    #[error("cannot create the report folder `{}`: {source}", path.display())]
    Folder {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot copy `{}` to `{}`: {source}", from.display(), to.display())]
    Copy {
        from: PathBuf,
        to: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Write(#[from] meso_materials::atomic::AtomicWriteError),
}

/// Escapes text for HTML and XML (element content and attribute values).
pub(crate) fn escape_xml(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for ch in text.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            // XML 1.0 allows no other control characters.
            c if (c as u32) < 0x20 && !matches!(c, '\t' | '\n' | '\r') => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

/// A number for tables: scientific below 1e-3, else 4 significant decimals.
pub(crate) fn number(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() < 1e-3 || v.abs() >= 1e6 {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A report of three cases, one per status that renders, for the renderers' tests.
    pub(crate) fn sample_report() -> Report {
        let case = |name: &str, status: Status, rel: f64| CaseReport {
            name: name.into(),
            scene: "default".into(),
            material: "leather".into(),
            mode: "spmm".into(),
            device: "cpu".into(),
            width: 64,
            height: 64,
            frames: 4,
            status,
            message: (status == Status::Fail).then(|| "relative RMSE 2e-1 > 0.05 & <x>".into()),
            tolerance: Tolerance {
                max_relative_rmse: Some(0.05),
                min_mssim: None,
            },
            metrics: Some(CaseMetrics {
                rmse: rel * 0.1,
                relative_rmse: Some(rel),
                psnr_db: Some(30.0),
                mssim: 0.99,
                max_abs_error: 0.5,
                identical: rel == 0.0,
            }),
            seconds: Some(0.5),
            trace_seconds: Some(0.25),
            rays: Some(1_000_000),
            nonfinite_dropped: Some(0),
            golden_png: Some(format!("images/{name}.golden.png")),
            new_png: Some(format!("images/{name}.new.png")),
            diff_png: Some(format!("images/{name}.diff.png")),
            diff_scale: Some(0.5),
        };
        let mut r = Report {
            format: REPORT_FORMAT.into(),
            version: REPORT_VERSION,
            meso_version: "0.1.0".into(),
            manifest: "m.toml".into(),
            manifest_digest: "0".into(),
            shard: None,
            merged_shards: vec![],
            date_utc: "2026-01-01T00:00:00Z".into(),
            command: "meso regress m.toml".into(),
            wall_seconds: 1.0,
            jobs: 1,
            threads: 2,
            cases: vec![
                case("b.pass", Status::Pass, 0.0),
                case("a.pass", Status::Pass, 0.01),
                case("z.fail", Status::Fail, 0.2),
            ],
        };
        r.cases.push(CaseReport {
            status: Status::Skipped,
            message: Some("the biscale mode on the cpu is not built yet".into()),
            metrics: None,
            seconds: None,
            trace_seconds: None,
            rays: None,
            golden_png: None,
            new_png: None,
            diff_png: None,
            diff_scale: None,
            mode: "biscale".into(),
            ..r.cases[0].clone()
        });
        r.cases[3].name = "c.skip".into();
        r.sort();
        r
    }

    #[test]
    fn failures_come_first_then_skipped_then_passes_by_name() {
        let r = sample_report();
        let names: Vec<&str> = r.cases.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["z.fail", "c.skip", "a.pass", "b.pass"]);
        let c = r.counts();
        assert_eq!((c.total, c.failed, c.skipped, c.passed), (4, 1, 1, 2));
    }

    #[test]
    fn mode_summaries_count_only_rendered_cases() {
        let s = sample_report().mode_summaries();
        assert_eq!(s.len(), 1, "the skipped biscale case rendered nothing");
        assert_eq!(s[0].rendered, 3);
        assert!((s[0].total_seconds - 1.5).abs() < 1e-12);
        // 3e6 rays over 0.75 s of frames.
        assert!((s[0].mrays_per_second.expect("rays") - 4.0).abs() < 1e-9);
        assert_eq!(s[0].worst_relative_rmse, Some(0.2));
        assert!((s[0].mean_relative_rmse.expect("some") - 0.07).abs() < 1e-12);
    }

    #[test]
    fn escaping_covers_markup_and_control_characters() {
        assert_eq!(
            escape_xml("a<b>&\"c'\u{1}"),
            "a&lt;b&gt;&amp;&quot;c&apos; "
        );
    }
}
