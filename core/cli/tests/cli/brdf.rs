//! `meso brdf`: evaluation, albedo and lobe plots.

use crate::*;

#[test]
fn brdf_eval_prints_one_value_per_row() {
    // Lambertian is 1/pi for every pair above the horizon and 0 below (docs/brdf.md);
    // unnormalised input directions are normalised by the tool.
    let input = "0,0,1,0,0,1\n\n# a comment\n0.3,0.1,2,0,-0.2,5\n0,0,-1,0,0,1\n";
    let o = meso(&["brdf", "eval", "--model", "lambertian"], input);
    assert_ok(&o);
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
    assert_ok(&o);
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
    assert_ok(&o);
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
    assert_ok(&o);
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
    assert_ok(&o);
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
