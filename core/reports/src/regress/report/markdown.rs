//! The report as a Markdown summary (for CI job summaries and pull-request comments):
//! counts, each mode's speed and error, and one row per case, failures first, with
//! its thumbnails linked relatively.

use super::{Report, number};

/// `|` would end a table cell.
fn cell(text: &str) -> String {
    text.replace('|', "\\|").replace('\n', " ")
}

pub fn render(report: &Report) -> String {
    let c = report.counts();
    let mut md = format!(
        "# Regression renders: `{}`\n\n**{} failed** of {} cases ({} skipped, {} updated, {} passed). Meso {}, {}, {} job(s) on {} thread(s), {:.1} s wall{}.\n\n",
        report.manifest,
        c.failed,
        c.total,
        c.skipped,
        c.updated,
        c.passed,
        report.meso_version,
        report.date_utc,
        report.jobs,
        report.threads,
        report.wall_seconds,
        report
            .shard
            .map(|s| format!(", shard {s}"))
            .unwrap_or_default(),
    );
    md.push_str("## Speed and error of each mode\n\n| mode | device | cases | total s | s per case | Mrays/s | mean relative RMSE | worst relative RMSE | worst MSSIM |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for m in report.mode_summaries() {
        let opt = |v: Option<f64>| v.map_or("-".to_string(), number);
        md.push_str(&format!(
            "| {} | {} | {} | {:.3} | {:.3} | {} | {} | {} | {} |\n",
            m.mode,
            m.device,
            m.rendered,
            m.total_seconds,
            m.mean_seconds,
            m.mrays_per_second
                .map_or("-".to_string(), |v| format!("{v:.2}")),
            opt(m.mean_relative_rmse),
            opt(m.worst_relative_rmse),
            opt(m.worst_mssim),
        ));
    }
    md.push_str("\n## Cases\n\n| status | case | relative RMSE (max) | MSSIM (min) | render s | golden | new | difference (scale) | note |\n|---|---|---:|---:|---:|---|---|---|---|\n");
    for case in &report.cases {
        let m = case.metrics;
        let rel = m.map_or("-".to_string(), |m| {
            m.relative_rmse.map_or("inf".to_string(), number)
        });
        let rel_bound = case
            .tolerance
            .max_relative_rmse
            .map_or(String::new(), |v| format!(" ({})", number(v)));
        let mssim = m.map_or("-".to_string(), |m| format!("{:.5}", m.mssim));
        let mssim_bound = case
            .tolerance
            .min_mssim
            .map_or(String::new(), |v| format!(" ({v})"));
        let img = |p: &Option<String>| p.as_ref().map_or("-".to_string(), |p| format!("![]({p})"));
        let diff = match case.diff_scale {
            Some(s) => format!("{} (0 to {})", img(&case.diff_png), number(s)),
            None => "-".to_string(),
        };
        md.push_str(&format!(
            "| **{}** | `{}` | {rel}{rel_bound} | {mssim}{mssim_bound} | {} | {} | {} | {diff} | {} |\n",
            case.status.name().to_uppercase(),
            case.name,
            case.seconds.map_or("-".to_string(), |s| format!("{s:.3}")),
            img(&case.golden_png),
            img(&case.new_png),
            cell(case.message.as_deref().unwrap_or("")),
        ));
    }
    md
}

#[cfg(test)]
mod tests {
    use super::super::tests::sample_report;
    use super::*;

    #[test]
    fn the_summary_has_one_row_per_case_failures_first() {
        let md = render(&sample_report());
        let rows: Vec<&str> = md.lines().filter(|l| l.starts_with("| **")).collect();
        assert_eq!(rows.len(), 4, "{md}");
        assert!(rows[0].contains("`z.fail`") && rows[0].contains("**FAIL**"));
        assert!(rows[1].contains("`c.skip`"));
        assert!(rows[0].contains("![](images/z.fail.diff.png) (0 to 0.5000)"));
        assert!(md.contains("**1 failed** of 4 cases"));
    }
}
