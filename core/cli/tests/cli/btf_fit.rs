//! `meso btf` and `meso fit`: synthesis, fitting, slices, `meso report fit`.

use crate::*;

pub(crate) const SMALL_BTF_RECIPE: &str = r#"
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
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
    assert_eq!(v["lights"], 9);
    let o = meso(&["btf", "info", b, "--json"], "");
    assert_ok(&o);
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
    assert_ok(&o);
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
    assert_ok(&meso(&["pack", "validate", p], ""));
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
    assert_ok(&o);
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
    assert_ok(&meso(&["pack", "validate", q], ""));
    let o = meso(&["pack", "info", q, "--json"], "");
    let info: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(info["residual"]["precision"], "i8");
    assert!(stdout(&meso(&["pack", "info", p], "")).contains("f16 tables"));
    let mut direct = args.to_vec();
    direct[3] = q;
    direct.extend(["--precision", "i8"]);
    assert_ok(&meso(&direct, ""));
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
    assert_ok(&meso(&args, ""));
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
    assert_ok(&o);
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
    assert_ok(&meso(&["btf", "synth", r, "-o", x], ""));
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
    assert_ok(&meso(&["btf", "synth", r, "-o", b], ""));
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
    assert_ok(&o);
    let out = dir.path().join("report");
    let o_arg = out.to_str().expect("utf-8");
    let o = meso(
        &[
            "report", "fit", b, p, "-o", o_arg, "--width", "24", "--height", "24", "--frames", "2",
            "--json",
        ],
        "",
    );
    assert_ok(&o);
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
        assert_ok(&c);
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
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/default.toml"
    );
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

#[test]
fn fit_in_shards_merges_to_the_unsharded_pack_and_refuses_odd_parts() {
    let dir = tempfile::tempdir().expect("temp dir");
    let recipe = dir.path().join("weave.toml");
    std::fs::write(&recipe, SMALL_BTF_RECIPE).expect("write recipe");
    let btf = dir.path().join("weave.btf");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let b = btf.to_str().expect("utf-8");
    assert_ok(&meso(
        &["btf", "synth", recipe.to_str().expect("utf-8"), "-o", b],
        "",
    ));
    // A sample of 20 of the 36 texels, a tight memory budget.
    let common = [
        "--clusters",
        "2",
        "--subclusters",
        "2",
        "--npca",
        "2",
        "--sample-texels",
        "20",
        "--residual-texels",
        "5",
        "--max-memory",
        "64MB",
    ];
    let whole = path("whole.spmm");
    let mut args = vec!["fit", b, "-o", &whole];
    args.extend(common);
    assert_ok(&meso(&args, ""));
    // The model once; shards 2 and 3 take it from the file, shard 1 finds its own.
    let model = path("weave.model");
    let mut args = vec!["fit", b, "--model-only", "-o", &model];
    args.extend(common);
    assert_ok(&meso(&args, ""));
    let parts: Vec<String> = (1..=3).map(|k| path(&format!("p{k}.part"))).collect();
    for (k, part) in parts.iter().enumerate() {
        let shard = format!("{}/3", k + 1);
        let mut args = vec!["fit", b, "-o", part, "--shard", &shard, "--json"];
        if k > 0 {
            args.extend(["--model", model.as_str()]);
        }
        args.extend(common);
        let o = meso(&args, "");
        assert_ok(&o);
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
        assert_eq!(v["shard"], shard);
        let texels = v["texels"].as_array().expect("range");
        assert_eq!(
            texels[1].as_u64().expect("end") - texels[0].as_u64().expect("first"),
            12
        );
    }
    let merged = path("merged.spmm");
    let o = meso(
        &[
            "fit", "merge", &parts[2], &parts[0], &parts[1], "-o", &merged, "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("one JSON object");
    assert_eq!(v["width"], 6);
    assert!(
        std::fs::read(&merged).expect("merged") == std::fs::read(&whole).expect("whole"),
        "3 shards merged differ from the unsharded pack"
    );
    assert_ok(&meso(&["pack", "validate", &merged], ""));

    // Refusals name the place at fault; nothing is written.
    let refused = path("refused.spmm");
    assert_bad_input(
        &meso(
            &[
                "fit", "merge", &parts[0], &parts[1], &parts[1], "-o", &refused,
            ],
            "",
        ),
        &["p2.part", "both shard 2/3"],
    );
    assert_bad_input(
        &meso(&["fit", "merge", &parts[0], &parts[2], "-o", &refused], ""),
        &["shard(s) 2 of 3 missing"],
    );
    let mut args = vec!["fit", b, "-o", &refused, "--model", &model];
    args.extend(common.iter().map(|a| if *a == "2" { "1" } else { a }));
    assert_bad_input(&meso(&args, ""), &["weave.model", "other options"]);
    let whole_as_model = ["fit", b, "-o", &refused, "--model", &whole];
    assert_bad_input(
        &meso(&whole_as_model, ""),
        &["whole.spmm", "not a fit model"],
    );
    assert!(!std::path::Path::new(&refused).exists());
    assert_bad_input(
        &meso(&["fit", b, "-o", &refused, "--shard", "4/3"], ""),
        &["--shard", "4/3", "out of range"],
    );
    assert_bad_input(
        &meso(&["fit", b, "-o", &refused, "--max-memory", "12XB"], ""),
        &["--max-memory", "12XB", "suffix"],
    );
    assert_bad_input(
        &meso(&["fit", b, "-o", &refused, "--max-memory", "1MB"], ""),
        &["--max-memory 1048576 bytes", "--sample-texels"],
    );
    assert!(!std::path::Path::new(&refused).exists());
}

/// `meso btf slice` reads the BTF in blocks of `--max-memory`: one texel at a time
/// gives the same image as the whole file in one block, and both hold the BTF's own
/// values at the pair; a bound under one texel, or a damaged file, is named.
#[test]
fn slices_read_in_blocks_equal_the_btf_held_whole() {
    let dir = tempfile::tempdir().expect("temp dir");
    let recipe = dir.path().join("weave.toml");
    std::fs::write(&recipe, SMALL_BTF_RECIPE).expect("write recipe");
    let btf = dir.path().join("weave.btf");
    let (r, b) = (
        recipe.to_str().expect("utf-8"),
        btf.to_str().expect("utf-8"),
    );
    assert_ok(&meso(&["btf", "synth", r, "-o", b], ""));
    let whole = meso_materials::btf::file::read_btf(&btf).expect("read");
    // 9 x 9 pairs, RGB, f32: one texel's values.
    let texel = (whole.pairs() * 3 * 4).to_string();
    let slice = |name: &str, bound: &str| {
        let out = dir.path().join(name);
        let o = meso(
            &[
                "btf",
                "slice",
                b,
                "-o",
                out.to_str().expect("utf-8"),
                "--light",
                "45,90",
                "--view",
                "70,0",
                "--scale",
                "1",
                "--max-memory",
                bound,
            ],
            "",
        );
        (o, out)
    };
    let (o, one) = slice("one.exr", &texel);
    assert_ok(&o);
    let (o, all) = slice("all.exr", "1GB");
    assert_ok(&o);
    assert_eq!(
        std::fs::read(&one).expect("exr"),
        std::fs::read(&all).expect("exr")
    );
    let image = meso_materials::image::read_image(&one).expect("exr");
    let dirs = meso_materials::btf::directions::from_angles_deg;
    let nearest = |set: &[glam::DVec3], d: glam::DVec3| {
        (0..set.len())
            .max_by(|&a, &b| set[a].dot(d).total_cmp(&set[b].dot(d)))
            .expect("directions")
    };
    let l = nearest(whole.light_dirs(), dirs(45.0, 90.0));
    let v = nearest(whole.view_dirs(), dirs(70.0, 0.0));
    for t in 0..whole.texels() {
        let (x, y) = ((t % 6) as u32, (t / 6) as u32);
        assert_eq!(image.get(x, y), whole.value(t, l, v), "texel {t}");
    }
    let smaller = (whole.pairs() * 3 * 4 - 1).to_string();
    assert_bad_input(&slice("no.exr", &smaller).0, &["--max-memory", "one texel"]);
    // Damaged: the file cut short is named with the sizes that disagree.
    let bytes = std::fs::read(&btf).expect("btf");
    std::fs::write(&btf, &bytes[..bytes.len() - 2]).expect("write");
    assert_bad_input(&slice("cut.exr", "1GB").0, &["weave.btf", "the file has"]);
}

/// `meso report fit` with a bound far under the BTF's values (both the BTF and the
/// pack's tabulation shaded from blocks on demand, the table errors read a texel at a
/// time) writes the same images and figures as with both held whole.
#[test]
fn report_fit_out_of_core_equals_the_report_held_whole() {
    let dir = tempfile::tempdir().expect("temp dir");
    let recipe = dir.path().join("weave.toml");
    std::fs::write(&recipe, SMALL_BTF_RECIPE).expect("write recipe");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let (b, p) = (path("weave.btf"), path("weave.spmm"));
    assert_ok(&meso(
        &["btf", "synth", recipe.to_str().expect("utf-8"), "-o", &b],
        "",
    ));
    assert_ok(&meso(
        &["fit", &b, "-o", &p, "--clusters", "2", "--npca", "2"],
        "",
    ));
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/fit_grazing.toml"
    );
    let report = |out: &str, bound: &str| {
        let o = meso_with_env(
            &[
                "report",
                "fit",
                &b,
                &p,
                "-o",
                out,
                "--scene",
                scene,
                "--width",
                "16",
                "--height",
                "16",
                "--frames",
                "1",
                "--max-memory",
                bound,
                "--json",
            ],
            &[("RAYON_NUM_THREADS", "2")],
        );
        assert_ok(&o);
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
        v
    };
    // 36 texels of 81 pairs: 17.5 KB as f16, 35 KB as f32; 20 KB is 10 KB a table.
    let (whole, out_whole) = (report(&path("whole"), "1GB"), path("whole"));
    let (ooc, out_ooc) = (report(&path("ooc"), "20KB"), path("ooc"));
    assert!(
        whole["btf_resident_bytes"].as_u64() > ooc["btf_resident_bytes"].as_u64(),
        "{whole} {ooc}"
    );
    for key in [
        "table_relative_rmse",
        "table_basis_relative_rmse",
        "mean_reflectance",
        "image_relative_rmse",
        "fit_image_relative_rmse",
    ] {
        assert_eq!(whole[key], ooc[key], "{key}");
    }
    for file in ["btf", "pack", "tabulated"] {
        let f = format!("fit_grazing_{file}.exr");
        let read = |d: &str| std::fs::read(std::path::Path::new(d).join(&f)).expect("exr");
        assert!(read(&out_whole) == read(&out_ooc), "{f}");
    }
}
