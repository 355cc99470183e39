//! `meso btf import` of Bonn's formats (told apart by content) and `meso btf export
//! --format ubo2014`, on the reference fixtures of tests/reference/ubo.

use std::path::{Path, PathBuf};

use meso_materials::btf::{Btf, directions, file};

use super::{assert_bad_input, assert_ok, meso, stdout};

fn reference(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/reference/ubo")
        .join(name)
}

fn json(o: &std::process::Output) -> serde_json::Value {
    serde_json::from_str(&stdout(o)).expect("one JSON object")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8")
}

#[test]
fn bonn_files_import_by_content_and_export_round_trips() {
    let dir = tempfile::tempdir().expect("dir");
    // A UBO2014 file under a name that says nothing of its format.
    let renamed = dir.path().join("material.data");
    std::fs::copy(reference("dfmf_rgb.btf"), &renamed).expect("copy");
    let imported = dir.path().join("rgb.btf");
    let o = meso(
        &["btf", "import", s(&renamed), "-o", s(&imported), "--json"],
        "",
    );
    assert_ok(&o);
    let v = json(&o);
    assert_eq!(v["source"], "ubo2014");
    assert_eq!(
        (v["width"].as_u64(), v["lights"].as_u64()),
        (Some(3), Some(3))
    );
    let b = file::read_btf(&imported).expect("valid .btf");
    assert_eq!(b.name(), "material");

    // The zip, with a crop.
    let zipped = dir.path().join("zip.btf");
    let o = meso(
        &[
            "btf",
            "import",
            s(&reference("ubo2003.zip")),
            "-o",
            s(&zipped),
            "--texels",
            "1,2,4,3",
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v = json(&o);
    assert_eq!(v["source"], "ubo2003");
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(4), Some(3))
    );
    assert_eq!(
        (v["lights"].as_u64(), v["views"].as_u64()),
        (Some(3), Some(2))
    );

    // Export, then import what was exported: each value once rounded to a half float.
    let exported = dir.path().join("out.ubo");
    let o = meso(
        &[
            "btf",
            "export",
            s(&imported),
            "--format",
            "ubo2014",
            "-o",
            s(&exported),
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    let v = json(&o);
    assert_eq!(v["signature"], "!DFMF08FCR");
    assert_eq!(v["components"].as_u64(), Some(6)); // min(9 pairs, 6 texels)
    assert_eq!(
        v["bytes"].as_u64(),
        std::fs::metadata(&exported).map(|m| m.len()).ok()
    );
    let again = dir.path().join("again.btf");
    assert_ok(&meso(
        &["btf", "import", s(&exported), "-o", s(&again), "--f32"],
        "",
    ));
    let back = file::read_btf(&again).expect("valid");
    for (a, w) in back.data().iter().zip(b.data()) {
        assert_eq!(*a, half::f16::from_f32(*w).to_f32());
    }
}

/// A DFMF file of `w` x `h` texels on the 151 UBO2014 directions with one component
/// per channel: value(t, l, v, c) = u(l, v, c) * s(t).
fn ubo151_file(path: &Path, w: u32, h: u32) {
    let dirs = directions::ubo151();
    let angles: Vec<[f32; 2]> = dirs
        .iter()
        .map(|d| {
            let (t, p) = directions::to_angles_deg(*d);
            [t.to_radians() as f32, p.to_radians() as f32]
        })
        .collect();
    let mut b = b"!DFMF08FCR".to_vec();
    let meta_len = 4 + 4 + 240 + 16 + 4;
    b.extend((meta_len as u32).to_le_bytes());
    b.extend(2u32.to_le_bytes());
    b.extend([0u8; 240]);
    b.extend([0u8; 16]);
    b.extend(1u32.to_le_bytes()); // cosine flag
    b.extend(151u32.to_le_bytes());
    for v in &angles {
        b.extend(v.iter().flat_map(|x| x.to_le_bytes()));
        b.extend(151u32.to_le_bytes());
        for l in &angles {
            b.extend(l.iter().flat_map(|x| x.to_le_bytes()));
        }
    }
    b.extend(w.to_le_bytes());
    b.extend(h.to_le_bytes());
    b.extend(0u32.to_le_bytes());
    b.extend(1u32.to_le_bytes());
    b.extend(0i32.to_le_bytes());
    b.extend([0u8; 12]);
    for x in [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] {
        b.extend(x.to_le_bytes());
    }
    let half = |x: f32| half::f16::from_f32(x).to_le_bytes();
    for c in 0..3 {
        b.push(2);
        for n in [1, 151 * 151, w * h] {
            b.extend(n.to_le_bytes());
        }
        b.extend(half(1.0));
        for v in 0..151 {
            for l in 0..151 {
                b.extend(half(
                    dirs[l].z as f32 * (0.2 + 0.1 * c as f32) * (1.0 + 0.3 * dirs[v].x as f32),
                ));
            }
        }
        for t in 0..w * h {
            b.extend(half(0.5 + (t % 7) as f32 * 0.05));
        }
    }
    std::fs::write(path, b).expect("write");
}

#[test]
fn a_ubo2014_table_too_large_to_import_is_cropped_and_fitted_on_151_directions() {
    let dir = tempfile::tempdir().expect("dir");
    let big = dir.path().join("big.ubo");
    // 31 400 texels x 151^2 pairs x 3 values is just over the import budget.
    ubo151_file(&big, 200, 157);
    let out = dir.path().join("big.btf");
    let o = meso(&["btf", "import", s(&big), "-o", s(&out)], "");
    assert_bad_input(
        &o,
        &[
            "big.ubo",
            "31400 texels",
            "--texels",
            "at most 31394 texels",
        ],
    );
    assert!(!out.exists());
    assert_bad_input(
        &meso(
            &[
                "btf",
                "import",
                s(&big),
                "-o",
                s(&out),
                "--texels",
                "198,0,4,4",
            ],
            "",
        ),
        &["198,0,4,4", "200x157"],
    );
    assert_bad_input(
        &meso(
            &["btf", "import", s(&big), "-o", s(&out), "--texels", "1,2"],
            "",
        ),
        &["--texels", "X,Y,WIDTH,HEIGHT"],
    );
    // `info` reads the header only and says how much fits.
    let o = meso(&["btf", "info", s(&big), "--json"], "");
    assert_ok(&o);
    let v = json(&o);
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(200), Some(157))
    );
    assert_eq!(v["signature"], "!DFMF08FCR");
    assert_eq!(v["components"], serde_json::json!([1, 1, 1]));
    assert_eq!(v["max_import_texels"].as_u64(), Some(31394));
    let d = &v["light_dirs_deg"][1 + 6 + 12 + 12 + 12 + 18 + 2];
    assert!((d[0].as_f64().expect("theta") - 52.5).abs() < 1e-4, "{d}");
    assert!((d[1].as_f64().expect("phi") - 47.5).abs() < 1e-4, "{d}");
    let o = meso(
        &[
            "btf",
            "import",
            s(&big),
            "-o",
            s(&out),
            "--texels",
            "10,20,4,4",
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    assert_eq!(json(&o)["lights"].as_u64(), Some(151));
    let b: Btf = file::read_btf(&out).expect("valid");
    assert_eq!(b.light_dirs().len(), 151);
    for (a, w) in b.light_dirs().iter().zip(directions::ubo151()) {
        assert!(a.distance(w) < 1e-6);
    }
    // The 151-direction BTF fits and slices like an 81-direction one.
    let pack = dir.path().join("big.spmm");
    let o = meso(
        &[
            "fit",
            s(&out),
            "-o",
            s(&pack),
            "--clusters",
            "2",
            "--subclusters",
            "2",
            "--npca",
            "2",
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    assert_ok(&meso(&["pack", "validate", s(&pack)], ""));
    let png = dir.path().join("slice.png");
    assert_ok(&meso(
        &[
            "btf",
            "slice",
            s(&out),
            "-o",
            s(&png),
            "--light",
            "37.5,0",
            "--view",
            "52.5,7.5",
            "--pack",
            s(&pack),
        ],
        "",
    ));
}

#[test]
fn sources_that_are_no_btf_are_named() {
    let dir = tempfile::tempdir().expect("dir");
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "hello").expect("write");
    let out = dir.path().join("o.btf");
    assert_bad_input(
        &meso(&["btf", "import", s(&text), "-o", s(&out)], ""),
        &["notes.txt", "zip archive", "UBO2014", "hello"],
    );
    let cut = dir.path().join("cut.btf");
    let bytes = std::fs::read(reference("dfmf_rgb.btf")).expect("fixture");
    std::fs::write(&cut, &bytes[..bytes.len() - 10]).expect("write");
    assert_bad_input(
        &meso(&["btf", "import", s(&cut), "-o", s(&out)], ""),
        &["cut.btf", "channel 2's factors", "ends at byte"],
    );
    let bad_zip = dir.path().join("x.zip");
    std::fs::write(&bad_zip, b"PK\x03\x04 not really").expect("write");
    assert_bad_input(
        &meso(&["btf", "import", s(&bad_zip), "-o", s(&out)], ""),
        &["x.zip", "zip"],
    );
    assert_bad_input(
        &meso(
            &[
                "btf",
                "export",
                s(&text),
                "--format",
                "ubo2014",
                "-o",
                s(&out),
            ],
            "",
        ),
        &["notes.txt"],
    );
    assert_bad_input(
        &meso(
            &["btf", "export", s(&text), "--format", "png", "-o", s(&out)],
            "",
        ),
        &["png"],
    );
    assert!(!out.exists());
}
