//! `meso pack`: info, validate, eval, edit, the lobe bound.

use std::path::Path;

use crate::*;

/// A two-cluster pack built through the public API (Ward + Lambertian, one weight
/// per texel, no residual).
pub(crate) fn write_small_pack(path: &Path) {
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
    assert_ok(&o);
    let o = meso(&["pack", "info", good_s, "--json"], "");
    assert_ok(&o);
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
    assert_ok(&o);
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
    assert_ok(&meso(&["pack", "validate", &added], ""));
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
    assert_ok(&o);
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
