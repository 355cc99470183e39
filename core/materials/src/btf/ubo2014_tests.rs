use super::*;
use crate::btf::directions;

/// The reference fixtures (tests/reference/ubo, written by make_fixtures.py, an
/// independent Python implementation of Bonn's layout) and btf_extractor's values.
pub(crate) fn reference(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/reference/ubo")
        .join(name)
}

pub(crate) fn expected() -> serde_json::Value {
    let text = std::fs::read_to_string(reference("expected.json")).expect("expected.json");
    serde_json::from_str(&text).expect("json")
}

/// A BTF with `w` x `h` texels on `dirs` (light and view), values distinct per entry.
fn small(w: u32, h: u32, dirs: Vec<DVec3>) -> Btf {
    let n = (w * h) as usize * dirs.len() * dirs.len() * 3;
    let data = (0..n)
        .map(|i| 0.01 + (i as f32 * 0.37).sin().abs())
        .collect();
    Btf::new("s".into(), "test".into(), w, h, dirs.clone(), dirs, data).expect("valid")
}

fn encode(btf: &Btf) -> Vec<u8> {
    check_writable(btf).expect("writable");
    let mut bytes = Vec::new();
    encode_dfmf(btf, &mut bytes).expect("encode");
    bytes
}

fn half_round(x: f32) -> f32 {
    half::f16::from_f32(x).to_f32()
}

/// Meso's values against btf_extractor's `[light][view][row][column][rgb]`, the
/// light's cosine multiplied in where the file's cosine flag is clear.
fn compare(btf: &Btf, want: &serde_json::Value, cosine: bool, tol: f32) {
    for l in 0..btf.light_dirs().len() {
        let cos = if cosine {
            btf.light_dirs()[l].z as f32
        } else {
            1.0
        };
        for v in 0..btf.view_dirs().len() {
            for y in 0..btf.height() as usize {
                for x in 0..btf.width() as usize {
                    let got = btf.value(y * btf.width() as usize + x, l, v);
                    for c in 0..3 {
                        let w = want[l][v][y][x][c].as_f64().expect("number") as f32 * cos;
                        assert!(
                            (got[c] - w).abs() <= tol * w.abs().max(1.0),
                            "light {l} view {v} row {y} column {x} channel {c}: {} vs {w}",
                            got[c]
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn reference_files_read_as_btf_extractor_reads_them() {
    let want = expected();
    // Same halves and products: only the order of an f32 sum differs.
    let rgb = import_path(&reference("dfmf_rgb.btf"), "rgb", None).expect("dfmf rgb");
    assert_eq!((rgb.width(), rgb.height(), rgb.pairs()), (3, 2, 9));
    compare(&rgb, &want["dfmf_rgb.btf"], false, 1e-6);
    // Cosine flag clear: Meso multiplies cos(theta_l) in. btf_extractor's model 11
    // adds the 1e-5 offset after scaling U and V by Y, btflib (and Meso) before:
    // blue = Y + 2.03211 U differs by 2.03211e-5 (1 - U/Y) at most, 2.3e-5 here.
    let yuv = import_path(&reference("dfmf_logyuv.btf"), "yuv", None).expect("dfmf yuv");
    compare(&yuv, &want["dfmf_logyuv.btf"], true, 2.5e-5);
    let fmf = import_path(&reference("fmf_drr.btf"), "fmf", None).expect("fmf");
    compare(&fmf, &want["fmf_drr.btf"], false, 1e-6);
    // The directions are the stored (theta, phi).
    let (t, p) = directions::to_angles_deg(yuv.light_dirs()[2]);
    assert!((t - 1.0f64.to_degrees()).abs() < 1e-4 && (p - 4.0f64.to_degrees()).abs() < 1e-4);
    let f = Ubo2014::open_path(&reference("dfmf_logyuv.btf")).expect("open");
    assert_eq!(f.header().color_model, 11);
    assert_eq!(f.header().xml, "<measurement/>");
    assert_eq!(f.components(), vec![3, 2, 1]);
    assert!(!f.header().cosine_flag);
}

/// The PVF and BDI fixtures (make_pvf_bdi_fixtures.py) and what btflib's decoder
/// returns for them (checked against btflib itself under Octave: btflib_values.m).
const PVF_BDI: [&str; 5] = [
    "pvf_texels.btf",
    "pvf_lights.btf",
    "pvf_old.btf",
    "bdi_full.btf",
    "bdi_sparse.btf",
];

#[test]
fn pvf_and_bdi_files_read_as_btflib_reads_them() {
    let text = std::fs::read_to_string(reference("expected_pvf_bdi.json")).expect("json");
    let want: serde_json::Value = serde_json::from_str(&text).expect("json");
    let mut unmasked = 0;
    for name in PVF_BDI {
        let btf = import_path(&reference(name), name, None).expect(name);
        assert_eq!(
            (btf.width(), btf.height(), btf.pairs()),
            (3, 2, 9),
            "{name}"
        );
        let want = &want[name];
        for l in 0..3 {
            // btflib divides the light's cosine out; Meso's values include it.
            let cos = btf.light_dirs()[l].z;
            for v in 0..3 {
                for y in 0..2 {
                    for x in 0..3 {
                        // btflib's row y is the file's; Meso's row 0 is the file's last.
                        let got = btf.value((1 - y) * 3 + x, l, v);
                        for c in 0..3 {
                            let w = want[l][v][y][x][c].as_f64().expect("number") * cos;
                            let g = f64::from(got[c]);
                            assert!(
                                (g - w).abs() <= 1e-6 * w.abs().max(1.0),
                                "{name}: light {l} view {v} btflib row {y} column {x} channel {c}: {g} vs {w}"
                            );
                            unmasked += usize::from(w == 0.0);
                        }
                    }
                }
            }
        }
    }
    // bdi_sparse.btf leaves 2 of its 6 texels out of the mask.
    assert_eq!(unmasked, 2 * 27);
}

#[test]
fn texel_blocks_are_the_whole_tables_rectangles() {
    for name in ["dfmf_rgb.btf", "fmf_drr.btf"].iter().chain(&PVF_BDI) {
        let mut f = Ubo2014::open_path(&reference(name)).expect("open");
        let whole = f.to_btf("w", "", None).expect("whole");
        let rect = TexelRect::parse("1,1,2,1").expect("rect");
        let part = f.to_btf("p", "", Some(rect)).expect("part");
        assert_eq!((part.width(), part.height()), (2, 1));
        for x in 0..2 {
            assert_eq!(part.texel(x), whole.texel(3 + 1 + x), "{name}");
        }
        let e = f.read_texels(TexelRect::parse("2,0,2,1").expect("rect"));
        assert!(e.expect_err("outside").to_string().contains("3x2"));
    }
}

#[test]
fn export_then_import_rounds_each_value_once_to_half() {
    // More pairs than texels (U holds the values) and more texels than pairs (S x V does).
    for btf in [
        small(3, 2, directions::rings(&[(0.0, 1), (40.0, 3)])),
        small(5, 4, directions::rings(&[(0.0, 1), (50.0, 2)])),
    ] {
        let bytes = encode(&btf);
        let back = decode(&bytes).expect("decode");
        assert_eq!((back.width(), back.height()), (btf.width(), btf.height()));
        for (a, b) in back.light_dirs().iter().zip(btf.light_dirs()) {
            assert!(a.distance(*b) < 1e-6, "{a} vs {b}");
        }
        for (i, (a, b)) in back.data().iter().zip(btf.data()).enumerate() {
            assert_eq!(*a, half_round(*b), "value {i}");
        }
        // The whole table is kept: k = min(pairs, texels) components per channel.
        let f = Ubo2014::open(io::Cursor::new(&bytes)).expect("open");
        let k = btf.pairs().min(btf.texels());
        assert_eq!(f.components(), vec![k; 3]);
        assert!(f.header().cosine_flag);
        assert_eq!(f.header().signature, "!DFMF08FCR");
    }
}

/// The checked-in `meso_export.btf` is what `encode_dfmf` writes for this BTF, and
/// btf_extractor (expected.json) returns its values rounded to half floats, with the
/// rows the right way up.
#[test]
fn meso_export_matches_the_checked_in_file() {
    let btf = small(4, 3, directions::rings(&[(0.0, 1), (30.0, 3), (60.0, 4)]));
    let bytes = encode(&btf);
    let path = reference("meso_export.btf");
    if std::env::var_os("MESO_WRITE_FIXTURES").is_some() {
        std::fs::write(&path, &bytes).expect("write fixture");
    }
    assert_eq!(std::fs::read(&path).expect("meso_export.btf"), bytes);
    let mut rounded = btf.data().to_vec();
    rounded.iter_mut().for_each(|x| *x = half_round(*x));
    let btf = Btf::new(
        "r".into(),
        "".into(),
        4,
        3,
        btf.light_dirs().to_vec(),
        btf.view_dirs().to_vec(),
        rounded,
    )
    .expect("valid");
    compare(&btf, &expected()["meso_export.btf"], false, 0.0);
}

/// A DFMF file built field by field: 1 light, 1 view, 1 x 1 texel, k = 1.
fn tiny(model: i32) -> Vec<u8> {
    let mut b = b"!DFMF08FCR".to_vec();
    let mut meta = Vec::new();
    meta.extend(2u32.to_le_bytes());
    meta.extend([0u8; 240]);
    meta.extend([0u8; 16]);
    meta.extend(1u32.to_le_bytes()); // cosine flag
    b.extend((meta.len() as u32 + 4).to_le_bytes());
    b.extend(meta);
    b.extend(1u32.to_le_bytes());
    b.extend([0u8; 8]); // view (0, 0)
    b.extend(1u32.to_le_bytes());
    b.extend([0u8; 8]); // light (0, 0)
    b.extend(1u32.to_le_bytes()); // width
    b.extend(1u32.to_le_bytes()); // height
    b.extend(0u32.to_le_bytes()); // rotations
    b.extend(1u32.to_le_bytes());
    b.extend(model.to_le_bytes());
    b.extend([0u8; 12]);
    for v in [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] {
        b.extend(v.to_le_bytes());
    }
    for ch in 0..3 {
        b.push(4);
        for n in [1u32, 1, 1] {
            b.extend(n.to_le_bytes());
        }
        b.extend(1.0f32.to_le_bytes()); // S
        b.extend((0.5f32 + ch as f32 * 0.1).to_le_bytes()); // U
        b.extend(0.5f32.to_le_bytes()); // S x V
    }
    b
}

#[test]
fn colour_models_are_undone_as_btflib_does() {
    let c = [0.25f32, 0.3, 0.35];
    let value = |model| decode(&tiny(model)).expect("tiny").value(0, 0, 0);
    assert_eq!(value(0), c);
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    let yuv = [
        c[0] + 1.13983 * c[2],
        c[0] - 0.39465 * c[1] - 0.5806 * c[2],
        c[0] + 2.03211 * c[1],
    ];
    assert!(close(value(1), yuv), "{:?}", value(1));
    assert!(close(
        value(4),
        [c[0] + c[1] - c[2], c[0] + c[2], c[0] - c[1] - c[2]]
    ));
    assert!(close(value(12), c.map(|x| x.exp() - 1e-5)));
    let e = decode(&tiny(2)).expect_err("LAB").to_string();
    assert!(e.contains("colour model") && e.contains("= 2"), "{e}");
}

/// Asserts `decode` refuses `bytes` with a message holding every needle.
fn check(bytes: &[u8], needles: &[&str]) {
    let e = decode(bytes).expect_err("must fail").to_string();
    for n in needles {
        assert!(e.contains(n), "`{e}` should mention `{n}`");
    }
}

#[test]
fn damaged_files_are_refused_with_the_place_named() {
    let good = tiny(0);
    assert!(decode(&good).is_ok());
    check(b"PK\x03\x04", &["signature", "PK"]);
    check(b"!PVF06FCR....", &["meta-data version", "ends at byte"]);
    check(
        &good[..good.len() - 2],
        &["channel 2's factors", "ends at byte"],
    );
    check(&good[..40], &["ends at byte 40"]);
    let mut extra = good.clone();
    extra.push(0);
    check(&extra, &["1 bytes follow"]);
    // The meta-data size disagrees with its fields.
    let mut b = good.clone();
    b[10] += 4;
    check(&b, &["declares", "bytes"]);
    // A huge view count is refused before anything is allocated.
    let views_at = 10 + 264 + 4;
    let mut b = good.clone();
    b[views_at..views_at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    check(&b, &["view directions", "ends at byte"]);
    // A light below the horizon.
    let mut b = good.clone();
    let light_theta = views_at + 4 + 8 + 4;
    b[light_theta..light_theta + 4].copy_from_slice(&2.0f32.to_le_bytes());
    check(&b, &["light 0", "theta"]);
    // A wrong row count in channel 1, a scalar size of 3, a zero width.
    let ch0 = good.len() - 3 * 25;
    let mut b = good.clone();
    b[ch0 + 25 + 5..ch0 + 25 + 9].copy_from_slice(&7u32.to_le_bytes());
    check(&b, &["channel 1's row count", "7"]);
    let mut b = good.clone();
    b[ch0] = 3;
    check(&b, &["channel 0's scalar size", "3"]);
    let width_at = light_theta + 8;
    let mut b = good.clone();
    b[width_at..width_at + 4].copy_from_slice(&0u32.to_le_bytes());
    check(&b, &["width", "1..="]);
    // A huge component count: the size check fails before U is allocated.
    let mut b = good.clone();
    b[ch0 + 1..ch0 + 5].copy_from_slice(&u32::MAX.to_le_bytes());
    check(&b, &["channel 0's factors", "ends at byte"]);
}

#[test]
fn out_of_range_values_are_refused_before_writing() {
    let mut b = small(1, 1, directions::rings(&[(0.0, 1), (40.0, 3)]));
    let mut data = b.data().to_vec();
    data[7] = 1e6;
    b = Btf::new(
        "x".into(),
        "".into(),
        1,
        1,
        b.light_dirs().to_vec(),
        b.view_dirs().to_vec(),
        data,
    )
    .expect("valid");
    let e = check_writable(&b).expect_err("too large").to_string();
    assert!(
        e.contains("light 0, view 2, channel 1") && e.contains("half"),
        "{e}"
    );
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("x.btf");
    assert!(write_dfmf(&path, &b).is_err());
    assert!(!path.exists(), "nothing is written");
}

/// `bytes` with the u32 at `at` replaced by `v`.
fn patched(bytes: &[u8], at: usize, v: u32) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
    b
}

/// Where the common header of a fixture written by make_pvf_bdi_fixtures.py ends.
fn after_common(bytes: &[u8], signature: &str) -> usize {
    let meta = u32::from_le_bytes(
        bytes[signature.len()..signature.len() + 4]
            .try_into()
            .expect("4"),
    );
    // 3 views, each 8 + 4 + 3 x 8 bytes; width and height.
    signature.len() + meta as usize + 4 + 3 * 36 + 8
}

#[test]
fn damaged_pvf_files_are_refused_with_the_place_named() {
    let good = std::fs::read(reference("pvf_lights.btf")).expect("fixture");
    assert!(decode(&good).is_ok());
    // `!PVF06FC`: no rotations; then the largest component count and the slot count.
    let slots_at = after_common(&good, "!PVF06FC") + 4;
    check(
        &patched(&good, slots_at, 2),
        &["view-slot count", "3 views"],
    );
    let slot0 = slots_at + 4;
    // Dimension 5 fits neither layout.
    check(
        &patched(&good, slot0 + 9, 5),
        &["view 0's factorisation's dimension", "5 (with 3 weights)"],
    );
    // A view whose sides differ from view 0's: view 1 says (channel, light) rows with
    // texel weights.
    let k = 2;
    let slot_bytes = 13 + 4 * (k + 18 + 18 * k + 3 * k);
    let slot1 = slot0 + slot_bytes;
    let mut b = patched(&good, slot1 + 5, 6);
    b = patched(&b, slot1 + 9, 9);
    check(
        &b,
        &["view 1's factorisation's dimension", "same sides as view 0"],
    );
    // A huge component count: refused before anything is allocated.
    check(
        &patched(&good, slot0 + 1, u32::MAX),
        &["view 0's factorisation", "ends at byte"],
    );
    check(
        &good[..good.len() - 1],
        &["view 2's factorisation", "ends at byte"],
    );
    check(
        &patched(&good, slot0 + 1, 0),
        &["component count", "at least 1"],
    );
}

#[test]
fn damaged_bdi_files_are_refused_with_the_place_named() {
    let good = std::fs::read(reference("bdi_full.btf")).expect("fixture");
    assert!(decode(&good).is_ok());
    let lines_at = after_common(&good, "!BDIF06R2!");
    check(
        &patched(&good, lines_at, 0),
        &["scan lines per chunk", "at least 1"],
    );
    let mut b = good.clone();
    b[lines_at + 4] = 1;
    check(&b, &["bzip2-compressed BDI", "not read"]);
    b[lines_at + 4] = 7;
    check(&b, &["compression", "= 7"]);
    // Without the trailing `!` btflib takes the chunks to be bzip2-compressed.
    let mut b = good.clone();
    b.remove(lines_at + 4);
    b.remove(9);
    check(&b, &["`!BDIF06R2`", "bzip2"]);
    // Mask (6 bytes), no rotations (4), then chunk 0's byte count: one texel short.
    let chunk0 = lines_at + 5 + 6 + 4;
    let texel = 3 * 2 * 9;
    check(
        &patched(&good, chunk0, (3 * texel - 1) as u32),
        &["chunk 0's byte count", "162 bytes"],
    );
    check(&good[..good.len() - 1], &["chunk 1", "ends at byte"]);
}
