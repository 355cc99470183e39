use std::io::{Cursor, Write};

use super::*;
use crate::btf::ubo2014::tests::{expected, reference};

/// The fixture's entries: (name, bytes).
fn fixture_entries() -> Vec<(String, Vec<u8>)> {
    let file = std::fs::File::open(reference("ubo2003.zip")).expect("fixture");
    let mut zip = zip::ZipArchive::new(file).expect("zip");
    (0..zip.len())
        .map(|i| {
            let mut f = zip.by_index(i).expect("entry");
            let mut b = Vec::new();
            f.read_to_end(&mut b).expect("read");
            (f.name().expect("name").into_owned(), b)
        })
        .collect()
}

fn pack(entries: &[(String, Vec<u8>)]) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut out);
        let opts = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored);
        for (name, bytes) in entries {
            z.start_file(name.as_str(), opts).expect("start");
            z.write_all(bytes).expect("write");
        }
        z.finish().expect("finish");
    }
    out.into_inner()
}

fn read(bytes: Vec<u8>, rect: Option<TexelRect>) -> Result<Btf, ZipImportErrorKind> {
    read_zip(Cursor::new(bytes), "z", "test", rect)
}

#[test]
fn names_parse_into_whole_degrees() {
    assert_eq!(
        parse_name("UBO_X/tl015 pl060 tv030 pv120.jpg"),
        Ok(Some([15, 60, 30, 120]))
    );
    assert_eq!(
        parse_name("tl000 pl090 tv075 pv345.JPG"),
        Ok(Some([0, 0, 75, 345]))
    );
    assert_eq!(parse_name("readme.txt"), Ok(None));
    assert!(parse_name("tl015 pl060 tv030.jpg").is_err());
    assert!(
        parse_name("tl015 pl060 tv030 px120.jpg")
            .expect_err("key")
            .contains("px120")
    );
    assert!(
        parse_name("tl095 pl060 tv030 pv120.jpg")
            .expect_err("horizon")
            .contains("tl = 95")
    );
    assert!(parse_name("tl01a pl060 tv030 pv120.jpg").is_err());
}

/// The fixture (written by tests/reference/ubo/make_fixtures.py with PIL) against
/// btf_extractor's 8-bit codes: Meso's value is the sRGB-decoded code of its own
/// JPEG decoder (the `image` crate's, zune-jpeg), which agrees with libjpeg-turbo's
/// (btf_extractor's simplejpeg) within 3 codes and 0.5 codes on average here: JPEG
/// decoders may round the inverse DCT and the 4:2:0 chroma upsampling differently.
#[test]
fn the_reference_zip_reads_as_btf_extractor_reads_it() {
    let want = &expected()["ubo2003.zip"];
    let btf = import_zip(
        &reference("ubo2003.zip"),
        "tiny",
        None,
        DEFAULT_MAX_IMPORT_BYTES,
    )
    .expect("import");
    assert_eq!((btf.width(), btf.height()), (8, 6));
    assert_eq!((btf.light_dirs().len(), btf.view_dirs().len()), (3, 2));
    let (mut worst, mut sum, mut n) = (0i64, 0i64, 0i64);
    for (l, la) in want["lights"]
        .as_array()
        .expect("lights")
        .iter()
        .enumerate()
    {
        let (t, p) = directions::to_angles_deg(btf.light_dirs()[l]);
        assert!((t - la[0].as_f64().expect("t")).abs() < 1e-9);
        assert!((p - la[1].as_f64().expect("p")).abs() < 1e-9);
        for v in 0..2 {
            for y in 0..6 {
                for x in 0..8 {
                    let got = btf.value(y * 8 + x, l, v);
                    for c in 0..3 {
                        // Meso's value is exactly a decoded 8-bit code.
                        let code = (crate::image::srgb_encode(got[c]) * 255.0).round();
                        assert_eq!(got[c], crate::image::srgb_decode(code / 255.0));
                        let bonn = want["codes"][l][v][y][x][c].as_i64().expect("code");
                        worst = worst.max((code as i64 - bonn).abs());
                        sum += (code as i64 - bonn).abs();
                        n += 1;
                    }
                }
            }
        }
    }
    let mean = sum as f64 / n as f64;
    assert!(
        worst <= 3 && mean <= 0.5,
        "JPEG decoders differ by {worst} codes, {mean} on average"
    );
    // A crop holds the same texels.
    let rect = TexelRect::parse("2,1,3,4").expect("rect");
    let part = import_zip(
        &reference("ubo2003.zip"),
        "tiny",
        Some(rect),
        DEFAULT_MAX_IMPORT_BYTES,
    )
    .expect("crop");
    assert_eq!((part.width(), part.height()), (3, 4));
    assert_eq!(part.texel(0), btf.texel(8 + 2));
    assert_eq!(part.texel(3 * 3 + 2), btf.texel(4 * 8 + 4));
}

#[test]
fn incomplete_or_damaged_archives_are_named() {
    let entries = fixture_entries();
    assert!(read(pack(&entries), None).is_ok());
    let check = |bytes: Vec<u8>, needles: &[&str]| {
        let e = read(bytes, None).expect_err("must fail").to_string();
        for n in needles {
            assert!(e.contains(n), "`{e}` should mention `{n}`");
        }
    };
    let jpg = |name: &str| {
        entries
            .iter()
            .find(|(n, _)| n.ends_with(name))
            .expect("entry")
            .clone()
    };
    // One image fewer: the missing pair is named.
    let fewer: Vec<_> = entries
        .iter()
        .filter(|(n, _)| !n.ends_with("tl015 pl060 tv030 pv090.jpg"))
        .cloned()
        .collect();
    check(
        pack(&fewer),
        &[
            "light (15, 60) deg with view (30, 90) deg",
            "6 images are needed, found 5",
        ],
    );
    // The same pair twice (in another folder).
    let mut twice = entries.clone();
    let (_, b) = jpg("tl000 pl000 tv000 pv000.jpg");
    twice.push(("other/tl000 pl000 tv000 pv000.jpg".into(), b));
    check(
        pack(&twice),
        &["tiny/tl000 pl000 tv000 pv000.jpg", "other/tl000"],
    );
    // A JPEG whose name is not the database's.
    let mut named = entries.clone();
    named.push((
        "tiny/photo.jpg".into(),
        jpg("tl000 pl000 tv000 pv000.jpg").1,
    ));
    check(pack(&named), &["tiny/photo.jpg", "1 space-separated"]);
    // A damaged JPEG, and one of another size.
    let mut broken = entries.clone();
    let k = broken
        .iter()
        .position(|(n, _)| n.ends_with("tl015 pl000 tv000 pv000.jpg"))
        .expect("entry");
    broken[k].1.truncate(40);
    check(pack(&broken), &["tl015 pl000 tv000 pv000.jpg"]);
    let mut resized = entries.clone();
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new(&mut out)
        .encode(&[128u8; 4 * 4 * 3], 4, 4, image::ExtendedColorType::Rgb8)
        .expect("encode");
    resized[k].1 = out;
    check(
        pack(&resized),
        &["tl015 pl000 tv000 pv000.jpg", "4x4", "8x6"],
    );
    // No images; not a zip; a crop outside the grid.
    check(pack(&[("a.txt".into(), b"x".to_vec())]), &["no `tl"]);
    check(b"!DFMF08FCR".to_vec(), &["not a readable zip"]);
    let e = read(pack(&entries), TexelRect::parse("6,0,3,1").ok()).expect_err("outside");
    assert!(e.to_string().contains("8x6"), "{e}");
}

/// A Radiance file of `w` x `h` flat (not run-length encoded: widths below 8) RGBE
/// pixels in file order, with the resolution line `resolution`.
fn radiance(resolution: &str, pixels: &[[u8; 4]]) -> Vec<u8> {
    let mut out = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n{resolution}\n").into_bytes();
    for p in pixels {
        out.extend_from_slice(p);
    }
    out
}

/// The light and view angles of a 3 x 2 archive, in Meso's (ring) order.
const LIGHTS: [[u32; 2]; 3] = [[0, 0], [15, 0], [15, 60]];
const VIEWS: [[u32; 2]; 2] = [[0, 0], [30, 90]];

fn hdr_name(folder: &str, l: [u32; 2], v: [u32; 2]) -> String {
    format!(
        "{folder}/tl{:03} pl{:03} tv{:03} pv{:03}.hdr",
        l[0], l[1], v[0], v[1]
    )
}

/// Pixel `i` (file order) of pair `p`: mantissas 128..=255 and exponents 126..=129,
/// so every value c * 2^(e - 136) is exact in f32.
fn rgbe(p: usize, i: usize) -> [u8; 4] {
    let c = |k: usize| 128 + ((p * 17 + i * 5 + k * 7) % 128) as u8;
    [c(0), c(1), c(2), 126 + (p % 4) as u8]
}

fn rgbe_value(px: [u8; 4]) -> [f32; 3] {
    let scale = 2f32.powi(i32::from(px[3]) - 136);
    [0, 1, 2].map(|k| f32::from(px[k]) * scale)
}

/// ATRIUM's HDR archives: `.hdr` entries whose resolution line is `+X N -Y N`, read
/// as btf_extractor reads them (rows bottom-up), and standard `-Y H +X W` files (rows
/// top-down); values linear and exact: an RGBE value is c * 2^(e - 136), which f32
/// holds exactly, and no sRGB decode is applied.
#[test]
fn hdr_archives_read_linear_values_exactly_in_both_orientations() {
    for (resolution, w, h, bottom_up) in [("+X 4 -Y 4", 4, 4, true), ("-Y 3 +X 5", 5, 3, false)] {
        let mut entries = vec![("CEILING_HDR/readme.txt".to_string(), b"hi".to_vec())];
        for (li, l) in LIGHTS.iter().enumerate() {
            for (vi, v) in VIEWS.iter().enumerate() {
                let p = li * VIEWS.len() + vi;
                let pixels: Vec<[u8; 4]> = (0..w * h).map(|i| rgbe(p, i)).collect();
                entries.push((
                    hdr_name("CEILING_HDR", *l, *v),
                    radiance(resolution, &pixels),
                ));
            }
        }
        // Stored in any order: the listing decides the order.
        entries.reverse();
        let btf = read(pack(&entries), None).expect("imports");
        assert_eq!((btf.width(), btf.height()), (w as u32, h as u32));
        assert_eq!((btf.light_dirs().len(), btf.view_dirs().len()), (3, 2));
        for l in 0..3 {
            for v in 0..2 {
                let p = l * 2 + v;
                for y in 0..h {
                    for x in 0..w {
                        let row = if bottom_up { h - 1 - y } else { y };
                        let want = rgbe_value(rgbe(p, row * w + x));
                        assert_eq!(
                            btf.value(y * w + x, l, v),
                            want,
                            "{resolution} l {l} v {v} ({x}, {y})"
                        );
                    }
                }
            }
        }
        // A crop keeps the same texels.
        let part = read(pack(&entries), TexelRect::parse("1,1,2,2").ok()).expect("crop");
        assert_eq!(part.texel(3), btf.texel(2 * w + 2));
    }
}

/// Written by the `image` crate's encoder from arbitrary f32 values: RGBE keeps an
/// 8-bit mantissa for the pixel's largest channel and truncates, so each channel
/// comes back at most max(r, g, b) / 128 below the value written (never above).
#[test]
fn hdr_values_round_trip_within_the_rgbe_mantissa() {
    let (w, h) = (6, 2);
    let value = |p: usize, i: usize, k: usize| {
        0.001 + ((p * 31 + i * 7 + k * 13) % 97) as f32 * 0.37 * (1 + p % 3) as f32
    };
    let mut entries = Vec::new();
    for (li, l) in LIGHTS.iter().enumerate() {
        for (vi, v) in VIEWS.iter().enumerate() {
            let p = li * 2 + vi;
            let pixels: Vec<image::Rgb<f32>> = (0..w * h)
                .map(|i| image::Rgb([0, 1, 2].map(|k| value(p, i, k))))
                .collect();
            let mut bytes = Vec::new();
            image::codecs::hdr::HdrEncoder::new(&mut bytes)
                .encode(&pixels, w, h)
                .expect("encode");
            entries.push((hdr_name("x", *l, *v), bytes));
        }
    }
    let btf = read(pack(&entries), None).expect("imports");
    let mut worst = 0f32;
    for p in 0..6 {
        for i in 0..w * h {
            let want = [0, 1, 2].map(|k| value(p, i, k));
            let max = want.iter().copied().fold(0.0, f32::max);
            let got = btf.value(i, p / 2, p % 2);
            for k in 0..3 {
                let below = want[k] - got[k];
                assert!(
                    below >= 0.0 && below <= max / 128.0,
                    "pair {p} pixel {i}: {got:?} vs {want:?}"
                );
                worst = worst.max(below / max);
            }
        }
    }
    // Not trivially exact: the mantissa did round.
    assert!(worst > 1e-4, "{worst}");
}

#[test]
fn hdr_archives_refuse_mixed_kinds_and_unread_orientations() {
    let px: Vec<[u8; 4]> = (0..16).map(|i| rgbe(0, i)).collect();
    let all = |resolution: &str| -> Vec<(String, Vec<u8>)> {
        LIGHTS
            .iter()
            .flat_map(|l| VIEWS.iter().map(move |v| (*l, *v)))
            .map(|(l, v)| (hdr_name("a", l, v), radiance(resolution, &px)))
            .collect()
    };
    assert!(read(pack(&all("+X 4 -Y 4")), None).is_ok());
    let e = |entries: Vec<(String, Vec<u8>)>| {
        read(pack(&entries), None).expect_err("refused").to_string()
    };
    // A JPEG among HDR images names both entries.
    let mut mixed = all("+X 4 -Y 4");
    mixed[3] = (
        "a/tl015 pl000 tv030 pv090.jpg".into(),
        fixture_entries().remove(1).1,
    );
    let m = e(mixed);
    assert!(
        m.contains("a/tl015 pl000 tv030 pv090.jpg")
            && m.contains("JPEG")
            && m.contains("a/tl000 pl000 tv000 pv000.hdr"),
        "{m}"
    );
    // Orientations other than the standard one and ATRIUM's square one.
    for bad in ["+Y 4 +X 4", "+X 8 -Y 2"] {
        let px: Vec<[u8; 4]> = (0..16).map(|i| rgbe(0, i)).collect();
        let mut entries = all("+X 4 -Y 4");
        entries[0].1 = radiance(bad, &px);
        let m = e(entries);
        assert!(
            m.contains("tl000 pl000 tv000 pv000.hdr") && m.contains(bad),
            "{m}"
        );
    }
    // Cut short: named by entry.
    let mut cut = all("-Y 4 +X 4");
    let n = cut[4].1.len();
    cut[4].1.truncate(n - 10);
    let m = e(cut);
    assert!(m.contains(&hdr_name("a", LIGHTS[2], VIEWS[0])), "{m}");
}

/// The import's bound is checked against the first image's size before any other
/// entry is decoded, naming the image and the most texels that fit.
#[test]
fn an_import_over_its_bound_is_refused_naming_the_first_image() {
    let entries = fixture_entries();
    // 8 x 6 texels x 6 pairs x 3 x 4 bytes = 3456 bytes.
    let bytes = pack(&entries);
    assert!(read_zip_within(Cursor::new(bytes.clone()), "z", "t", None, 3456).is_ok());
    let e = read_zip_within(Cursor::new(bytes.clone()), "z", "t", None, 3455)
        .expect_err("over")
        .to_string();
    assert!(
        e.contains("tiny/tl000 pl000 tv000 pv000.jpg")
            && e.contains("is 8x6")
            && e.contains("3456 bytes")
            && e.contains("at most 47 texels"),
        "{e}"
    );
    // A crop within the bound imports.
    let rect = TexelRect::parse("0,0,2,2").ok();
    assert!(read_zip_within(Cursor::new(bytes), "z", "t", rect, 288).is_ok());
}
