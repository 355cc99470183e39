//! The `meso` command-line contract (spec/cli.md), tested on the real binary: exit
//! codes 0/2/1, one `error:` line naming the place at fault, `--json` output that
//! parses, and outputs that are written whole or not at all.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Output, Stdio};

fn meso(args: &[&str], stdin: &str) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_meso"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the meso binary was built by cargo for this test");
    let written = child
        .stdin
        .take()
        .expect("stdin is piped")
        .write_all(stdin.as_bytes());
    // A command that rejects its arguments exits without reading stdin.
    if let Err(e) = written {
        assert_eq!(e.kind(), std::io::ErrorKind::BrokenPipe, "write stdin: {e}");
    }
    child.wait_with_output().expect("meso runs to completion")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Asserts a bad-input failure: exit 2, exactly one stderr line, starting `error:`
/// and containing every `needle`, nothing on stdout.
fn assert_bad_input(o: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "stderr: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "one error line expected, got: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    for needle in needles {
        assert!(lines[0].contains(needle), "`{needle}` missing from: {err}");
    }
    assert!(
        o.stdout.is_empty(),
        "stdout must stay empty on error: {}",
        stdout(o)
    );
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn brdf_eval_prints_one_value_per_row() {
    // Lambertian is 1/pi for every pair above the horizon and 0 below (spec/brdf.md);
    // unnormalised input directions are normalised by the tool.
    let input = "0,0,1,0,0,1\n\n# a comment\n0.3,0.1,2,0,-0.2,5\n0,0,-1,0,0,1\n";
    let o = meso(&["brdf", "eval", "--model", "lambertian"], input);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let values: Vec<f64> = stdout(&o)
        .lines()
        .map(|l| l.parse().expect("a number"))
        .collect();
    let inv_pi = std::f64::consts::FRAC_1_PI;
    assert_eq!(values.len(), 3);
    assert!((values[0] - inv_pi).abs() < 1e-8 * inv_pi);
    assert!((values[1] - inv_pi).abs() < 1e-8 * inv_pi);
    assert_eq!(values[2], 0.0);
}

#[test]
fn brdf_eval_blinn_phong_matches_closed_form() {
    // wi = wo = normal: cos_h = 1, so f = (n + 8) / (8 pi) exactly.
    let o = meso(
        &["brdf", "eval", "--model", "blinn_phong", "--param", "n=120"],
        "0,0,1,0,0,1\n",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: f64 = stdout(&o).trim().parse().expect("a number");
    let expected = 128.0 / (8.0 * std::f64::consts::PI);
    assert!((v - expected).abs() < 1e-8 * expected, "{v} vs {expected}");
}

#[test]
fn brdf_eval_json_is_one_object() {
    let o = meso(
        &[
            "brdf", "eval", "--model", "ward", "--param", "ax=0.2", "--param", "ay=0.1", "--json",
        ],
        "0,0,1,0,0,1\n0.5,0,0.8,-0.5,0,0.8\n",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("stdout is JSON");
    assert_eq!(v["model"], "ward");
    assert_eq!(v["params"]["ax"], 0.2);
    assert_eq!(v["values"].as_array().map(Vec::len), Some(2));
}

#[test]
fn brdf_eval_bad_input_names_the_fault() {
    let ok_row = "0,0,1,0,0,1\n";
    assert_bad_input(
        &meso(&["brdf", "eval", "--model", "phong"], ok_row),
        &["phong"],
    );
    assert_bad_input(
        &meso(
            &["brdf", "eval", "--model", "ward", "--param", "ax=0.1"],
            ok_row,
        ),
        &["ay"],
    );
    assert_bad_input(
        &meso(
            &[
                "brdf", "eval", "--model", "ward", "--param", "ax=0.1", "--param", "ay=2",
            ],
            ok_row,
        ),
        &["ay", "2"],
    );
    assert_bad_input(
        &meso(
            &[
                "brdf", "eval", "--model", "ward", "--param", "ax=abc", "--param", "ay=0.1",
            ],
            ok_row,
        ),
        &["ax=abc"],
    );
    assert_bad_input(
        &meso(
            &["brdf", "eval", "--model", "lambertian", "--param", "n=3"],
            ok_row,
        ),
        &["n"],
    );
    assert_bad_input(
        &meso(
            &["brdf", "eval", "--model", "lambertian"],
            "0,0,1,0,0,1\n0,0,1,0,0\n",
        ),
        &["line 2", "6"],
    );
    assert_bad_input(
        &meso(
            &["brdf", "eval", "--model", "lambertian"],
            "0,0,1,0,0,1\n0,0,1,0,zero,1\n",
        ),
        &["line 2", "zero"],
    );
    assert_bad_input(
        &meso(
            &["brdf", "eval", "--model", "lambertian"],
            "0,0,1,0,0,1\n\n0,0,0,0,0,1\n",
        ),
        &["line 3", "wi", "zero vector"],
    );
    assert_bad_input(
        &meso(
            &["brdf", "eval", "--model", "lambertian"],
            "0,0,1,nan,0,1\n",
        ),
        &["line 1", "wo"],
    );
}

#[test]
fn usage_errors_are_one_line_and_exit_2() {
    assert_bad_input(
        &meso(&["brdf", "eval", "--modle", "ward"], ""),
        &["--modle"],
    );
    assert_bad_input(&meso(&["render-everything"], ""), &["render-everything"]);
    let help = meso(&["--help"], "");
    assert_eq!(help.status.code(), Some(0));
    assert!(stdout(&help).contains("compare"));
}

#[test]
fn brdf_albedo_of_lambertian_is_one() {
    let o = meso(
        &[
            "brdf",
            "albedo",
            "--model",
            "lambertian",
            "--theta-deg",
            "0,60",
            "--samples",
            "20000",
            "--json",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    let rows = v["albedo"].as_array().expect("table");
    assert_eq!(rows.len(), 2);
    for row in rows {
        // Cosine sampling makes f cos / pdf exactly 1 for every sample.
        let a = row["albedo"].as_f64().expect("albedo");
        assert!((a - 1.0).abs() < 1e-9, "{row}");
    }
    assert_bad_input(
        &meso(
            &[
                "brdf",
                "albedo",
                "--model",
                "lambertian",
                "--theta-deg",
                "95",
            ],
            "",
        ),
        &["95", "[0, 90)"],
    );
}

fn write_exr(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> [f32; 3]) {
    let mut img = meso_materials::image::Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            img.set(x, y, f(x, y));
        }
    }
    meso_materials::image::write_exr(path, &img).expect("write test EXR");
}

#[test]
fn compare_reports_metrics_and_rejects_bad_pairs() {
    let dir = tempfile::tempdir().expect("temp dir");
    let a = dir.path().join("a.exr");
    let b = dir.path().join("b.exr");
    let small = dir.path().join("small.exr");
    write_exr(&a, 32, 24, |x, y| [x as f32 / 32.0, y as f32 / 24.0, 0.5]);
    // B differs from A by exactly 0.1 in the red channel of one pixel.
    write_exr(&b, 32, 24, |x, y| {
        let r = x as f32 / 32.0 + if (x, y) == (5, 7) { 0.1 } else { 0.0 };
        [r, y as f32 / 24.0, 0.5]
    });
    write_exr(&small, 16, 24, |_, _| [0.0; 3]);
    let (a_s, b_s) = (a.to_str().expect("utf-8"), b.to_str().expect("utf-8"));

    let same = meso(&["compare", a_s, a_s, "--json"], "");
    assert_eq!(
        same.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&same.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&same)).expect("JSON");
    assert_eq!(v["rmse"], 0.0);
    assert_eq!(v["mssim"], 1.0);
    assert!(v["psnr_db"].is_null());

    let diff = meso(&["compare", a_s, b_s, "--json"], "");
    assert_eq!(diff.status.code(), Some(0));
    let v: serde_json::Value = serde_json::from_str(&stdout(&diff)).expect("JSON");
    // RMSE over 32*24 pixels x 3 channels with one entry off by 0.1.
    let expected_rmse = (0.01f64 / (32.0 * 24.0 * 3.0)).sqrt();
    let rmse = v["rmse"].as_f64().expect("rmse");
    assert!(
        (rmse - expected_rmse).abs() < 1e-6 * expected_rmse + 1e-9,
        "{rmse}"
    );
    assert!((v["max_abs_error"].as_f64().expect("max") - 0.1).abs() < 1e-6);
    assert_eq!(v["max_error_pixel"], serde_json::json!([5, 7]));
    assert!(v["mssim"].as_f64().expect("mssim") < 1.0);

    let human = meso(&["compare", a_s, b_s], "");
    assert_eq!(human.status.code(), Some(0));
    assert!(stdout(&human).contains("MSSIM"));

    let small_s = small.to_str().expect("utf-8");
    assert_bad_input(&meso(&["compare", a_s, small_s], ""), &["32x24", "16x24"]);
    let missing = dir.path().join("missing.exr");
    assert_bad_input(
        &meso(&["compare", a_s, missing.to_str().expect("utf-8")], ""),
        &["missing.exr"],
    );
    let garbage = dir.path().join("garbage.exr");
    std::fs::write(&garbage, b"not an exr at all").expect("write");
    assert_bad_input(
        &meso(&["compare", garbage.to_str().expect("utf-8"), a_s], ""),
        &["garbage.exr"],
    );
}

#[test]
fn plot_writes_a_png_and_a_failed_write_keeps_what_was_there() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("lobe.png");
    let out_s = out.to_str().expect("utf-8");
    let o = meso(
        &[
            "brdf", "plot", "--model", "ward", "--param", "ax=0.2", "--param", "ay=0.2", "-o",
            out_s,
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let png = meso_materials::image::read_image(&out).expect("a readable PNG");
    assert_eq!(png.width(), 480);
    // The plot is not blank: some pixels are far from the white background.
    assert!(png.pixels().iter().any(|p| p[0] < 0.5 && p[2] > 0.1));

    // The output path is an existing folder: the rename fails (exit 1, not bad
    // input), the folder and its content survive, and no temporary is left behind.
    let blocker = dir.path().join("blocker.png");
    std::fs::create_dir(&blocker).expect("mkdir");
    std::fs::write(blocker.join("keep.txt"), b"keep me").expect("write");
    let o = meso(
        &[
            "brdf",
            "plot",
            "--model",
            "lambertian",
            "-o",
            blocker.to_str().expect("utf-8"),
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.starts_with("error: ") && err.contains("blocker.png"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(blocker.join("keep.txt")).expect("kept"),
        b"keep me"
    );
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .expect("list")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

/// A two-cluster pack built through the public API (Ward + Lambertian, one weight
/// per texel, no residual).
fn write_small_pack(path: &Path) {
    use glam::DVec3;
    use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
    use meso_materials::spmm::{Cluster, SparseWeights, SpmmMaterial, pack};
    let ward = AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.1), ("ay", 0.3)]).expect("valid");
    let lamb = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    let clusters = vec![
        Cluster {
            bases: vec![
                BasisFunction::new(ward, DVec3::Z).expect("unit"),
                BasisFunction::new(lamb, DVec3::Z).expect("unit"),
            ],
        },
        Cluster {
            bases: vec![
                BasisFunction::new(lamb, DVec3::new(0.1, 0.0, 1.0).normalize()).expect("unit"),
            ],
        },
    ];
    let texel_cluster = vec![0, 1, 1, 0];
    let weights = SparseWeights {
        offsets: vec![0, 2, 3, 4, 6],
        basis: vec![0, 1, 0, 0, 0, 1],
        rgb: vec![
            [0.2, 0.2, 0.2],
            [0.5, 0.4, 0.3],
            [0.7, 0.1, 0.1],
            [0.6, 0.1, 0.1],
            [0.3, 0.3, 0.3],
            [0.4, 0.4, 0.4],
        ],
    };
    let m = SpmmMaterial::new(
        "small".into(),
        "cli test".into(),
        2,
        2,
        clusters,
        texel_cluster,
        weights,
        None,
    )
    .expect("valid material");
    pack::write_pack(path, &m, pack::ResidualPrecision::F32).expect("write pack");
}

#[test]
fn pack_info_and_validate() {
    let dir = tempfile::tempdir().expect("temp dir");
    let good = dir.path().join("small.spmm");
    write_small_pack(&good);
    let good_s = good.to_str().expect("utf-8");
    let o = meso(&["pack", "validate", good_s], "");
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let o = meso(&["pack", "info", good_s, "--json"], "");
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["width"], 2);
    assert_eq!(v["clusters"][0]["bases"][0]["model"], "ward");
    assert_eq!(v["clusters"][0]["bases"][0]["params"]["ay"], 0.3);
    assert_eq!(v["clusters"][1]["texels"], 2);
    assert_eq!(v["weights_per_texel"]["max"], 2);
    assert_eq!(v["weights_per_texel"]["mean"], 1.5);
    let total: u64 = v["bytes"]
        .as_array()
        .expect("parts")
        .iter()
        .map(|p| p["bytes"].as_u64().expect("n"))
        .sum();
    assert_eq!(
        total,
        std::fs::metadata(&good).expect("stat").len(),
        "parts add up to the file size"
    );
    let o = meso(&["pack", "info", good_s], "");
    assert!(stdout(&o).contains("cluster 1: 2 texels"));

    // A corrupted model id: exit 2, the file and the tensor element named.
    let mut bytes = std::fs::read(&good).expect("read");
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8")) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).expect("header");
    let at = 8
        + n
        + header["basis_model"]["data_offsets"][0]
            .as_u64()
            .expect("offset") as usize;
    bytes[at + 1] = 42;
    let bad = dir.path().join("bad.spmm");
    std::fs::write(&bad, &bytes).expect("write");
    assert_bad_input(
        &meso(&["pack", "validate", bad.to_str().expect("utf-8")], ""),
        &["bad.spmm", "basis_model", "[1]", "42"],
    );
    assert_bad_input(
        &meso(&["pack", "info", bad.to_str().expect("utf-8")], ""),
        &["bad.spmm", "basis_model"],
    );
    let truncated = dir.path().join("truncated.spmm");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).expect("write");
    assert_bad_input(
        &meso(
            &["pack", "validate", truncated.to_str().expect("utf-8")],
            "",
        ),
        &["truncated.spmm"],
    );
    assert_bad_input(
        &meso(&["pack", "validate", "/no/such.spmm"], ""),
        &["/no/such.spmm"],
    );
}

#[test]
fn pack_eval_prints_rgb_per_row() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("small.spmm");
    write_small_pack(&path);
    let p = path.to_str().expect("utf-8");
    // Texel (1, 0) (u = 0.75, v = 0.75: column 1, top row) is cluster 1: one Lambertian
    // basis on a tilted normal n = normalize(0.1, 0, 1), weight (0.7, 0.1, 0.1). With
    // wi = n the value is weight / pi * (n . wi) = weight / pi.
    let n = [0.1f64 / 1.01f64.sqrt(), 0.0, 1.0 / 1.01f64.sqrt()];
    let row = format!("{},{},{},0,0,1\n0,0,-1,0,0,1\n", n[0], n[1], n[2]);
    let o = meso(&["pack", "eval", p, "--texel", "0.75,0.75"], &row);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let lines: Vec<Vec<f64>> = stdout(&o)
        .lines()
        .map(|l| l.split(',').map(|x| x.parse().expect("number")).collect())
        .collect();
    let inv_pi = std::f64::consts::FRAC_1_PI;
    for (got, w) in lines[0].iter().zip([0.7f32, 0.1, 0.1]) {
        assert!((got - w as f64 * inv_pi).abs() < 1e-8, "{got}");
    }
    assert_eq!(lines[1], vec![0.0, 0.0, 0.0]);
    assert_bad_input(
        &meso(&["pack", "eval", p, "--texel", "0.5"], &row),
        &["--texel", "0.5"],
    );
    assert_bad_input(
        &meso(&["pack", "eval", p, "--texel", "0.5,0.5"], "1,2\n"),
        &["line 1"],
    );
}

/// `meso pack eval --json` at `uv` for one direction pair: (values, per-basis
/// contributions) of the nearest texel.
fn eval_parts(pack: &str, uv: &str) -> (Vec<f64>, Vec<Vec<f64>>) {
    let row = "0.3,0.1,0.9,-0.2,0.1,0.95\n";
    let o = meso(&["pack", "eval", pack, "--texel", uv, "--json"], row);
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    let nums = |x: &serde_json::Value| -> Vec<f64> {
        x.as_array()
            .expect("array")
            .iter()
            .map(|n| n.as_f64().expect("number"))
            .collect()
    };
    let values = nums(&v["values"][0]);
    let bases: Vec<Vec<f64>> = v["contributions"][0]["bases"]
        .as_array()
        .expect("bases")
        .iter()
        .map(nums)
        .collect();
    // The parts add up to the value (no residual in this pack).
    for k in 0..3 {
        let sum: f64 = bases.iter().map(|b| b[k]).sum();
        assert!((sum - values[k]).abs() < 1e-12, "{sum} vs {}", values[k]);
    }
    (values, bases)
}

#[test]
fn pack_edit_scales_mutes_adds_and_removes_through_the_core_edits() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("small.spmm");
    write_small_pack(&path);
    let p = path.to_str().expect("utf-8");
    let out = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let original = std::fs::read(&path).expect("read");

    // A unit scale writes the same bytes.
    let same = out("same.spmm");
    assert_ok(&meso(
        &[
            "pack",
            "edit",
            p,
            "-o",
            &same,
            "--cluster",
            "0",
            "--basis",
            "1",
            "--scale",
            "1,1,1",
        ],
        "",
    ));
    assert_eq!(std::fs::read(&same).expect("read"), original);

    // Scaling basis 1 of cluster 0 by 2 doubles its contribution at texel 0 (u 0.25,
    // v 0.75: cluster 0, bases 0 and 1) and leaves basis 0's as it was.
    let doubled = out("doubled.spmm");
    let o = meso(
        &[
            "pack",
            "edit",
            p,
            "-o",
            &doubled,
            "--cluster",
            "0",
            "--basis",
            "1",
            "--scale",
            "2",
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(
        v["changed_texels"], 2,
        "the two texels of cluster 0 weigh basis 1"
    );
    let (_, before) = eval_parts(p, "0.25,0.75");
    let (_, after) = eval_parts(&doubled, "0.25,0.75");
    assert_eq!(after[0], before[0]);
    for k in 0..3 {
        assert!((after[1][k] - 2.0 * before[1][k]).abs() < 1e-12 && before[1][k] > 0.0);
    }
    // Scales read their --cluster and --basis in order: basis 1 of cluster 0 doubled,
    // then the whole of cluster 1 (texel (1, 0), u 0.75, v 0.75) halved.
    let mixed = out("mixed.spmm");
    assert_ok(&meso(
        &[
            "pack",
            "edit",
            p,
            "-o",
            &mixed,
            "--cluster",
            "0",
            "--basis",
            "1",
            "--scale",
            "2",
            "--cluster",
            "1",
            "--scale",
            "0.5",
        ],
        "",
    ));
    assert_eq!(eval_parts(&mixed, "0.25,0.75").1, after);
    let (v0, _) = eval_parts(p, "0.75,0.75");
    let (v1, _) = eval_parts(&mixed, "0.75,0.75");
    for k in 0..3 {
        assert!((v1[k] - 0.5 * v0[k]).abs() < 1e-12);
    }
    // ... and 0.5 brings it back.
    let back = out("back.spmm");
    assert_ok(&meso(
        &[
            "pack",
            "edit",
            &doubled,
            "-o",
            &back,
            "--cluster",
            "0",
            "--basis",
            "1",
            "--scale",
            "0.5",
        ],
        "",
    ));
    assert_eq!(eval_parts(&back, "0.25,0.75").1, before);

    // Mute bakes: basis 1 loses its weights, basis 0 keeps them.
    let muted = out("muted.spmm");
    assert_ok(&meso(
        &["pack", "edit", p, "-o", &muted, "--mute", "0:1"],
        "",
    ));
    let (_, m) = eval_parts(&muted, "0.25,0.75");
    assert_eq!(m[0], before[0]);
    assert_eq!(m[1], vec![0.0; 3]);

    // Add a Lambertian basis to cluster 1 weighted only where the mask is white
    // (texel (1, 0)), then remove it again.
    let mask = dir.path().join("mask.png");
    image::GrayImage::from_raw(2, 2, vec![0, 255, 0, 0])
        .expect("2x2")
        .save(&mask)
        .expect("write mask");
    let added = out("added.spmm");
    let o = meso(
        &[
            "pack",
            "edit",
            p,
            "-o",
            &added,
            "--add-basis",
            "1",
            "--model",
            "lambertian",
            "--normal",
            "0.2,-1",
            "--add-weight",
            "0.1,0.2,0.3",
            "--texels",
            mask.to_str().expect("utf-8"),
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["added_basis"]["basis"], 1);
    assert_eq!(v["changed_texels"], 1);
    assert_eq!(
        meso(&["pack", "validate", &added], "").status.code(),
        Some(0)
    );
    let (_, at_painted) = eval_parts(&added, "0.75,0.75");
    assert!(at_painted[1].iter().all(|&x| x > 0.0), "{at_painted:?}");
    let (_, elsewhere) = eval_parts(&added, "0.25,0.25");
    assert_eq!(
        elsewhere[1],
        vec![0.0; 3],
        "cluster 1's other texel is unpainted"
    );
    let removed = out("removed.spmm");
    assert_ok(&meso(
        &[
            "pack",
            "edit",
            &added,
            "-o",
            &removed,
            "--remove-basis",
            "1:1",
        ],
        "",
    ));
    assert_eq!(
        eval_parts(&removed, "0.75,0.75"),
        eval_parts(p, "0.75,0.75")
    );

    // Bad indices and values exit 2 naming the option; nothing is written.
    let never = out("never.spmm");
    let bad = |args: &[&str], needles: &[&str]| {
        let mut all = vec!["pack", "edit", p, "-o", never.as_str()];
        all.extend_from_slice(args);
        assert_bad_input(&meso(&all, ""), needles);
        assert!(!Path::new(&never).exists());
    };
    bad(
        &["--cluster", "0", "--basis", "7", "--scale", "2"],
        &["--basis 7", "basis 7 of cluster 0"],
    );
    bad(
        &["--cluster", "3", "--scale", "2"],
        &["--cluster 3", "cluster 3"],
    );
    bad(
        &["--cluster", "0", "--scale", "-1"],
        &["--cluster 0", "non-negative"],
    );
    bad(
        &["--cluster", "0", "--scale", "1,x,1"],
        &["--scale #1", "1,x,1"],
    );
    bad(&["--scale", "2"], &["--scale #1", "no --cluster before it"]);
    bad(
        &["--cluster", "0", "--scale", "2", "--basis", "1"],
        &["give --scale after them"],
    );
    bad(
        &["--remove-basis", "1:4"],
        &["--remove-basis 1:4", "basis 4 of cluster 1"],
    );
    bad(
        &["--remove-basis", "1:0"],
        &["--remove-basis 1:0", "only basis"],
    );
    bad(&["--mute", "0:9"], &["--mute 0:9"]);
    bad(&["--add-basis", "0", "--model", "nope"], &["--model"]);
    bad(
        &["--add-basis", "0", "--model", "ward", "--param", "ax"],
        &["--param #1", "ax"],
    );
    bad(
        &["--cluster", "0", "--scale", "2", "--texels", p],
        &["--texels"],
    );
}

#[test]
fn render_writes_an_image_and_reports_json() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("r.exr");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    let out_arg = out.to_str().expect("utf-8");
    // Renders 2 frames of the default scene with `extra` flags, as JSON.
    let render = |extra: &[&str]| {
        let mut args = vec!["render", scene, "-o", out_arg, "--frames", "2", "--json"];
        args.extend_from_slice(extra);
        let o = meso(&args, "");
        assert_eq!(
            o.status.code(),
            Some(0),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        serde_json::from_str::<serde_json::Value>(&stdout(&o)).expect("JSON")
    };
    let v = render(&["--width", "24", "--height", "16"]);
    assert_eq!(v["frames"], 2);
    assert_eq!(v["mode"], "spmm");
    assert_eq!(v["rays"]["primary"], 2 * 24 * 16);
    assert!(v["rays"]["shadow"].as_u64().expect("count") > 0);
    assert!(v["rays_per_second"].as_f64().expect("rate") > 0.0);
    assert_eq!(v["nonfinite_dropped"], 0);
    let loaded = meso_render::scene::load_scene(std::path::Path::new(scene)).expect("scene");
    let layers = meso_render::layers::layer_count(&loaded);
    assert_eq!(
        v["film_bytes"],
        meso_render::Film::bytes_for(24, 16, layers)
    );
    let img = meso_materials::image::read_image(&out).expect("an EXR");
    assert_eq!((img.width(), img.height()), (24, 16));
    assert!(img.pixels().iter().any(|p| p[0] > 0.0), "something is lit");

    // The default scene draws two points on its area light per frame; `--light-samples`
    // overrides it: four trace about twice the shadow rays of two from the same
    // shading points (a point below a surface's horizon traces none, so not exactly);
    // out of range is an error naming the flag.
    assert_eq!(v["light_samples"], 2);
    let four = render(&["--width", "24", "--height", "16", "--light-samples", "4"]);
    assert_eq!(four["light_samples"], 4);
    assert_eq!(four["shading_points"], v["shading_points"]);
    let shadow = |v: &serde_json::Value| v["rays"]["shadow"].as_u64().expect("count") as f64;
    let ratio = shadow(&four) / shadow(&v);
    assert!((1.9..2.1).contains(&ratio), "shadow rays x{ratio}");
    let mut bad = vec!["render", scene, "-o", out_arg, "--light-samples", "65"];
    assert_bad_input(&meso(&bad, ""), &["--light-samples", "65", "1..=64"]);
    bad[5] = "0";
    assert_bad_input(&meso(&bad, ""), &["--light-samples", "0"]);

    // Three samples per pixel per frame: three times the primary rays.
    let v = render(&["--width", "8", "--height", "8", "--spp-per-frame", "3"]);
    assert_eq!(v["rays"]["primary"], 2 * 3 * 64);
    assert_eq!(v["samples_per_pixel"], 6);
    assert_bad_input(
        &meso(
            &[
                "render",
                scene,
                "-o",
                out.to_str().expect("utf-8"),
                "--spp-per-frame",
                "0",
            ],
            "",
        ),
        &["--spp-per-frame"],
    );

    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "version = 1\n[camera]\nposition = [0.0, 0.0, 1.0]\n").expect("write");
    assert_bad_input(
        &meso(
            &[
                "render",
                bad.to_str().expect("utf-8"),
                "-o",
                out.to_str().expect("utf-8"),
            ],
            "",
        ),
        &["bad.toml", "look_at"],
    );
}

#[test]
fn report_convergence_writes_csv_json_charts_and_the_reference() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("conv");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    let args = [
        "report",
        "convergence",
        scene,
        "-o",
        out.to_str().expect("utf-8"),
        "--width",
        "16",
        "--height",
        "16",
        "--reference-frames",
        "64",
        "--max-frames",
        "8",
        "--json",
    ];
    let o = meso(&args, "");
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    let variants: Vec<&str> = v["summaries"]
        .as_array()
        .expect("summaries")
        .iter()
        .map(|s| s["variant"].as_str().expect("name"))
        .collect();
    assert_eq!(
        variants,
        [
            "full",
            "full_denoised",
            "independent",
            "one_light_sample",
            "no_ao"
        ],
        "the default scene has AO, two light samples and no residual; the denoiser's and the independent sampler's rows come with every scene"
    );
    let csv = std::fs::read_to_string(out.join("convergence.csv")).expect("csv");
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(
        rows[0],
        "variant,reference,frames,seconds,rmse,psnr_db,mssim"
    );
    assert_eq!(
        rows.len(),
        1 + 5 * 8,
        "frames 1 to 8 for the five variants (the denoiser's rows too)"
    );
    for name in [
        "convergence_rmse.svg",
        "convergence_mssim.svg",
        "reference.png",
    ] {
        assert!(out.join(name).metadata().expect(name).len() > 100, "{name}");
    }
    let reference = meso_materials::image::read_image(&out.join("reference.exr")).expect("EXR");
    assert_eq!((reference.width(), reference.height()), (16, 16));
    let mut bad = args.to_vec();
    bad[10] = "4";
    assert_bad_input(&meso(&bad, ""), &["--max-frames", "--reference-frames"]);
}

const SMALL_BTF_RECIPE: &str = r#"
version = 1
name = "small weave"
width = 6
height = 6
direction_rings = [[0.0, 1], [45.0, 4], [70.0, 4]]
detail = 2
supersample = 1
[mesostructure]
kind = "weave"
depth = 2.0
threads = 2
[[region]]
[[region.lobe]]
model = "lambertian"
weight = [0.6, 0.3, 0.2]
[[region]]
[[region.lobe]]
model = "oren_nayar"
params = { sigma = 0.3 }
weight = [0.2, 0.3, 0.6]
[[region]]
[[region.lobe]]
model = "lambertian"
weight = [0.05, 0.05, 0.05]
"#;

#[test]
fn btf_synth_info_fit_and_slice() {
    let dir = tempfile::tempdir().expect("temp dir");
    let recipe = dir.path().join("weave.toml");
    std::fs::write(&recipe, SMALL_BTF_RECIPE).expect("write recipe");
    let btf = dir.path().join("weave.btf");
    let (r, b) = (
        recipe.to_str().expect("utf-8"),
        btf.to_str().expect("utf-8"),
    );
    let o = meso(&["btf", "synth", r, "-o", b, "--json"], "");
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
    assert_eq!(v["lights"], 9);
    let o = meso(&["btf", "info", b, "--json"], "");
    assert_eq!(o.status.code(), Some(0));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(
        (v["width"].as_u64(), v["view_dirs_deg"][5][0].as_f64()),
        (Some(6), Some(70.0))
    );

    let pack = dir.path().join("weave.spmm");
    let report = dir.path().join("report.json");
    let p = pack.to_str().expect("utf-8");
    let args = [
        "fit",
        b,
        "-o",
        p,
        "--clusters",
        "2",
        "--subclusters",
        "2",
        "--npca",
        "3",
        "--json",
    ];
    let mut with_report = args.to_vec();
    with_report.extend(["--report", report.to_str().expect("utf-8")]);
    let o = meso(&with_report, "");
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
    let rows = v["overall"]["rmse_npca"].as_array().expect("rows");
    assert_eq!(rows.len(), 4); // N_PCA 0, 1, 2 and 3
    assert!(v["compression_ratio"].as_f64().expect("ratio") > 0.0);
    for stage in ["clustering", "dictionary", "weights", "residual", "total"] {
        assert!(v["seconds"][stage].as_f64().is_some(), "{stage}");
    }
    let saved: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&report).expect("report written")).expect("JSON");
    assert_eq!(saved["overall"], v["overall"]);
    assert_eq!(meso(&["pack", "validate", p], "").status.code(), Some(0));
    // The residual at 8 bits: by trimming to a precision, or fitted so directly.
    let i8_pack = dir.path().join("weave_i8.spmm");
    let q = i8_pack.to_str().expect("utf-8");
    let o = meso(
        &[
            "pack",
            "trim",
            p,
            "-o",
            q,
            "--npca",
            "3",
            "--precision",
            "i8",
            "--json",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let trimmed: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    let bytes = std::fs::read(&i8_pack).expect("written");
    assert_eq!(trimmed["pack_bytes"].as_u64(), Some(bytes.len() as u64));
    let f16_len = std::fs::metadata(&pack).expect("pack").len();
    assert!(
        (bytes.len() as u64) < f16_len,
        "{} >= {f16_len}",
        bytes.len()
    );
    let header = |b: &[u8]| -> serde_json::Value {
        let n = u64::from_le_bytes(b[..8].try_into().expect("8 bytes")) as usize;
        serde_json::from_slice(&b[8..8 + n]).expect("JSON header")
    };
    let h = header(&bytes);
    assert_eq!(h["residual_components"]["dtype"], "I8");
    assert_eq!(h["residual_component_exponents"]["dtype"], "I8");
    assert!(
        h["__metadata__"]["provenance"]
            .as_str()
            .is_some_and(|s| s.ends_with("meso pack trim --npca 3 --precision i8")),
        "{}",
        h["__metadata__"]["provenance"]
    );
    assert_eq!(meso(&["pack", "validate", q], "").status.code(), Some(0));
    let o = meso(&["pack", "info", q, "--json"], "");
    let info: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(info["residual"]["precision"], "i8");
    assert!(stdout(&meso(&["pack", "info", p], "")).contains("f16 tables"));
    let mut direct = args.to_vec();
    direct[3] = q;
    direct.extend(["--precision", "i8"]);
    assert_eq!(meso(&direct, "").status.code(), Some(0));
    assert_eq!(
        header(&std::fs::read(&i8_pack).expect("written"))["residual_components"]["dtype"],
        "I8"
    );
    direct.push("--f32");
    assert_eq!(
        meso(&direct, "").status.code(),
        Some(2),
        "--precision and --f32 conflict"
    );
    // Same seed, same bytes.
    let first = std::fs::read(&pack).expect("pack");
    assert_eq!(meso(&args, "").status.code(), Some(0));
    assert_eq!(std::fs::read(&pack).expect("pack"), first);

    let png = dir.path().join("slice.png");
    let o = meso(
        &[
            "btf",
            "slice",
            b,
            "-o",
            png.to_str().expect("utf-8"),
            "--light",
            "45,0",
            "--view",
            "0,0",
            "--pack",
            p,
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(std::fs::metadata(&png).expect("png").len() > 0);
}

#[test]
fn btf_and_fit_bad_input_is_named() {
    let dir = tempfile::tempdir().expect("temp dir");
    let recipe = dir.path().join("bad.toml");
    std::fs::write(
        &recipe,
        SMALL_BTF_RECIPE.replace("threads = 2", "thread = 2"),
    )
    .expect("write");
    let out = dir.path().join("x.btf");
    let (r, x) = (
        recipe.to_str().expect("utf-8"),
        out.to_str().expect("utf-8"),
    );
    assert_bad_input(
        &meso(&["btf", "synth", r, "-o", x], ""),
        &["bad.toml", "thread", "line"],
    );
    assert!(!out.exists());
    assert_bad_input(&meso(&["btf", "info", "missing.btf"], ""), &["missing.btf"]);
    std::fs::write(&out, b"not a btf").expect("write");
    assert_bad_input(
        &meso(&["fit", x, "-o", "y.spmm"], ""),
        &["x.btf", "safetensors"],
    );
    assert_bad_input(
        &meso(
            &[
                "btf",
                "import",
                dir.path().to_str().expect("utf-8"),
                "-o",
                x,
            ],
            "",
        ),
        &["directions.csv"],
    );
    // A valid BTF with a bad setting.
    std::fs::write(&recipe, SMALL_BTF_RECIPE).expect("write");
    assert_eq!(
        meso(&["btf", "synth", r, "-o", x], "").status.code(),
        Some(0)
    );
    assert_bad_input(
        &meso(&["fit", x, "-o", "y.spmm", "--clusters", "0"], ""),
        &["--clusters"],
    );
    assert_bad_input(
        &meso(
            &[
                "btf", "slice", x, "-o", "s.png", "--light", "95,0", "--view", "0,0",
            ],
            "",
        ),
        &["--light"],
    );
}

#[test]
fn a_closed_output_pipe_ends_the_command_quietly() {
    use std::io::{BufRead, BufReader};
    // Far more output than a pipe buffers; the reader stops after one line.
    let input: String = (0..200_000).map(|_| "0,0,1,0,0,1\n").collect();
    let mut child = Command::new(env!("CARGO_BIN_EXE_meso"))
        .args(["brdf", "eval", "--model", "lambertian"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("meso starts");
    let mut stdin = child.stdin.take().expect("stdin");
    let writer = std::thread::spawn(move || {
        let _ = stdin.write_all(input.as_bytes());
    });
    let mut first = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut first)
        .expect("one line");
    assert!(first.starts_with("3.18309886e-1"), "{first}");
    let out = child.wait_with_output().expect("meso ends");
    let _ = writer.join();
    let err = String::from_utf8_lossy(&out.stderr);
    // Ended by SIGPIPE like any Unix filter: no panic, no error line.
    assert!(err.is_empty(), "{err}");
    assert_ne!(out.status.code(), Some(101), "not a panic");
}

fn assert_ok(o: &Output) {
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn merl_tabulate_validate_info_eval_round_trip() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("lambert.binary");
    let o_s = out.to_str().expect("utf-8");
    let o = meso(
        &[
            "merl",
            "tabulate",
            "--model",
            "lambertian",
            "--albedo",
            "0.8,0.5,0.2",
            "-o",
            o_s,
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["model"], "lambertian");
    assert_eq!(v["cells"], 1_458_000);
    assert_eq!(
        std::fs::metadata(&out).expect("written").len(),
        34_992_012,
        "the MERL file size"
    );

    let o = meso(&["merl", "validate", o_s], "");
    assert_ok(&o);
    assert!(stdout(&o).contains("valid MERL BRDF"), "{}", stdout(&o));
    let o = meso(&["merl", "validate", o_s, "--json"], "");
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["valid"], true);

    let o = meso(&["merl", "info", o_s, "--json"], "");
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["dimensions"], serde_json::json!([90, 90, 180]));
    for (c, want) in [0.8, 0.5, 0.2].into_iter().enumerate() {
        let a = v["channels"][c]["albedo_at_normal"]
            .as_f64()
            .expect("number");
        assert!((a - want).abs() < 1e-6, "channel {c}: albedo {a} vs {want}");
    }
    assert!(stdout(&meso(&["merl", "info", o_s], "")).contains("albedo at normal"));

    // A Lambertian table is albedo / pi wherever both directions are above the
    // horizon (including grazing ones, unnormalised input), 0 elsewhere.
    let rows =
        "0,0,1,0,0,1\n0.3,0.1,2,0,-0.2,5\n# comment\n0.999,0,0.01,-0.5,0.5,0.1\n0,0,-1,0,0,1\n";
    let o = meso(&["merl", "eval", o_s], rows);
    assert_ok(&o);
    let lines: Vec<Vec<f64>> = stdout(&o)
        .lines()
        .map(|l| l.split(',').map(|x| x.parse().expect("a number")).collect())
        .collect();
    assert_eq!(lines.len(), 4, "{}", stdout(&o));
    let inv_pi = std::f64::consts::FRAC_1_PI;
    for line in &lines[..3] {
        for (got, a) in line.iter().zip([0.8, 0.5, 0.2]) {
            assert!((got - a * inv_pi).abs() < 1e-8, "{line:?}");
        }
    }
    assert_eq!(lines[3], vec![0.0, 0.0, 0.0]);
    let o = meso(&["merl", "eval", o_s, "--trilinear", "--json"], rows);
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["lookup"], "trilinear");
    assert_eq!(v["values"].as_array().map(Vec::len), Some(4));

    // An analytic model tabulated and looked up at its bin centre matches `brdf eval`
    // there: theta_h = 0 (index 0 centre is 4.8e-5 rad, negligible), theta_d at the
    // centre of bin 30, so the mirror pair at 30.5 degrees from the normal.
    let ward = dir.path().join("ward.binary");
    let w_s = ward.to_str().expect("utf-8");
    let model = ["--model", "ward", "--param", "ax=0.3", "--param", "ay=0.3"];
    let mut args = vec!["merl", "tabulate"];
    args.extend(model);
    args.extend(["-o", w_s]);
    assert_ok(&meso(&args, ""));
    let t = 30.5f64.to_radians();
    let row = format!("{},0,{},{},0,{}\n", t.sin(), t.cos(), -t.sin(), t.cos());
    let o = meso(&["merl", "eval", w_s], &row);
    assert_ok(&o);
    let r: f64 = stdout(&o)
        .trim()
        .split(',')
        .next()
        .and_then(|x| x.parse().ok())
        .expect("r");
    let mut args = vec!["brdf", "eval"];
    args.extend(model);
    let f: f64 = stdout(&meso(&args, &row)).trim().parse().expect("f");
    assert!((r - f).abs() < 1e-3 * f, "merl {r} vs analytic {f}");
}

#[test]
fn merl_bad_input_exits_2_naming_the_fault() {
    let dir = tempfile::tempdir().expect("temp dir");
    let good = dir.path().join("good.binary");
    assert_ok(&meso(
        &[
            "merl",
            "tabulate",
            "--model",
            "lambertian",
            "-o",
            good.to_str().expect("utf-8"),
        ],
        "",
    ));
    let bytes = std::fs::read(&good).expect("read");
    let write = |name: &str, b: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, b).expect("write");
        p.to_str().expect("utf-8").to_string()
    };
    let short = write("short.binary", &bytes[..1000]);
    for cmd in ["validate", "info", "eval"] {
        assert_bad_input(
            &meso(&["merl", cmd, &short], "0,0,1,0,0,1\n"),
            &["short.binary", "1000 bytes", "34992012"],
        );
    }
    let mut dims = bytes.clone();
    dims[8..12].copy_from_slice(&360i32.to_le_bytes());
    assert_bad_input(
        &meso(&["merl", "validate", &write("dims.binary", &dims)], ""),
        &["dims.binary", "90, 90, 360"],
    );
    // A NaN in the green block, cell 1000.
    let mut nan = bytes.clone();
    let at = 12 + (1_458_000 + 1000) * 8;
    nan[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    assert_bad_input(
        &meso(&["merl", "validate", &write("nan.binary", &nan)], ""),
        &["nan.binary", "green channel", "cell 1000", "NaN"],
    );
    let mut empty = bytes[..12].to_vec();
    empty.extend(std::iter::repeat_n((-1.0f64).to_le_bytes(), 3 * 1_458_000).flatten());
    assert_bad_input(
        &meso(&["merl", "validate", &write("empty.binary", &empty)], ""),
        &["empty.binary", "no data"],
    );
    assert_bad_input(
        &meso(&["merl", "validate", "/no/such.binary"], ""),
        &["/no/such.binary"],
    );
    let g = good.to_str().expect("utf-8");
    assert_bad_input(
        &meso(&["merl", "eval", g], "0,0,1,0,0\n"),
        &["stdin line 1"],
    );
    let out = dir.path().join("t.binary");
    let o_s = out.to_str().expect("utf-8");
    assert_bad_input(
        &meso(&["merl", "tabulate", "--model", "phong", "-o", o_s], ""),
        &["phong"],
    );
    assert_bad_input(
        &meso(
            &[
                "merl",
                "tabulate",
                "--model",
                "lambertian",
                "--albedo",
                "1,nan,1",
                "-o",
                o_s,
            ],
            "",
        ),
        &["--albedo", "green"],
    );
    assert_bad_input(
        &meso(
            &[
                "merl",
                "tabulate",
                "--model",
                "lambertian",
                "--albedo",
                "1,1",
                "-o",
                o_s,
            ],
            "",
        ),
        &["--albedo"],
    );
    assert!(!out.exists(), "nothing is written on bad input");
    // An output that cannot be written is exit 1, one line naming it.
    let o = meso(
        &[
            "merl",
            "tabulate",
            "--model",
            "lambertian",
            "-o",
            "/no/such/dir/t.binary",
        ],
        "",
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("error: ") && err.contains("t.binary"),
        "{err}"
    );
}

#[test]
fn render_modes_devices_and_unsupported_scenes_exit_2_naming_why() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("r.exr");
    let out_arg = out.to_str().expect("utf-8");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/env.toml");
    let render = |extra: &[&str]| {
        let mut args = vec![
            "render", scene, "-o", out_arg, "--width", "16", "--height", "16",
        ];
        args.extend_from_slice(extra);
        meso(&args, "")
    };
    // The adaptive mode names the material it cannot shade (an SPMM pack); devices
    // not built yet say so; unknown names are usage errors.
    assert_bad_input(
        &render(&["--mode", "adaptive"]),
        &["adaptive", "material `cloth` (spmm)"],
    );
    // The biscale mode names what it cannot render: lights, AO, no environment.
    let default = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    assert_bad_input(
        &meso(&["render", default, "-o", out_arg, "--mode", "biscale"], ""),
        &[
            "biscale",
            "light[0] (area)",
            "[ambient]",
            "without [environment]",
        ],
    );
    assert_bad_input(
        &render(&["--mode", "biscale", "--device", "gpu"]),
        &["biscale", "gpu", "not built yet"],
    );
    assert_bad_input(
        &render(&["--mode", "fast"]),
        &["fast", "spmm, biscale, adaptive"],
    );
    // The environment scene renders in its own mode, which --json names with its counters.
    let o = render(&[
        "--frames", "2", "--json", "--mode", "spmm", "--device", "cpu",
    ]);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(
        (v["mode"].as_str(), v["device"].as_str()),
        (Some("spmm"), Some("cpu"))
    );
    assert_eq!(v["samples"], 2 * 16 * 16);
    assert!(v["rays"]["environment"].as_u64().expect("count") > 0);
    assert!(v["shading_points"].as_u64().expect("count") > 0);
    // A MERL table (here tabulated at load) renders in the spmm mode; the modes that
    // are not built yet refuse it before writing anything.
    let merl_scene = dir.path().join("merl.toml");
    std::fs::write(
        &merl_scene,
        r#"version = 1
[camera]
position = [0.0, 0.5, 2.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y_deg = 40.0
[materials.gold]
kind = "merl"
tabulate = { model = "lambertian", albedo = [0.9, 0.7, 0.2] }
[[light]]
kind = "point"
position = [0.0, 1.0, 0.5]
intensity = [2.0, 2.0, 2.0]
[[quad]]
corner = [-1.0, 0.0, 1.0]
edge_u = [2.0, 0.0, 0.0]
edge_v = [0.0, 0.0, -2.0]
material = "gold"
"#,
    )
    .expect("write scene");
    let merl_arg = merl_scene.to_str().expect("utf-8");
    // The spmm mode on the GPU renders what the CPU does: here 17 lights (once the
    // GPU's limit, refused by name) on a MERL table.
    let many = dir.path().join("many.toml");
    let mut text = std::fs::read_to_string(&merl_scene).expect("the scene");
    for k in 0..16 {
        text.push_str(&format!(
            "[[light]]\nkind = \"point\"\nposition = [{}, 1.0, 0.5]\nintensity = [0.1, 0.1, 0.1]\n",
            k as f64 * 0.1
        ));
    }
    std::fs::write(&many, text).expect("write scene");
    let o = meso(
        &[
            "render",
            many.to_str().expect("utf-8"),
            "-o",
            out_arg,
            "--width",
            "8",
            "--height",
            "8",
            "--frames",
            "1",
            "--device",
            "gpu",
            "--json",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["device"].as_str(), Some("gpu"));
    let shaded = dir.path().join("merl.exr");
    let o = meso(
        &[
            "render",
            merl_arg,
            "-o",
            shaded.to_str().expect("utf-8"),
            "--width",
            "8",
            "--height",
            "8",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let img = meso_materials::image::read_image(&shaded).expect("written");
    // Lambertian gold under a point light above: red > green > blue where lit.
    let centre = img.get(4, 4);
    assert!(
        centre[0] > centre[1] && centre[1] > centre[2] && centre[2] > 0.0,
        "{centre:?}"
    );
}

#[test]
fn render_refuses_a_film_that_cannot_fit_naming_its_bytes() {
    // The default scene with 15 point lights more: 16 lights, one layer each, 19
    // layers in all, 145 GB at 16384^2: more than any machine these tests run on.
    let dir = tempfile::tempdir().expect("temp dir");
    let scenes = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes");
    let text = std::fs::read_to_string(format!("{scenes}/default.toml")).expect("scene");
    // The copy lives elsewhere: its relative paths become absolute.
    let mut scene = text
        .replace("pack = \"../../", &format!("pack = \"{scenes}/../../"))
        .replace("path = \"meshes/", &format!("path = \"{scenes}/meshes/"));
    for k in 0..15 {
        scene.push_str(&format!(
            "\n[[light]]\nkind = \"point\"\nposition = [{}, 1.5, 0.0]\nintensity = [0.1, 0.1, 0.1]\n",
            k as f64 * 0.1
        ));
    }
    let path = dir.path().join("many.toml");
    std::fs::write(&path, scene).expect("write scene");
    let out = dir.path().join("r.exr");
    let o = meso(
        &[
            "render",
            path.to_str().expect("utf-8"),
            "-o",
            out.to_str().expect("utf-8"),
            "--width",
            "16384",
            "--height",
            "16384",
            "--frames",
            "1",
        ],
        "",
    );
    let bytes = meso_render::Film::bytes_for(16384, 16384, 19);
    assert_bad_input(&o, &[&bytes.to_string(), "bytes", "19 layers"]);
    assert!(!out.exists());
}

#[test]
fn bench_rays_reports_both_kinds_on_the_spec_rays() {
    let mesh = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/meshes/teapot.obj"
    );
    let o = meso(
        &[
            "bench",
            "rays",
            mesh,
            "--size",
            "24",
            "--threads",
            "1",
            "--json",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    // The teapot has 992 faces; every one is a proper triangle.
    assert_eq!(v["triangles"], 992);
    assert_eq!(
        (v["threads"].as_u64(), v["rays_per_kind"].as_u64()),
        (Some(1), Some(576))
    );
    for key in ["coherent_mrays", "incoherent_mrays", "build_ms"] {
        assert!(
            v[key].as_f64().is_some_and(|x| x > 0.0 && x.is_finite()),
            "{key}: {v}"
        );
    }
    // The spec's camera sees the teapot; rays leaving its surface hit it sometimes
    // (the spout and handle) and escape mostly.
    let coherent = v["coherent_hit_fraction"].as_f64().expect("fraction");
    let incoherent = v["incoherent_hit_fraction"].as_f64().expect("fraction");
    assert!(coherent > 0.05 && coherent < 0.9, "{coherent}");
    assert!(incoherent > 0.0 && incoherent < 0.6, "{incoherent}");
    // --baseline times obvhs's traversal too: it finds the same hits; --save-rays
    // writes the triangles, the rays and the tracer's distances as f32.
    let dir = tempfile::tempdir().expect("temp dir");
    let saved = dir.path().join("rays");
    let o = meso(
        &[
            "bench",
            "rays",
            mesh,
            "--size",
            "24",
            "--threads",
            "1",
            "--json",
            "--baseline",
            "--save-rays",
            saved.to_str().expect("path"),
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let b: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    for kind in ["coherent", "incoherent"] {
        assert!(
            b[format!("baseline_{kind}_mrays")]
                .as_f64()
                .is_some_and(|x| x > 0.0)
        );
        assert_eq!(
            b[format!("baseline_{kind}_hit_fraction")],
            b[format!("{kind}_hit_fraction")]
        );
        assert_eq!(
            b[format!("{kind}_hit_fraction")],
            v[format!("{kind}_hit_fraction")]
        );
        let floats = |name: String| -> Vec<f32> {
            std::fs::read(saved.join(name))
                .expect("saved")
                .chunks(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect()
        };
        let rays = floats(format!("{kind}.f32"));
        let t = floats(format!("{kind}_t.f32"));
        assert_eq!((rays.len(), t.len()), (6 * 576, 576));
        // Unit directions; as many finite distances as the hit fraction says.
        for r in rays.chunks(6) {
            let len = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
            assert!((len - 1.0).abs() < 1e-5, "{r:?}");
        }
        let hits = t.iter().filter(|t| t.is_finite()).count() as f64 / 576.0;
        assert_eq!(Some(hits), b[format!("{kind}_hit_fraction")].as_f64());
    }
    let triangles = std::fs::read(saved.join("triangles.f32")).expect("saved");
    assert_eq!(triangles.len(), 992 * 9 * 4);
    assert_bad_input(
        &meso(&["bench", "rays", mesh, "--threads", "0"], ""),
        &["--threads"],
    );
    assert_bad_input(
        &meso(&["bench", "rays", mesh, "--size", "0"], ""),
        &["--size"],
    );
    assert_bad_input(&meso(&["bench", "rays", "/no/such.obj"], ""), &["such.obj"]);
    // --embree: a library that cannot be loaded, or one that is not Embree, is named.
    assert_bad_input(
        &meso(
            &[
                "bench",
                "rays",
                mesh,
                "--embree",
                "/no/such/libembree4.so.4",
            ],
            "",
        ),
        &["/no/such/libembree4.so.4"],
    );
    #[cfg(target_os = "linux")]
    assert_bad_input(
        &meso(&["bench", "rays", mesh, "--embree", "libm.so.6"], ""),
        &["libm.so.6", "not an Embree library", "rtcNewDevice"],
    );
}

/// A regression manifest in `dir` over the repository's default scene: its own
/// material and the shipped woven wool substituted, `extra` appended.
fn regress_manifest(dir: &Path, size: u32, frames: u32, extra: &str) -> std::path::PathBuf {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = format!(
        "version = 1\ngoldens = \"goldens\"\n\n[defaults]\nwidth = {size}\nheight = {size}\nframes = {frames}\nmax_relative_rmse = 0.001\n\n[scenes.default]\npath = \"{}\"\nreplace = \"leather\"\n\n[materials.wool]\nkind = \"spmm\"\npack = \"{}\"\n\n[[matrix]]\nscenes = [\"default\"]\nmaterials = [\"scene\", \"wool\"]\nmodes = [\"spmm\"]\n{extra}",
        repo.join("tests/scenes/default.toml").display(),
        repo.join("materials/woven_wool.spmm").display(),
    );
    let path = dir.join("manifest.toml");
    std::fs::write(&path, text).expect("manifest");
    path
}

#[test]
fn regress_exit_codes_json_update_log_and_junit() {
    let dir = tempfile::tempdir().expect("temp dir");
    let m = regress_manifest(dir.path(), 24, 2, "");
    let ms = m.to_str().expect("utf-8 path");
    // No goldens yet: exit 1, each case says how to create its golden.
    let o = meso(&["regress", ms], "");
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("error: 2 of 2 cases failed: "), "{err}");
    assert!(stdout(&o).contains("--update --reason"), "{}", stdout(&o));
    // --update needs a reason, and a reason needs --update.
    assert_bad_input(&meso(&["regress", ms, "--update"], ""), &["--reason"]);
    assert_bad_input(&meso(&["regress", ms, "--reason", "x"], ""), &["--update"]);
    let o = meso(
        &["regress", ms, "--update", "--reason", "first goldens"],
        "",
    );
    assert_ok(&o);
    let log = std::fs::read_to_string(dir.path().join("goldens/LOG.md")).expect("log");
    assert!(log.contains("- reason: first goldens"), "{log}");
    assert!(log.contains("--update --reason 'first goldens'"), "{log}");
    assert!(
        log.contains("cases: `default.scene.spmm-cpu` `default.wool.spmm-cpu`"),
        "{log}"
    );
    assert!(
        log.contains(&format!("- meso: {}", env!("CARGO_PKG_VERSION"))),
        "{log}"
    );
    for case in ["default.scene.spmm-cpu", "default.wool.spmm-cpu"] {
        assert!(dir.path().join(format!("goldens/{case}.exr")).is_file());
    }
    // All pass: exit 0, one JSON object, a report folder and a JUnit file.
    let report = dir.path().join("report");
    let junit = dir.path().join("junit.xml");
    let o = meso(
        &[
            "regress",
            ms,
            "--json",
            "--jobs",
            "2",
            "-o",
            report.to_str().expect("utf-8"),
            "--junit",
            junit.to_str().expect("utf-8"),
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert_eq!(
        (v["total"].as_u64(), v["passed"].as_u64()),
        (Some(2), Some(2)),
        "{v}"
    );
    assert_eq!(
        v["cases"][0]["metrics"]["identical"],
        serde_json::json!(true)
    );
    for f in ["index.html", "summary.md", "report.json"] {
        assert!(report.join(f).is_file(), "{f}");
    }
    let x = std::fs::read_to_string(&junit).expect("junit");
    assert!(x.contains("tests=\"2\" failures=\"0\""), "{x}");
    // Another seed changes every render: exit 1 naming both cases; the JUnit file
    // says so too.
    let m = regress_manifest(dir.path(), 24, 2, "seed = 9\n");
    let ms = m.to_str().expect("utf-8 path");
    let o = meso(
        &["regress", ms, "--junit", junit.to_str().expect("utf-8")],
        "",
    );
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("default.scene.spmm-cpu") && err.contains("default.wool.spmm-cpu"),
        "{err}"
    );
    let x = std::fs::read_to_string(&junit).expect("junit");
    assert!(x.contains("tests=\"2\" failures=\"2\""), "{x}");
    // Shards: every case in one of the two; merged, one report and one JUnit file
    // with both failures, and exit 1.
    let mut total = 0;
    let mut dirs = Vec::new();
    for (i, k) in ["1/2", "2/2"].into_iter().enumerate() {
        let d = dir.path().join(format!("shard{i}"));
        let o = meso(
            &[
                "regress",
                ms,
                "--shard",
                k,
                "--json",
                "-o",
                d.to_str().expect("utf-8"),
            ],
            "",
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
        total += v["total"].as_u64().expect("total");
        dirs.push(d.to_str().expect("utf-8").to_string());
    }
    assert_eq!(total, 2);
    let merged = dir.path().join("merged");
    let merged_junit = dir.path().join("merged.xml");
    let o = meso(
        &[
            "regress",
            "merge",
            &dirs[0],
            &dirs[1],
            "-o",
            merged.to_str().expect("utf-8"),
            "--junit",
            merged_junit.to_str().expect("utf-8"),
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(merged.join("index.html").is_file());
    let x = std::fs::read_to_string(&merged_junit).expect("merged junit");
    assert!(x.contains("tests=\"2\" failures=\"2\""), "{x}");
    assert_bad_input(
        &meso(
            &[
                "regress",
                "merge",
                &dirs[0],
                "-o",
                merged.to_str().expect("utf-8"),
            ],
            "",
        ),
        &["shard(s) 2/2 missing"],
    );
}

#[test]
fn regress_bad_input_exits_2_naming_the_place() {
    let dir = tempfile::tempdir().expect("temp dir");
    let m = regress_manifest(dir.path(), 24, 2, "colour = 3\n");
    let ms = m.to_str().expect("utf-8 path");
    assert_bad_input(
        &meso(&["regress", ms], ""),
        &["manifest.toml` line 22", "colour"],
    );
    let m = regress_manifest(
        dir.path(),
        24,
        2,
        "\n[materials.velvet]\nkind = \"btf\"\npath = \"velvet.btf\"\n\n[[case]]\nscene = \"default\"\nmaterial = \"velvet\"\nmode = \"spmm\"\n",
    );
    let ms = m.to_str().expect("utf-8 path");
    assert_bad_input(
        &meso(&["regress", ms], ""),
        &[
            "case `default.velvet.spmm-cpu`",
            "line 25, `materials.velvet.path`",
            "velvet.btf",
        ],
    );
    let m = regress_manifest(dir.path(), 24, 2, "");
    let ms = m.to_str().expect("utf-8 path");
    assert_bad_input(
        &meso(&["regress", ms, "--only", "nothing*"], ""),
        &["matches no case"],
    );
    assert_bad_input(
        &meso(&["regress", ms, "--shard", "3/2"], ""),
        &["--shard", "K/N"],
    );
    assert_bad_input(&meso(&["regress", ms, "--jobs", "0"], ""), &["--jobs"]);
    assert_bad_input(
        &meso(&["regress", "/no/such.toml"], ""),
        &["/no/such.toml", "cannot read"],
    );
    // A replaced material the scene does not have names the manifest line and the case.
    let text = std::fs::read_to_string(&m)
        .expect("text")
        .replace("replace = \"leather\"", "replace = \"suede\"");
    std::fs::write(&m, text).expect("edit");
    assert_bad_input(
        &meso(&["regress", ms], ""),
        &[
            "case `default.wool.spmm-cpu`",
            "line 12",
            "no material `suede`",
            "leather",
        ],
    );
    // merge: not a report folder.
    assert_bad_input(
        &meso(
            &[
                "regress",
                "merge",
                dir.path().to_str().expect("utf-8"),
                "-o",
                "x",
            ],
            "",
        ),
        &["report.json"],
    );
}

/// `--update` renders every case before it writes: killed while rendering, every old
/// golden and the log stay as they were.
#[test]
fn regress_update_killed_midway_keeps_the_old_goldens() {
    let dir = tempfile::tempdir().expect("temp dir");
    let m = regress_manifest(dir.path(), 16, 1, "");
    let ms = m.to_str().expect("utf-8 path");
    assert_ok(&meso(&["regress", ms, "--update", "--reason", "old"], ""));
    let goldens = dir.path().join("goldens");
    let snapshot = || -> Vec<(std::ffi::OsString, Vec<u8>)> {
        let mut files: Vec<_> = std::fs::read_dir(&goldens)
            .expect("goldens")
            .map(|e| {
                let e = e.expect("entry");
                (e.file_name(), std::fs::read(e.path()).expect("readable"))
            })
            .collect();
        files.sort();
        files
    };
    let before = snapshot();
    assert_eq!(before.len(), 3, "two goldens and the log");
    // Larger and longer on another seed, on one thread: seconds of rendering on any
    // machine to kill into.
    regress_manifest(dir.path(), 256, 64, "seed = 3\n");
    let mut child = Command::new(env!("CARGO_BIN_EXE_meso"))
        .args([
            "regress",
            ms,
            "--update",
            "--reason",
            "new",
            "--threads",
            "1",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("meso starts");
    std::thread::sleep(std::time::Duration::from_millis(700));
    let still_running = child.try_wait().expect("wait").is_none();
    child.kill().expect("kill");
    let status = child.wait().expect("reaped");
    assert!(
        still_running && !status.success(),
        "the update finished before it could be killed ({status}); the test needs a longer render"
    );
    assert_eq!(
        snapshot(),
        before,
        "goldens or log changed by a killed update"
    );
}

#[test]
fn render_denoises_only_when_asked() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    let render = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let out_arg = out.to_str().expect("utf-8").to_owned();
        let mut args = vec![
            "render", scene, "-o", &out_arg, "--width", "32", "--height", "32", "--frames", "1",
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = meso(&args, "");
        assert_eq!(
            o.status.code(),
            Some(0),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
        (
            meso_materials::image::read_image(&out).expect("written"),
            v["denoised"].clone(),
        )
    };
    let (plain, flag) = render("a.exr", &[]);
    let (again, _) = render("b.exr", &[]);
    let (filtered, flag_on) = render("c.exr", &["--denoise"]);
    assert_eq!(
        (flag, flag_on),
        (serde_json::json!(false), serde_json::json!(true))
    );
    // Without the flag the image is the estimate, bit for bit.
    assert_eq!(plain, again);
    // With it, the one-sample noise is smoothed: less variation between neighbours.
    let variation = |img: &meso_materials::image::Image| -> f64 {
        (1..32u32)
            .flat_map(|y| (1..32u32).map(move |x| (x, y)))
            .map(|(x, y)| f64::from((img.get(x, y)[1] - img.get(x - 1, y)[1]).abs()))
            .sum()
    };
    assert!(
        variation(&filtered) < 0.8 * variation(&plain),
        "{} vs {}",
        variation(&filtered),
        variation(&plain)
    );
}

#[test]
fn bench_stroke_times_each_step_and_restarts_fewer_pixels_than_the_material() {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    let o = meso(
        &[
            "bench",
            "stroke",
            scene,
            "--size",
            "48",
            "--strokes",
            "3",
            "--warm-frames",
            "1",
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    let parts: Vec<&str> = v["ms"]
        .as_array()
        .expect("parts")
        .iter()
        .map(|p| p["part"].as_str().expect("name"))
        .collect();
    assert_eq!(
        parts,
        [
            "dab",
            "pack edit",
            "apply",
            "frame + image",
            "stroke to frame"
        ]
    );
    let whole: Vec<&str> = v["whole_frame_ms"]
        .as_array()
        .expect("the whole-frame parts")
        .iter()
        .map(|p| p["part"].as_str().expect("name"))
        .collect();
    assert_eq!(whole, parts);
    for p in v["ms"]
        .as_array()
        .expect("parts")
        .iter()
        .chain(v["whole_frame_ms"].as_array().expect("parts"))
    {
        let (med, max) = (
            p["median"].as_f64().expect("ms"),
            p["max"].as_f64().expect("ms"),
        );
        assert!(med >= 0.0 && max >= med, "{p}");
    }
    let restarted = v["restarted_pixels_median"].as_u64().expect("count");
    let material = v["pixels_of_material"].as_u64().expect("count");
    assert!(
        restarted > 0 && restarted < material,
        "{restarted} of {material}"
    );
    assert_bad_input(
        &meso(&["bench", "stroke", scene, "--size", "8"], ""),
        &["--size"],
    );
}

#[test]
fn precompute_biscale_reports_json_and_writes_a_cache() {
    let dir = tempfile::tempdir().expect("temp dir");
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
    // A floor and a wall beside it (occlusion) under the studio map: 8 vertices.
    let scene = dir.path().join("plane.toml");
    std::fs::write(
        &scene,
        format!(
            r#"version = 1
[render]
width = 16
height = 16
[camera]
position = [0.0, 2.0, 3.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y_deg = 40.0
[materials.white]
kind = "brdf"
model = "lambertian"
albedo = [0.6, 0.6, 0.6]
[[quad]]
corner = [-1.0, 0.0, 1.0]
edge_u = [2.0, 0.0, 0.0]
edge_v = [0.0, 0.0, -2.0]
material = "white"
[[quad]]
corner = [0.0, 0.0, 1.0]
edge_u = [0.0, 0.0, -2.0]
edge_v = [0.0, 1.0, 0.0]
material = "white"
[environment]
path = "{root}/materials/env/env_studio.exr"
strength = 1.0
"#
        ),
    )
    .expect("write scene");
    let cache = dir.path().join("plane.biscale");
    let scene_arg = scene.to_str().expect("utf-8");
    let cache_arg = cache.to_str().expect("utf-8");
    let o = meso(
        &[
            "precompute",
            scene_arg,
            "--mode",
            "biscale",
            "-o",
            cache_arg,
            "--cube-n",
            "8",
            "--json",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
    for key in [
        "seconds",
        "vertices",
        "local_dirs",
        "env_pixels",
        "dense_nonzeros",
        "biclusters",
        "flop_ratio",
        "bytes_dense",
        "bytes_biclustered",
        "bytes_cpca",
        "bytes_sh",
        "max_abs_error",
    ] {
        assert!(v.get(key).is_some(), "missing `{key}` in {v}");
    }
    assert_eq!(v["vertices"], 8);
    assert_eq!(v["local_dirs"], 64);
    assert_eq!(v["env_pixels"], 6 * 8 * 8);
    assert!(v["flop_ratio"].as_f64().expect("number") <= 1.0);
    assert!(v["max_rel_error"].as_f64().expect("number") < 1e-6);
    assert!(cache.exists(), "the cache was written");
    // Bad input: another mode, a scene without an environment.
    assert_bad_input(
        &meso(&["precompute", scene_arg, "--mode", "spmm"], ""),
        &["spmm", "only the biscale mode"],
    );
    let default = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    assert_bad_input(
        &meso(&["precompute", default, "--mode", "biscale"], ""),
        &["biscale", "without [environment]"],
    );
}

#[test]
fn report_fit_measures_a_pack_against_its_btf_as_compare_does() {
    let dir = tempfile::tempdir().expect("temp dir");
    let recipe = dir.path().join("weave.toml");
    std::fs::write(&recipe, SMALL_BTF_RECIPE).expect("write recipe");
    let btf = dir.path().join("weave.btf");
    let pack = dir.path().join("weave.spmm");
    let (r, b, p) = (
        recipe.to_str().expect("utf-8"),
        btf.to_str().expect("utf-8"),
        pack.to_str().expect("utf-8"),
    );
    assert_eq!(
        meso(&["btf", "synth", r, "-o", b], "").status.code(),
        Some(0)
    );
    let o = meso(
        &[
            "fit",
            b,
            "-o",
            p,
            "--clusters",
            "2",
            "--subclusters",
            "2",
            "--npca",
            "2",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let out = dir.path().join("report");
    let o_arg = out.to_str().expect("utf-8");
    let o = meso(
        &[
            "report", "fit", b, p, "-o", o_arg, "--width", "24", "--height", "24", "--frames", "2",
            "--json",
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
    assert_eq!(
        v["pack_bytes"].as_u64(),
        Some(std::fs::metadata(&pack).expect("pack").len())
    );
    for key in [
        "image_relative_rmse",
        "image_mssim",
        "fit_image_relative_rmse",
        "fit_image_mssim",
        "table_relative_rmse",
        "table_grazing_relative_rmse",
        "table_elsewhere_relative_rmse",
        "table_basis_relative_rmse",
    ] {
        let x = v[key].as_f64().unwrap_or_else(|| panic!("{key} in {v}"));
        assert!(x.is_finite() && x >= 0.0, "{key} = {x}");
    }
    // The residual is fitted to the table: it is closer than the basis sum alone.
    assert!(v["table_relative_rmse"].as_f64() < v["table_basis_relative_rmse"].as_f64());
    let scenes = v["scenes"].as_array().expect("scenes");
    assert_eq!(scenes.len(), 2);
    let (mut worst_mssim, mut worst_fit_mssim) = (1.0f64, 1.0f64);
    for s in scenes {
        let file = |k: &str| out.join(s[k].as_str().expect("file name"));
        assert!(file("side_by_side").is_file());
        let c = meso(
            &[
                "compare",
                file("btf_image").to_str().expect("utf-8"),
                file("pack_image").to_str().expect("utf-8"),
                "--json",
            ],
            "",
        );
        assert_eq!(
            c.status.code(),
            Some(0),
            "{}",
            String::from_utf8_lossy(&c.stderr)
        );
        let c: serde_json::Value = serde_json::from_str(&stdout(&c)).expect("JSON");
        assert_eq!(c["mssim"], s["image_mssim"], "{}", s["scene"]);
        assert_eq!(c["rmse"], s["image_rmse"], "{}", s["scene"]);
        assert_eq!(c["psnr_db"], s["image_psnr_db"], "{}", s["scene"]);
        worst_mssim = worst_mssim.min(s["image_mssim"].as_f64().expect("mssim"));
        // The split: the fit's part is the BTF against the pack's tabulation, the
        // interpolation's the tabulation against the pack; RMSE is a norm, so the two
        // parts bound the whole.
        assert!(file("fit_side_by_side").is_file());
        for (reference, test, part) in [
            ("btf_image", "tabulated_image", "fit"),
            ("tabulated_image", "pack_image", "interpolation"),
        ] {
            let c = meso(
                &[
                    "compare",
                    file(reference).to_str().expect("utf-8"),
                    file(test).to_str().expect("utf-8"),
                    "--json",
                ],
                "",
            );
            let c: serde_json::Value = serde_json::from_str(&stdout(&c)).expect("JSON");
            assert_eq!(c["mssim"], s[format!("{part}_image_mssim")], "{part}");
            assert_eq!(c["rmse"], s[format!("{part}_image_rmse")], "{part}");
        }
        let rmse = |k: &str| s[k].as_f64().expect("an RMSE");
        assert!(
            rmse("image_rmse")
                <= (rmse("fit_image_rmse") + rmse("interpolation_image_rmse")) * (1.0 + 1e-9),
            "{s}"
        );
        worst_fit_mssim = worst_fit_mssim.min(rmse("fit_image_mssim"));
    }
    assert_eq!(v["image_mssim"].as_f64(), Some(worst_mssim));
    assert_eq!(v["fit_image_mssim"].as_f64(), Some(worst_fit_mssim));
    let saved: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("report"))
            .expect("JSON");
    assert_eq!(saved["table_relative_rmse"], v["table_relative_rmse"]);

    // A pack fitted to another BTF (another texel grid) is refused, naming the pack.
    let other = concat!(env!("CARGO_MANIFEST_DIR"), "/../../materials/leather.spmm");
    let o = meso(&["report", "fit", b, other, "-o", o_arg], "");
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("leather.spmm") && e.contains("texel grid"),
        "{e}"
    );
    // A scene without the material to replace is named.
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    let o = meso(
        &[
            "report", "fit", b, p, "-o", o_arg, "--scene", scene, "--width", "16", "--height", "16",
        ],
        "",
    );
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("no material `sample`"), "{e}");
}

/// A one-texel pack with a residual on the Bonn directions whose second basis, a rough
/// Cook-Torrance at weight 0.2, is fine at the measured directions and peaks near the
/// horizon far above the pack's brightest tabulated value.
fn write_too_bright_pack(path: &Path) {
    use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
    use meso_materials::spmm::{Cluster, Residual, SparseWeights, SpmmMaterial, pack};
    let z = glam::DVec3::Z;
    let lamb =
        BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), z).expect("valid");
    let ct = BasisFunction::new(
        AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.3), ("f0", 0.05)]).expect("valid"),
        z,
    )
    .expect("valid");
    let d = meso_materials::btf::directions::bonn81();
    let table = d.len() * d.len() * 3;
    let m = SpmmMaterial::new(
        "bright".into(),
        "test".into(),
        1,
        1,
        vec![Cluster {
            bases: vec![lamb, ct],
        }],
        vec![0],
        SparseWeights {
            offsets: vec![0, 2],
            basis: vec![0, 1],
            rgb: vec![[0.5; 3], [0.2; 3]],
        },
        Some(Residual {
            light_dirs: d.clone(),
            view_dirs: d,
            npca: 0,
            mean: vec![0.0; table],
            components: Vec::new(),
            coefficients: Vec::new(),
        }),
    )
    .expect("a valid pack");
    pack::write_pack(path, &m, pack::ResidualPrecision::F16).expect("written");
}

#[test]
fn a_pack_over_the_lobe_bound_validates_with_a_warning_and_fails_strict() {
    // Consistent, so valid, but said; --strict refuses it.
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("bright.spmm");
    write_too_bright_pack(&path);
    let pack = path.to_str().expect("utf-8");
    let o = meso(&["pack", "validate", pack, "--json"], "");
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
    let warnings = v["warnings"].as_array().expect("warnings");
    assert_eq!(warnings.len(), 1);
    assert!(
        warnings[0]
            .as_str()
            .is_some_and(|w| w.contains("cluster 0 basis 1 (cook_torrance)")
                && w.contains("on the hemisphere")),
        "{warnings:?}"
    );
    assert!(String::from_utf8_lossy(&o.stderr).starts_with("warning: "));
    let o = meso(&["pack", "validate", pack, "--strict"], "");
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("cluster 0 basis 1 (cook_torrance)") && err.lines().count() == 1,
        "{err}"
    );
}

#[test]
fn every_shipped_pack_passes_the_lobe_bound_strictly() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../materials");
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("materials/")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".spmm"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 7, "{names:?}");
    for name in names {
        let pack = format!("{dir}/{name}");
        let o = meso(&["pack", "validate", &pack, "--strict", "--json"], "");
        assert_eq!(
            o.status.code(),
            Some(0),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert_eq!(
            serde_json::from_str::<serde_json::Value>(&stdout(&o)).expect("JSON")["warnings"],
            serde_json::json!([]),
            "{name}"
        );
    }
}

/// `meso render` with `env` added to its environment.
fn meso_with_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_meso"))
        .args(args)
        .envs(env.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .expect("meso runs to completion")
}

#[test]
fn render_on_the_gpu_reports_device_memory_and_no_adapter_is_exit_2() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("g.exr");
    let out_arg = out.to_str().expect("utf-8");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/default.toml");
    let args = [
        "render", scene, "-o", out_arg, "--width", "16", "--height", "16", "--frames", "2",
        "--device", "gpu", "--json",
    ];
    // A backend that does not exist on this system: no adapter, one line, exit 2,
    // nothing written.
    let o = meso_with_env(&args, &[("WGPU_BACKEND", "metal")]);
    if cfg!(target_os = "linux") {
        assert_bad_input(&o, &["no GPU adapter", "WGPU_BACKEND=metal"]);
        assert!(!out.exists());
    }
    // Lavapipe (CI) or any adapter wgpu finds: ms per frame, device bytes by kind,
    // no traversal overflow.
    let o = meso_with_env(&args, &[]);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(
        (v["mode"].as_str(), v["device"].as_str()),
        (Some("spmm"), Some("gpu"))
    );
    assert_eq!(v["samples"], 2 * 16 * 16);
    assert_eq!(v["traversal_overflows"], 0);
    assert!(v["adapter"].as_str().is_some_and(|a| !a.is_empty()));
    assert!(v["ms_per_frame"].as_f64().expect("ms") > 0.0);
    for kind in ["bvh", "triangles", "spmm_bases", "spmm_weights", "film"] {
        assert!(
            v["device_bytes"][kind].as_u64().expect("bytes") > 0,
            "{kind}: {v}"
        );
    }
    // The shipped leather has no residual: nothing of it is uploaded; no MERL table,
    // and no environment or background image (the 16-word header alone).
    assert_eq!(v["device_bytes"]["residual_tables"], 0);
    assert_eq!(v["device_bytes"]["merl_tables"], 0);
    assert_eq!(v["device_bytes"]["btf_tables"], 0);
    assert_eq!(v["device_bytes"]["environment"], 64);
    assert!(v["rays"]["shadow"].as_u64().expect("count") > 0);
    assert!(out.exists());
}

#[test]
fn bench_frames_measures_both_devices_side_by_side() {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/cornell.toml");
    let v = bench_frames_json(scene, &["--size", "8"]);
    let runs = v["runs"].as_array().expect("runs");
    // As it is and with AO off (the brushed metal has no residual), on both devices.
    let names: Vec<(&str, &str)> = runs
        .iter()
        .map(|r| {
            (
                r["variant"].as_str().expect("variant"),
                r["device"].as_str().expect("device"),
            )
        })
        .collect();
    assert_eq!(
        names,
        [
            ("as_is", "cpu"),
            ("as_is", "gpu"),
            ("ao_off", "cpu"),
            ("ao_off", "gpu")
        ]
    );
    for r in runs {
        assert!(r["ms_per_frame"].as_f64().expect("measured") > 0.0, "{r}");
        assert!(
            r["edit_to_frame_ms"].as_f64().expect("a light") > 0.0,
            "{r}"
        );
        assert_eq!(r["traversal_overflows"], 0, "{r}");
    }
    assert_bad_input(
        &meso(&["bench", "frames", scene, "--devices", "cpu,tpu"], ""),
        &["--devices", "tpu"],
    );
}

/// `meso bench frames SCENE --frames 1 --json` plus `args`, which must succeed.
fn bench_frames_json(scene: &str, args: &[&str]) -> serde_json::Value {
    let mut all = vec!["bench", "frames", scene, "--frames", "1", "--json"];
    all.extend_from_slice(args);
    let o = meso(&all, "");
    assert_ok(&o);
    serde_json::from_str(&stdout(&o)).expect("JSON")
}

/// A scene with a residual is also measured with it off and as the viewport renders it
/// while the camera moves.
#[test]
fn bench_frames_measures_the_residual_off_and_the_moving_camera() {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/scenes/fitted.toml");
    let v = bench_frames_json(scene, &["--size", "4", "--devices", "cpu"]);
    let runs = v["runs"].as_array().expect("runs");
    let names: Vec<&str> = runs
        .iter()
        .map(|r| r["variant"].as_str().expect("variant"))
        .collect();
    assert_eq!(names, ["as_is", "ao_off", "residual_off", "moving"]);
    assert!(
        runs.iter().all(|r| r["ms_per_frame"].as_f64() > Some(0.0)),
        "{v}"
    );
}
