//! `meso merl`: tabulate, validate, info, eval and bad input.

use crate::*;

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
