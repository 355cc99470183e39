//! `meso bench`: rays, strokes, frames and edits.

use crate::*;

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
    assert_ok(&o);
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
    assert_ok(&o);
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

#[test]
fn bench_stroke_times_each_step_and_restarts_fewer_pixels_than_the_material() {
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/default.toml"
    );
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
fn bench_frames_measures_both_devices_side_by_side() {
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/cornell.toml"
    );
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
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/fitted.toml"
    );
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

/// `meso bench edits` times every kind the scene has, skips the others with the
/// reason, and its JSON has the documented shape; each edit was applied (a refused
/// edit would fail the run), so the kinds' edits all reached a frame.
#[test]
fn bench_edits_times_each_kind_the_scene_has_and_names_what_it_skips() {
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/scenes/default.toml"
    );
    let o = meso(
        &[
            "bench", "edits", scene, "--size", "32", "--edits", "2", "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(
        (v["size"].as_u64(), v["mode"].as_str()),
        (Some(32), Some("spmm"))
    );
    assert_eq!(v["device"], "cpu");
    let kinds = v["kinds"].as_array().expect("kinds");
    let names: Vec<&str> = kinds
        .iter()
        .map(|k| k["kind"].as_str().expect("name"))
        .collect();
    assert_eq!(
        names,
        [
            "material weight",
            "basis parameter",
            "light colour",
            "light move",
            "camera",
            "environment rotation"
        ]
    );
    for k in &kinds[..5] {
        let (median, p95) = (k["median_ms"].as_f64(), k["p95_ms"].as_f64());
        assert_eq!(k["edits"], 2, "{k}");
        assert!(median.is_some_and(|m| m > 0.0) && p95 >= median, "{k}");
    }
    // The default scene has no environment.
    assert_eq!(kinds[5]["edits"], 0);
    assert!(kinds[5]["p95_ms"].is_null());
    assert!(
        kinds[5]["skipped"]
            .as_str()
            .expect("why")
            .contains("environment")
    );
    assert_bad_input(
        &meso(&["bench", "edits", scene, "--edits", "0"], ""),
        &["--edits"],
    );
}

/// `meso bench btf`: the scene's BTF whole and through caches of rows and of whole
/// texels, the same image bits from each, the caches' counters reported; a bound that
/// holds the BTF whole is exit 2 (nothing to compare).
#[test]
fn bench_btf_compares_the_caches_with_the_whole_table() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = crate::render::btf_grazing_scene(dir.path());
    let bench = |bound: &str| {
        meso_with_env(
            &[
                "bench",
                "btf",
                scene.to_str().expect("utf-8"),
                "--size",
                "24",
                "--frames",
                "2",
                "--rounds",
                "1",
                "--max-memory",
                bound,
                "--block-bytes",
                "8B,486B",
                "--json",
            ],
            &[("RAYON_NUM_THREADS", "2")],
        )
    };
    // 36 texels of 81 pairs as f16 (17.5 KB): 16 KB holds it out of core.
    let o = bench("16KB");
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    let variants = v["variants"].as_array().expect("variants");
    assert_eq!(variants.len(), 3, "{v}");
    // 8-byte blocks are single rows (54 bytes); 486-byte ones whole texels.
    let rows: Vec<_> = variants.iter().map(|r| r["block_rows"].as_u64()).collect();
    assert_eq!(rows, [None, Some(1), Some(9)], "{v}");
    for r in variants {
        assert_eq!(r["bit_identical"], true, "{r}");
    }
    for r in &variants[1..] {
        assert!(r["blocks_read"].as_u64() > Some(0), "{r}");
        assert!(r["bytes_read"].as_u64() > Some(0), "{r}");
        assert!(r["cache_bytes"].as_u64() <= Some(16 << 10), "{r}");
    }
    assert_bad_input(&bench("1GB"), &["held whole", "--max-memory"]);
}
