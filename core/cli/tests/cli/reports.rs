//! `meso report convergence`, `meso report adaptive` and `meso precompute`.

use crate::*;

#[test]
fn report_convergence_writes_csv_json_charts_and_the_reference() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("conv");
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/default.toml"
    );
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
    assert_ok(&o);
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

/// Repeated runs: every curve runs twice, each checkpoint keeps its shorter time, and
/// the two runs must render the same images (the report asserts it in this debug
/// build), so the PSNR matches a single run's.
#[test]
fn report_adaptive_repeats_each_curve_and_keeps_its_images() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/merl_teapot.toml"
    );
    // Each curve's name and its checkpoints' PSNRs.
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec![
            "report",
            "adaptive",
            scene,
            "-o",
            out.to_str().expect("utf-8"),
            "--width",
            "16",
            "--height",
            "16",
            "--reference-frames",
            "16",
            "--spmm-frames",
            "4",
            "--adaptive-frames",
            "4",
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = meso(&args, "");
        assert_ok(&o);
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
        v["curves"]
            .as_array()
            .expect("curves")
            .iter()
            .map(|c| {
                let psnr = c["checkpoints"]
                    .as_array()
                    .expect("checkpoints")
                    .iter()
                    .map(|k| {
                        assert!(k["seconds"].as_f64().expect("seconds") > 0.0);
                        k["psnr_db"].as_f64().expect("PSNR")
                    })
                    .collect::<Vec<f64>>();
                (c["name"].as_str().expect("name").to_owned(), psnr)
            })
            .collect::<Vec<_>>()
    };
    let once = run("once", &["--repeats", "1"]);
    let twice = run("twice", &["--repeats", "2"]);
    let names: Vec<&str> = once.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "spmm",
            "adaptive_nb16",
            "adaptive_whole_map",
            "adaptive_nb256",
            "preconvolved"
        ]
    );
    assert!(
        once.iter().all(|(_, psnr)| psnr.len() == 3),
        "1, 2, 4 frames of each curve"
    );
    assert_eq!(once, twice);
    // The teapot's sky has a sun: drawing it apart changes the images; the whole map
    // drawn by every variant is the curve that measured it.
    let whole = run("whole", &["--whole-environment"]);
    let whole_names: Vec<&str> = whole.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        whole_names,
        ["spmm", "adaptive_nb16", "adaptive_nb256", "preconvolved"]
    );
    assert_eq!(whole[1].1, once[2].1);
    assert_ne!(once[1].1, once[2].1);
    // The pre-convolved variant draws its filtered level whole either way.
    assert_eq!(whole[3].1, once[4].1);
    let bad = meso(
        &[
            "report",
            "adaptive",
            scene,
            "-o",
            "unused",
            "--repeats",
            "0",
        ],
        "",
    );
    assert_bad_input(&bad, &["--repeats"]);
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
            "--refine-vertices",
            "0",
            "--json",
        ],
        "",
    );
    assert_ok(&o);
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
    // The refinement adds vertices where visibility varies (the floor meets the wall),
    // within its budget (three a split, counted as an upper bound).
    let refined_cache = dir.path().join("refined.biscale");
    let refined_arg = refined_cache.to_str().expect("utf-8");
    let refined = meso(
        &[
            "precompute",
            scene_arg,
            "--mode",
            "biscale",
            "--cube-n",
            "8",
            "--refine-vertices",
            "96",
            "-o",
            refined_arg,
            "--no-baselines",
            "--json",
        ],
        "",
    );
    assert_ok(&refined);
    let r: serde_json::Value = serde_json::from_str(&stdout(&refined)).expect("JSON");
    let vertices = r["vertices"].as_u64().expect("vertices");
    assert!((9..=8 + 96).contains(&vertices), "{vertices} vertices");
    // Bad input: another mode.
    assert_bad_input(
        &meso(&["precompute", scene_arg, "--mode", "spmm"], ""),
        &["spmm", "only the biscale mode"],
    );
}
