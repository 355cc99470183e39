//! The report as one static HTML page: no script, no network, images by relative
//! path, so it opens from the file system and from a CI artifact alike. Summary, the
//! speed and error of each mode, then one row per case, failures first, each with its
//! golden, new render and heat map (with the error its top colour stands for).

use super::images::VIRIDIS;
use super::{CaseReport, Report, escape_xml as esc, number};

const STYLE: &str = "
body { font: 14px/1.4 system-ui, sans-serif; margin: 1.5em; color: #111; background: #fff; }
h1 { font-size: 1.4em; margin: 0 0 0.3em; }
h2 { font-size: 1.1em; margin: 1.4em 0 0.4em; }
table { border-collapse: collapse; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: middle; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.status { font-weight: bold; color: #fff; text-align: center; min-width: 5em; }
.fail { background: #d00000; }
.skipped { background: #707070; }
.updated { background: #0050d0; }
.pass { background: #008a00; }
img.thumb { width: 128px; height: auto; image-rendering: pixelated; display: block; }
.scale { display: flex; align-items: center; gap: 4px; font-size: 12px; }
.bar { width: 80px; height: 10px; }
.msg { max-width: 28em; font-size: 12px; }
.summary span { margin-right: 1.2em; }
.failed-count { color: #d00000; }
";

/// The page for `report`.
pub fn render(report: &Report) -> String {
    let counts = report.counts();
    let mut h = String::new();
    h.push_str("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n");
    h.push_str(&format!(
        "<title>meso regress: {} failed of {}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n",
        counts.failed, counts.total
    ));
    h.push_str(&format!(
        "<h1>Regression renders: {}</h1>\n",
        esc(&report.manifest)
    ));
    h.push_str(&format!(
        "<p class=\"summary\"><span><b>{}</b> cases</span><span{}><b>{} failed</b></span><span>{} skipped</span><span>{} updated</span><span>{} passed</span></p>\n",
        counts.total,
        if counts.failed > 0 { " class=\"failed-count\"" } else { "" },
        counts.failed,
        counts.skipped,
        counts.updated,
        counts.passed
    ));
    let shard = match (&report.shard, report.merged_shards.as_slice()) {
        (Some(s), _) => format!("shard {s}"),
        (None, []) => "all cases".to_string(),
        (None, shards) => format!(
            "merge of shards {}",
            shards
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    h.push_str(&format!(
        "<p>Meso {} &middot; {} &middot; {} &middot; {} job(s) on {} thread(s) &middot; {:.1} s wall &middot; manifest digest <code>{}</code><br><code>{}</code></p>\n",
        esc(&report.meso_version),
        esc(&report.date_utc),
        esc(&shard),
        report.jobs,
        report.threads,
        report.wall_seconds,
        esc(&report.manifest_digest),
        esc(&report.command),
    ));

    h.push_str("<h2>Speed and error of each mode</h2>\n<table>\n<tr><th>mode</th><th>device</th><th>cases rendered</th><th>total s</th><th>s per case</th><th>Mrays/s</th><th>mean relative RMSE</th><th>worst relative RMSE</th><th>worst MSSIM</th></tr>\n");
    for m in report.mode_summaries() {
        let opt = |v: Option<f64>| v.map_or("&ndash;".to_string(), number);
        h.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{:.3}</td><td class=\"num\">{:.3}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>\n",
            esc(&m.mode),
            esc(&m.device),
            m.rendered,
            m.total_seconds,
            m.mean_seconds,
            m.mrays_per_second.map_or("&ndash;".to_string(), |v| format!("{v:.2}")),
            opt(m.mean_relative_rmse),
            opt(m.worst_relative_rmse),
            opt(m.worst_mssim),
        ));
    }
    h.push_str("</table>\n<p>Error is against each case's golden image.</p>\n");

    h.push_str("<h2>Cases (failures first)</h2>\n<table id=\"cases\">\n<tr><th>status</th><th>case</th><th>scene / material / mode</th><th>relative RMSE (max)</th><th>MSSIM (min)</th><th>PSNR dB</th><th>render s</th><th>golden</th><th>new</th><th>difference</th><th>note</th></tr>\n");
    for c in &report.cases {
        h.push_str(&row(c));
    }
    h.push_str("</table>\n</body>\n</html>\n");
    h
}

fn row(c: &CaseReport) -> String {
    let status = c.status.name();
    let m = c.metrics;
    let rel = m.map_or("&ndash;".to_string(), |m| {
        m.relative_rmse.map_or("inf".to_string(), number)
    });
    let rel_bound = c
        .tolerance
        .max_relative_rmse
        .map_or(String::new(), |v| format!(" ({})", number(v)));
    let mssim = m.map_or("&ndash;".to_string(), |m| format!("{:.5}", m.mssim));
    let mssim_bound = c
        .tolerance
        .min_mssim
        .map_or(String::new(), |v| format!(" ({v})"));
    let psnr = m.map_or("&ndash;".to_string(), |m| {
        if m.identical {
            "identical".to_string()
        } else {
            m.psnr_db.map_or("inf".to_string(), |p| format!("{p:.2}"))
        }
    });
    let img = |p: &Option<String>, alt: &str| {
        p.as_ref().map_or("&ndash;".to_string(), |p| {
            format!(
                "<img class=\"thumb\" src=\"{}\" alt=\"{} {}\">",
                esc(p),
                alt,
                esc(&c.name)
            )
        })
    };
    let diff = match (&c.diff_png, c.diff_scale) {
        (Some(_), Some(scale)) => format!(
            "{}<div class=\"scale\">0 <span class=\"bar\" style=\"background: linear-gradient(to right, {})\"></span> {}</div>",
            img(&c.diff_png, "difference"),
            gradient(),
            number(scale)
        ),
        _ => "&ndash;".to_string(),
    };
    format!(
        "<tr class=\"row-{status}\"><td class=\"status {status}\">{}</td><td><code>{}</code></td><td>{} / {} / {}-{}<br>{}x{}, {} frames</td><td class=\"num\">{rel}{rel_bound}</td><td class=\"num\">{mssim}{mssim_bound}</td><td class=\"num\">{psnr}</td><td class=\"num\">{}</td><td>{}</td><td>{}</td><td>{diff}</td><td class=\"msg\">{}</td></tr>\n",
        status.to_uppercase(),
        esc(&c.name),
        esc(&c.scene),
        esc(&c.material),
        esc(&c.mode),
        esc(&c.device),
        c.width,
        c.height,
        c.frames,
        c.seconds
            .map_or("&ndash;".to_string(), |s| format!("{s:.3}")),
        img(&c.golden_png, "golden"),
        img(&c.new_png, "new"),
        c.message.as_deref().map(esc).unwrap_or_default(),
    )
}

/// The heat map's colour scale as CSS gradient stops.
fn gradient() -> String {
    VIRIDIS
        .iter()
        .map(|c| format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2]))
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::super::Status;
    use super::super::tests::sample_report;
    use super::*;

    #[test]
    fn the_page_lists_failures_first_escapes_text_and_links_images_relatively() {
        let page = render(&sample_report());
        let fail = page.find("<code>z.fail</code>").expect("failing row");
        let skip = page.find("<code>c.skip</code>").expect("skipped row");
        let pass = page.find("<code>a.pass</code>").expect("passing row");
        assert!(fail < skip && skip < pass);
        assert!(page.contains("&amp; &lt;x&gt;"), "the message is escaped");
        assert!(page.contains("src=\"images/z.fail.diff.png\""));
        assert!(!page.contains("http"), "nothing from the network");
        assert!(!page.contains("<script"), "no script");
        assert!(page.contains("<td class=\"status fail\">FAIL</td>"));
        // The heat map's scale is printed next to it.
        assert!(page.contains("0.5000</div>"), "{page}");
        assert_eq!(
            page.matches("<tr class=\"row-").count(),
            4,
            "one row per case"
        );
        assert!(Status::Fail < Status::Pass);
    }
}
