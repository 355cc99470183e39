//! `meso render`: modes, devices, refusals, the denoiser, GPU memory.

use crate::*;

#[test]
fn render_writes_an_image_and_reports_json() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("r.exr");
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/default.toml"
    );
    let out_arg = out.to_str().expect("utf-8");
    // Renders 2 frames of the default scene with `extra` flags, as JSON.
    let render = |extra: &[&str]| {
        let mut args = vec!["render", scene, "-o", out_arg, "--frames", "2", "--json"];
        args.extend_from_slice(extra);
        let o = meso(&args, "");
        assert_ok(&o);
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
    // The adaptive and biscale modes render every scene the spmm mode does: the SPMM
    // pack under the environment, and the Cornell box (a mirror, a pack, an area
    // light, AO, no environment: biscale's precomputed part is dark there); devices not
    // built yet say so; unknown names are usage errors.
    assert_ok(&render(&["--mode", "adaptive", "--frames", "2"]));
    let cornell = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/cornell.toml"
    );
    let small = ["--width", "16", "--height", "16", "--frames", "2"];
    let in_mode = |mode: &str| {
        let mut args = vec!["render", cornell, "-o", out_arg, "--mode", mode];
        args.extend_from_slice(&small);
        meso(&args, "")
    };
    assert_ok(&in_mode("adaptive"));
    assert_ok(&in_mode("biscale"));
    // The biscale and adaptive modes on the GPU render the Cornell box's SPMM pack too
    // (once refused by name, and not built).
    for mode in ["biscale", "adaptive"] {
        let mut args = vec![
            "render", cornell, "-o", out_arg, "--mode", mode, "--device", "gpu", "--json",
        ];
        args.extend_from_slice(&small);
        let o = meso(&args, "");
        assert_ok(&o);
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
        assert_eq!(
            (v["mode"].as_str(), v["device"].as_str()),
            (Some(mode), Some("gpu"))
        );
        assert!(v["samples"].as_u64().expect("a count") > 0, "{mode}: {v}");
    }
    assert_bad_input(
        &render(&["--mode", "fast"]),
        &["fast", "spmm, biscale, adaptive"],
    );
    // The environment scene renders in its own mode, which --json names with its counters.
    let o = render(&[
        "--frames", "2", "--json", "--mode", "spmm", "--device", "cpu",
    ]);
    assert_ok(&o);
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
    assert_ok(&o);
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
    assert_ok(&o);
    let img = meso_materials::image::read_image(&shaded).expect("written");
    // Lambertian gold under a point light above: red > green > blue where lit.
    let centre = img.get(4, 4);
    assert!(
        centre[0] > centre[1] && centre[1] > centre[2] && centre[2] > 0.0,
        "{centre:?}"
    );
    // The biscale mode renders it on the GPU too.
    let o = meso(
        &[
            "render", merl_arg, "-o", out_arg, "--width", "8", "--height", "8", "--frames", "1",
            "--mode", "biscale", "--device", "gpu", "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(
        (v["mode"].as_str(), v["device"].as_str()),
        (Some("biscale"), Some("gpu"))
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
fn render_denoises_only_when_asked() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/default.toml"
    );
    let render = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let out_arg = out.to_str().expect("utf-8").to_owned();
        let mut args = vec![
            "render", scene, "-o", &out_arg, "--width", "32", "--height", "32", "--frames", "1",
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = meso(&args, "");
        assert_ok(&o);
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
fn render_on_the_gpu_reports_device_memory_and_no_adapter_is_exit_2() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("g.exr");
    let out_arg = out.to_str().expect("utf-8");
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/default.toml"
    );
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
    assert_ok(&o);
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
    // and no environment or background image (the 24-word header alone).
    assert_eq!(v["device_bytes"]["residual_tables"], 0);
    assert_eq!(v["device_bytes"]["merl_tables"], 0);
    assert_eq!(v["device_bytes"]["btf_tables"], 0);
    assert_eq!(v["device_bytes"]["environment"], 96);
    assert!(v["rays"]["shadow"].as_u64().expect("count") > 0);
    assert!(out.exists());
}

/// `fit_grazing.toml` with its pack replaced by a small synthesized `btf` material
/// (`weave.btf`, 36 texels on the Bonn layout), written in `dir`; the scene's path.
pub(crate) fn btf_grazing_scene(dir: &std::path::Path) -> std::path::PathBuf {
    let recipe = dir.join("weave.toml");
    std::fs::write(&recipe, crate::btf_fit::SMALL_BTF_RECIPE).expect("write recipe");
    let btf = dir.join("weave.btf");
    assert_ok(&meso(
        &[
            "btf",
            "synth",
            recipe.to_str().expect("utf-8"),
            "-o",
            btf.to_str().expect("utf-8"),
        ],
        "",
    ));
    let grazing = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/fit_grazing.toml"
    ))
    .expect("scene");
    let scene = dir.join("btf.toml");
    std::fs::write(
        &scene,
        grazing.replace(
            "kind = \"spmm\"\npack = \"../../materials/leather.spmm\"",
            "kind = \"btf\"\npath = \"weave.btf\"",
        ),
    )
    .expect("write scene");
    scene
}

/// `meso render --max-memory`: a `btf` material larger than the bound is shaded from
/// its file through the bounded cache and gives the same image bytes as held whole;
/// a bound too small for the cache or not a byte count is exit 2 naming it.
#[test]
fn render_reads_a_btf_larger_than_max_memory_from_disk_with_the_same_image() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = crate::render::btf_grazing_scene(dir.path());
    let render = |name: &str, bound: &str| {
        let out = dir.path().join(name);
        let o = meso_with_env(
            &[
                "render",
                scene.to_str().expect("utf-8"),
                "-o",
                out.to_str().expect("utf-8"),
                "--width",
                "24",
                "--height",
                "24",
                "--frames",
                "2",
                "--max-memory",
                bound,
                "--json",
            ],
            &[("RAYON_NUM_THREADS", "2")],
        );
        (o, out)
    };
    let (o, whole) = render("whole.exr", "2GB");
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["btf_out_of_core"], 0);
    // 36 texels of 81 pairs as f16, 17.5 KB: 8 KB holds 8 one-texel blocks besides
    // two workers' 4 each.
    let (o, ooc) = render("ooc.exr", "8KB");
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["btf_out_of_core"], 1);
    assert!(v["btf_blocks_read"].as_u64() > Some(8), "{v}");
    assert!(std::fs::read(&whole).expect("exr") == std::fs::read(&ooc).expect("exr"));
    assert_bad_input(&render("no.exr", "2KB").0, &["weave.btf", "at least"]);
    assert_bad_input(&render("no.exr", "lots").0, &["--max-memory", "lots"]);
}
