//! `meso regress` end to end (docs/regress.md): the shipped manifest passes bit for
//! bit on any thread count and shard split; a changed pack fails exactly the cases
//! that use it and the report names them; merged shard reports equal the unsharded
//! one; the JUnit output validates against tests/regress/junit.xsd (xmllint); the HTML
//! report opens in headless Chromium with the failing case first. The external tools
//! are skipped, loudly, where they are missing, except under CI (`.ci/run` installs
//! them), where a missing tool fails.

use std::path::{Path, PathBuf};

use meso_materials::spmm::pack::{ResidualPrecision, read_pack, residual_precision, write_pack};
use meso_reports::regress::{
    self, CaseReport, Manifest, Pattern, Report, RunRequest, Shard, Status, UpdateRequest,
    report::junit,
};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn quiet(_: &CaseReport, _: usize, _: usize) {}

fn run(
    manifest: &Manifest,
    shard: Option<Shard>,
    jobs: usize,
    threads: usize,
    update: Option<&UpdateRequest>,
    report_dir: Option<&Path>,
) -> Report {
    regress::run_manifest(
        manifest,
        &RunRequest {
            only: None,
            shard,
            jobs,
            threads,
            update,
            report_dir,
            command: "test".into(),
            on_case: &quiet,
        },
    )
    .expect("the run is made")
}

#[test]
fn shipped_manifest_passes_bit_for_bit_on_any_thread_count_and_shard_split() {
    let manifest =
        regress::load_manifest(&root().join("regress/manifest.toml")).expect("shipped manifest");
    let check = |report: &Report, what: &str| {
        for c in &report.cases {
            match c.status {
                Status::Pass => assert!(
                    c.metrics.is_some_and(|m| m.identical),
                    "{what}: {} passes but is not bit-identical to its golden: {:?}",
                    c.name,
                    c.metrics
                ),
                // Only what the mode cannot render yet may be skipped (and only while
                // it has no golden: with one it would fail).
                Status::Skipped => assert!(
                    c.message
                        .as_deref()
                        .is_some_and(|m| m.contains("cannot render") || m.contains("not built")),
                    "{what}: {} skipped: {:?}",
                    c.name,
                    c.message
                ),
                _ => panic!("{what}: {} {:?}: {:?}", c.name, c.status, c.message),
            }
        }
    };
    let one = run(&manifest, None, 1, 1, None, None);
    check(&one, "1 job on 1 thread");
    let passed = one.counts().passed;
    assert!(passed >= 68, "{passed} cases rendered");
    // Every scene x every shipped pack is covered.
    for scene in [
        "default",
        "fitted",
        "cloth",
        "env",
        "cornell",
        "merl_bunny",
        "merl_dragon",
        "merl_teapot",
    ] {
        for pack in [
            "woven_wool",
            "leather",
            "brushed_metal",
            "knitted_wool",
            "woven_cloth",
            "grain_leather",
            "corduroy",
        ] {
            let name = format!("{scene}.{pack}.spmm-cpu");
            assert!(one.cases.iter().any(|c| c.name == name), "{name} missing");
        }
    }
    // The goldens were rendered on 2 threads; here each shard renders 2 cases at once
    // with 2 threads each.
    let mut union = Vec::new();
    for index in 1..=3 {
        let part = run(&manifest, Some(Shard { index, count: 3 }), 2, 4, None, None);
        check(&part, &format!("shard {index}/3, 2 jobs x 2 threads"));
        union.extend(part.cases.into_iter().map(|c| c.name));
    }
    union.sort();
    let mut all: Vec<String> = one.cases.iter().map(|c| c.name.clone()).collect();
    all.sort();
    assert_eq!(union, all, "the shards together are the whole run");
}

/// A small manifest in a temporary folder: the default and cloth scenes with their own
/// material and with copies of two packs substituted, and goldens rendered for it.
struct Fixture {
    dir: tempfile::TempDir,
    manifest: PathBuf,
}

impl Fixture {
    fn new() -> Fixture {
        let dir = tempfile::tempdir().expect("temp dir");
        for pack in ["leather", "woven_wool"] {
            std::fs::copy(
                root().join(format!("../materials/{pack}.spmm")),
                dir.path().join(format!("{pack}.spmm")),
            )
            .expect("copy pack");
        }
        let scenes = root().join("scenes");
        let text = format!(
            r#"version = 1
goldens = "goldens"

[defaults]
width = 48
height = 48
frames = 2
# Renders repeat bit for bit, so any real change shows.
max_relative_rmse = 0.001

[scenes.default]
path = "{}"
replace = "leather"

[scenes.cloth]
path = "{}"
replace = "cloth"

[materials.leather]
kind = "spmm"
pack = "leather.spmm"

[materials.wool]
kind = "spmm"
pack = "woven_wool.spmm"

[[matrix]]
scenes = ["default", "cloth"]
materials = ["scene", "leather", "wool"]
modes = ["spmm"]
"#,
            scenes.join("default.toml").display(),
            scenes.join("cloth.toml").display()
        );
        let manifest = dir.path().join("manifest.toml");
        std::fs::write(&manifest, text).expect("manifest");
        let f = Fixture { dir, manifest };
        let update = UpdateRequest {
            reason: "fixture goldens".into(),
            command: "meso regress manifest.toml --update".into(),
        };
        let r = run(&f.load(), None, 2, 2, Some(&update), None);
        assert_eq!(r.counts().updated, 6, "{:?}", r.cases);
        f
    }

    fn load(&self) -> Manifest {
        regress::load_manifest(&self.manifest).expect("fixture manifest")
    }

    fn path(&self, rel: &str) -> PathBuf {
        self.dir.path().join(rel)
    }

    /// Brightens every cluster of the fixture's leather pack by 30%.
    fn change_leather(&self) {
        let path = self.path("leather.spmm");
        let bytes = std::fs::read(&path).expect("pack");
        let precision = residual_precision(&bytes);
        let mut pack = read_pack(&path).expect("pack");
        for c in 0..pack.clusters().len() {
            pack = pack
                .with_cluster_weight_scale(c, [1.3; 3])
                .expect("valid scale");
        }
        write_pack(&path, &pack, precision).expect("write pack");
        let _: ResidualPrecision = precision;
    }
}

fn failed(report: &Report) -> Vec<&str> {
    report
        .cases
        .iter()
        .filter(|c| c.status == Status::Fail)
        .map(|c| c.name.as_str())
        .collect()
}

#[test]
fn a_changed_pack_fails_exactly_the_cases_that_use_it_and_the_report_names_them() {
    let f = Fixture::new();
    let log = std::fs::read_to_string(f.path("goldens/LOG.md")).expect("update log");
    assert!(log.contains("reason: fixture goldens"), "{log}");
    assert_eq!(log.matches(".spmm-cpu`").count(), 6, "{log}");
    let clean = run(&f.load(), None, 1, 2, None, None);
    assert!(failed(&clean).is_empty(), "{:?}", clean.cases);

    f.change_leather();
    let out = f.path("report");
    let report = run(&f.load(), None, 2, 2, None, Some(&out));
    // The default scene's own leather is the shipped pack, not the changed copy.
    assert_eq!(
        failed(&report),
        ["cloth.leather.spmm-cpu", "default.leather.spmm-cpu"],
        "{:#?}",
        report.cases
    );
    for c in report.cases.iter().filter(|c| c.status == Status::Fail) {
        let m = c.metrics.expect("compared");
        assert!(m.relative_rmse.expect("finite") > 0.001, "{m:?}");
        assert!(
            c.message
                .as_deref()
                .is_some_and(|t| t.contains("relative RMSE"))
        );
        assert!(c.diff_scale.expect("heat map") > 0.0);
    }
    let page = std::fs::read_to_string(out.join("index.html")).expect("page");
    let md = std::fs::read_to_string(out.join("summary.md")).expect("summary");
    for name in failed(&report) {
        assert!(page.contains(&format!(
            "<td class=\"status fail\">FAIL</td><td><code>{name}</code>"
        )));
        assert!(md.contains(&format!("| **FAIL** | `{name}` |")), "{md}");
        for suffix in ["golden", "new", "diff"] {
            assert!(out.join(format!("images/{name}.{suffix}.png")).is_file());
        }
    }
    // Failures first in both.
    let first_pass = page.find("status pass").expect("passes");
    assert!(page.rfind("status fail").expect("failures") < first_pass);
    let x = junit::render(&report);
    assert!(x.contains("tests=\"6\" failures=\"2\""), "{x}");
}

/// Case rows without the fields that differ between runs (times, rays are equal).
fn comparable(report: &Report) -> Vec<CaseReport> {
    report
        .cases
        .iter()
        .map(|c| CaseReport {
            seconds: None,
            trace_seconds: None,
            ..c.clone()
        })
        .collect()
}

#[test]
fn merged_shards_equal_the_unsharded_report() {
    let f = Fixture::new();
    f.change_leather();
    let manifest = f.load();
    let whole_dir = f.path("whole");
    let whole = run(&manifest, None, 1, 2, None, Some(&whole_dir));
    let mut dirs = Vec::new();
    for index in 1..=3 {
        let d = f.path(&format!("shard{index}"));
        let part = run(
            &manifest,
            Some(Shard { index, count: 3 }),
            1,
            2,
            None,
            Some(&d),
        );
        assert_eq!(part.shard, Some(Shard { index, count: 3 }));
        dirs.push(d);
    }
    let merged_dir = f.path("merged");
    let merged = regress::merge::merge(&dirs, &merged_dir, "merge").expect("merged");
    assert_eq!(comparable(&merged), comparable(&whole));
    assert_eq!(merged.merged_shards.len(), 3);
    // The merge read back from disk is what it returned, and its pictures are the
    // unsharded run's, byte for byte.
    let reread = Report::read(&merged_dir).expect("merged report.json");
    assert_eq!(comparable(&reread), comparable(&whole));
    for c in &whole.cases {
        for rel in [&c.golden_png, &c.new_png, &c.diff_png]
            .into_iter()
            .flatten()
        {
            assert_eq!(
                std::fs::read(merged_dir.join(rel)).expect("merged picture"),
                std::fs::read(whole_dir.join(rel)).expect("whole picture"),
                "{rel}"
            );
        }
    }
    let count = |x: &str, pat: &str| x.matches(pat).count();
    let (jm, jw) = (junit::render(&merged), junit::render(&whole));
    for pat in ["<testcase ", "<failure ", "tests=\"6\" failures=\"2\""] {
        assert_eq!(count(&jm, pat), count(&jw, pat), "{pat}");
    }

    // Incomplete, repeated or foreign shards are refused by name.
    let e = regress::merge::merge(&dirs[..2], &f.path("m2"), "merge").expect_err("missing");
    assert!(e.to_string().contains("shard(s) 3/3 missing"), "{e}");
    let e = regress::merge::merge(&[dirs[0].clone(), dirs[0].clone()], &f.path("m3"), "merge")
        .expect_err("twice");
    assert!(e.to_string().contains("given twice"), "{e}");
    let e = regress::merge::merge(std::slice::from_ref(&whole_dir), &f.path("m4"), "merge")
        .expect_err("not a shard");
    assert!(e.to_string().contains("not a shard report"), "{e}");
    std::fs::write(
        &f.manifest,
        std::fs::read_to_string(&f.manifest).expect("text") + "\n# changed\n",
    )
    .expect("edit manifest");
    let other = f.path("other");
    run(
        &f.load(),
        Some(Shard { index: 3, count: 3 }),
        1,
        2,
        None,
        Some(&other),
    );
    let e = regress::merge::merge(
        &[dirs[0].clone(), dirs[1].clone(), other],
        &f.path("m5"),
        "merge",
    )
    .expect_err("another manifest");
    assert!(e.to_string().contains("another manifest"), "{e}");
    assert!(e.is_bad_input());
}

/// `name` if it runs (`--version`), else `None`; under CI a missing tool fails.
fn tool(name: &str, env: &str, package: &str) -> Option<String> {
    let program = std::env::var(env).unwrap_or_else(|_| name.to_string());
    let ok = std::process::Command::new(&program)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        return Some(program);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but `{program}` does not run (install the Debian package `{package}`; .ci/run does, or set {env})"
    );
    eprintln!("SKIPPED: `{program}` is not installed (Debian package `{package}`; or set {env})");
    None
}

#[test]
fn junit_validates_against_the_common_schema_with_its_counts() {
    let Some(xmllint) = tool("xmllint", "MESO_XMLLINT", "libxml2-utils") else {
        return;
    };
    let f = Fixture::new();
    f.change_leather();
    let report = run(&f.load(), None, 1, 2, None, None);
    let xml = f.path("junit.xml");
    std::fs::write(&xml, junit::render(&report)).expect("junit");
    let xsd = root().join("regress/junit.xsd");
    let validate = |file: &Path| {
        std::process::Command::new(&xmllint)
            .arg("--noout")
            .arg("--schema")
            .arg(&xsd)
            .arg(file)
            .output()
            .expect("xmllint runs")
    };
    let o = validate(&xml);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let xpath = |expr: &str| -> String {
        let o = std::process::Command::new(&xmllint)
            .args(["--xpath", expr])
            .arg(&xml)
            .output()
            .expect("xmllint runs");
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    };
    assert_eq!(xpath("count(//testcase)"), "6");
    assert_eq!(xpath("count(//testcase/failure)"), "2");
    assert_eq!(xpath("string(/testsuites/testsuite/@tests)"), "6");
    assert_eq!(xpath("string(/testsuites/testsuite/@failures)"), "2");
    assert_eq!(xpath("string(/testsuites/@failures)"), "2");
    // The schema is not vacuous: a testsuite without its required name is refused.
    let broken = f.path("broken.xml");
    std::fs::write(
        &broken,
        junit::render(&report).replacen("<testsuite name=", "<testsuite label=", 1),
    )
    .expect("broken");
    assert!(!validate(&broken).status.success());
}

#[test]
fn the_html_report_opens_in_headless_chromium_with_the_failing_case_first() {
    let Some(chromium) = tool("chromium", "MESO_CHROMIUM", "chromium") else {
        return;
    };
    let f = Fixture::new();
    f.change_leather();
    let out = f.path("report");
    run(&f.load(), None, 1, 2, None, Some(&out));
    let shot = f.path("shot.png");
    let o = std::process::Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--window-size=1400,1000",
        ])
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", out.join("index.html").display()))
        .output()
        .expect("chromium runs");
    assert!(
        shot.is_file(),
        "no screenshot: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let img = image::open(&shot).expect("a PNG").to_rgb8();
    // The first pixel row holding a run of each status cell's colour.
    let first_row_of = |rgb: [u8; 3]| -> Option<u32> {
        (0..img.height()).find(|&y| {
            let mut run = 0;
            (0..img.width()).any(|x| {
                run = if img.get_pixel(x, y).0 == rgb {
                    run + 1
                } else {
                    0
                };
                run >= 40
            })
        })
    };
    let fail = first_row_of([0xd0, 0x00, 0x00]).expect("a failing status cell is on screen");
    let pass = first_row_of([0x00, 0x8a, 0x00]).expect("a passing status cell is on screen");
    assert!(fail < pass, "failing row at y {fail}, passing at y {pass}");
    // The pictures load from the file system: the heat maps' bottom colour (viridis
    // at 0) fills most of each map, scaled up without smoothing.
    let dark = meso_reports::regress::report::images::VIRIDIS[0];
    let dark_pixels = img.pixels().filter(|p| p.0 == dark).count();
    assert!(
        dark_pixels > 2000,
        "{dark_pixels} heat-map pixels on screen"
    );
}

#[test]
fn only_selects_by_pattern() {
    let f = Fixture::new();
    let manifest = f.load();
    let only = Pattern::parse("cloth.*").expect("valid");
    let r = regress::run_manifest(
        &manifest,
        &RunRequest {
            only: Some(&only),
            shard: None,
            jobs: 1,
            threads: 2,
            update: None,
            report_dir: None,
            command: "test".into(),
            on_case: &quiet,
        },
    )
    .expect("runs");
    let names: Vec<&str> = r.cases.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "cloth.leather.spmm-cpu",
            "cloth.scene.spmm-cpu",
            "cloth.wool.spmm-cpu"
        ]
    );
    let none = Pattern::parse("nothing*").expect("valid");
    let e = regress::run_manifest(
        &manifest,
        &RunRequest {
            only: Some(&none),
            shard: None,
            jobs: 1,
            threads: 2,
            update: None,
            report_dir: None,
            command: "test".into(),
            on_case: &quiet,
        },
    )
    .expect_err("matches nothing");
    assert!(
        e.to_string().contains("--only `nothing*` matches no case"),
        "{e}"
    );
}

/// A MERL file substitution renders exactly as the table tabulated at load from the
/// same BRDF (the file holds the same f64 cells), and an analytic substitution differs
/// from both: each kind of substitution reaches the render.
#[test]
fn merl_file_and_analytic_substitutions_reach_the_render() {
    use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
    let dir = tempfile::tempdir().expect("temp dir");
    let brdf =
        AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.25), ("f0", 0.8)]).expect("valid");
    meso_materials::merl::tabulate(&brdf, glam::DVec3::new(0.9, 0.6, 0.3))
        .expect("tabulated")
        .write(&dir.path().join("ct.binary"))
        .expect("written");
    let text = format!(
        r#"version = 1
goldens = "goldens"

[defaults]
width = 32
height = 32
frames = 2
min_mssim = 0.99

[scenes.default]
path = "{}"
replace = "leather"

[materials.file]
kind = "merl"
path = "ct.binary"

[materials.table]
kind = "merl"
tabulate = {{ model = "cook_torrance", params = {{ m = 0.25, f0 = 0.8 }}, albedo = [0.9, 0.6, 0.3] }}

[materials.analytic]
kind = "brdf"
model = "cook_torrance"
params = {{ m = 0.25, f0 = 0.8 }}
albedo = [0.3, 0.6, 0.9]

[[matrix]]
scenes = ["default"]
materials = ["scene", "file", "table", "analytic"]
modes = ["spmm"]
"#,
        root().join("scenes/default.toml").display()
    );
    let path = dir.path().join("manifest.toml");
    std::fs::write(&path, text).expect("manifest");
    let manifest = regress::load_manifest(&path).expect("valid");
    let update = UpdateRequest {
        reason: "test".into(),
        command: "test".into(),
    };
    let r = run(&manifest, None, 1, 2, Some(&update), None);
    assert_eq!(r.counts().updated, 4, "{:?}", r.cases);
    let golden = |case: &str| {
        meso_materials::image::read_exr(
            &dir.path()
                .join(format!("goldens/default.{case}.spmm-cpu.exr")),
        )
        .expect("golden")
    };
    let (file, table, analytic) = (golden("file"), golden("table"), golden("analytic"));
    assert_eq!(file, table, "the MERL file and the tabulated table");
    assert_ne!(file, analytic);
    // The leather was replaced: the scene as written renders otherwise.
    assert_ne!(golden("scene"), file);
}
