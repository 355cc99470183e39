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
    let btf = import_zip(&reference("ubo2003.zip"), "tiny", None).expect("import");
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
    let part = import_zip(&reference("ubo2003.zip"), "tiny", Some(rect)).expect("crop");
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
