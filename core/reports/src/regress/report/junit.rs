//! The report as JUnit XML, the shape CI systems read (Jenkins, GitLab, GitHub
//! actions' test reporters): `testsuites` > one `testsuite` > a `testcase` per case,
//! with a `failure` carrying the metrics and the bounds, or `skipped` with its reason.
//! tests/regress/junit.xsd states the schema it is checked against.

use super::{Report, Status, escape_xml as esc, number};

pub fn render(report: &Report) -> String {
    let c = report.counts();
    let time: f64 = report.cases.iter().filter_map(|c| c.seconds).sum();
    let suite = format!("meso regress {}", report.manifest);
    let mut x = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    x.push_str(&format!(
        "<testsuites name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"0\" skipped=\"{}\" time=\"{time:.3}\">\n",
        esc(&suite),
        c.total,
        c.failed,
        c.skipped
    ));
    x.push_str(&format!(
        "  <testsuite name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"0\" skipped=\"{}\" time=\"{time:.3}\" timestamp=\"{}\">\n",
        esc(&suite),
        c.total,
        c.failed,
        c.skipped,
        esc(report.date_utc.trim_end_matches('Z')),
    ));
    x.push_str("    <properties>\n");
    for (name, value) in [
        ("meso_version", report.meso_version.clone()),
        ("manifest_digest", report.manifest_digest.clone()),
        ("command", report.command.clone()),
    ] {
        x.push_str(&format!(
            "      <property name=\"{name}\" value=\"{}\"/>\n",
            esc(&value)
        ));
    }
    x.push_str("    </properties>\n");
    for case in &report.cases {
        x.push_str(&format!(
            "    <testcase name=\"{}\" classname=\"regress.{}\" time=\"{:.3}\"",
            esc(&case.name),
            esc(&case.scene),
            case.seconds.unwrap_or(0.0)
        ));
        let metrics = case.metrics.map(|m| {
            format!(
                "rmse {} relative_rmse {} mssim {:.6} psnr_db {} max_abs_error {}; bounds: max_relative_rmse {} min_mssim {}",
                number(m.rmse),
                m.relative_rmse.map_or("inf".into(), number),
                m.mssim,
                m.psnr_db.map_or("inf".into(), |p| format!("{p:.3}")),
                number(m.max_abs_error),
                case.tolerance.max_relative_rmse.map_or("-".into(), number),
                case.tolerance.min_mssim.map_or("-".into(), |v| v.to_string()),
            )
        });
        match case.status {
            Status::Fail => {
                let message = case.message.clone().unwrap_or_default();
                x.push_str(&format!(
                    ">\n      <failure message=\"{}\" type=\"regression\">{}</failure>\n    </testcase>\n",
                    esc(&message),
                    esc(&metrics.unwrap_or_else(|| message.clone())),
                ));
            }
            Status::Skipped => {
                x.push_str(&format!(
                    ">\n      <skipped message=\"{}\"/>\n    </testcase>\n",
                    esc(case.message.as_deref().unwrap_or(""))
                ));
            }
            Status::Pass | Status::Updated => match metrics {
                Some(m) => x.push_str(&format!(
                    ">\n      <system-out>{}</system-out>\n    </testcase>\n",
                    esc(&format!("{}: {m}", case.status.name()))
                )),
                None => x.push_str("/>\n"),
            },
        }
    }
    x.push_str("  </testsuite>\n</testsuites>\n");
    x
}

#[cfg(test)]
mod tests {
    use super::super::tests::sample_report;
    use super::*;

    #[test]
    fn counts_and_elements_agree() {
        let x = render(&sample_report());
        assert!(x.contains("<testsuites name=\"meso regress m.toml\" tests=\"4\" failures=\"1\" errors=\"0\" skipped=\"1\""));
        assert_eq!(x.matches("<testcase ").count(), 4);
        assert_eq!(x.matches("<failure ").count(), 1);
        assert_eq!(x.matches("<skipped ").count(), 1);
        assert!(x.contains("message=\"relative RMSE 2e-1 &gt; 0.05 &amp; &lt;x&gt;\""));
        assert!(x.contains("relative_rmse 0.2000 mssim 0.990000"));
    }
}
