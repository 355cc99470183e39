//! Out-of-core and split fits: blocks, an on-disk source and shards merged all give
//! the unsharded in-memory pack bit for bit; merge refuses parts that do not belong
//! together, naming them.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use super::tests::{quiet, weave_btf};
use super::*;
use meso_materials::btf::Btf;
use meso_materials::btf::file::{BtfPrecision, write_btf};
use meso_materials::btf::on_disk::OnDiskBtf;
use meso_materials::spmm::pack::encode_pack;

/// Small settings that still sample (40 of 64 texels, 6 per cluster's residual).
fn settings() -> FitSettings {
    FitSettings {
        clusters: 3,
        subclusters: 2,
        max_bases: 3,
        npca: 3,
        fit_pairs: 60,
        seed: 3,
        sample_texels: 40,
        residual_texels: 6,
        ..FitSettings::default()
    }
}

fn pack_bytes(out: &FitOutput) -> Vec<u8> {
    encode_pack(&out.material, out.precision)
}

fn part(btf: &Btf, s: &FitSettings, k: u32, n: u32) -> Part {
    let shard = Shard::new(k, n).expect("valid shard");
    fit_part(
        btf,
        ("w", "t", "w.btf"),
        s,
        shard,
        &AtomicBool::new(false),
        &quiet,
    )
    .expect("part")
}

#[test]
fn blocks_disk_and_four_shards_all_give_the_same_pack() {
    let btf = weave_btf();
    let s = settings();
    let whole = fit_btf(&btf, "w", "t", &s, &AtomicBool::new(false), &quiet).expect("fit");
    let want = pack_bytes(&whole);
    assert_eq!(whole.report.overall.texels, 64);

    // A budget that leaves blocks of 3 texels.
    let (texels, pairs) = (btf.texels(), btf.pairs());
    let held = memory::fixed_bytes(&s, texels, pairs).max(memory::model_bytes(&s, texels, pairs));
    let tight = FitSettings {
        max_memory: held + 3 * pairs as u64 * 12,
        ..s
    };
    assert_eq!(
        memory::block_texels(&tight, texels, pairs).expect("fits"),
        3
    );
    let blocked = fit_btf(&btf, "w", "t", &tight, &AtomicBool::new(false), &quiet).expect("fit");
    assert!(pack_bytes(&blocked) == want, "blocks of 3 changed the pack");

    // The same BTF read from disk block by block.
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("w.btf");
    write_btf(&path, &btf, BtfPrecision::F32).expect("write");
    let disk = OnDiskBtf::open(&path).expect("open");
    let from_disk = fit_btf(&disk, "w", "t", &tight, &AtomicBool::new(false), &quiet).expect("fit");
    assert!(pack_bytes(&from_disk) == want, "the on-disk fit differs");

    // Four shards, their parts through the file format, merged in another order.
    let parts: Vec<Part> = (1..=4).map(|k| part(&btf, &s, k, 4)).collect();
    let mut files = Vec::new();
    for (i, p) in parts.iter().enumerate() {
        let bytes = p.encode();
        let back = Part::decode(&bytes).expect("decode");
        assert!(back == *p, "part {} does not round-trip", i + 1);
        let path = dir.path().join(format!("p{}.part", i + 1));
        std::fs::write(&path, &bytes).expect("write part");
        files.push(path);
    }
    assert_eq!(
        parts.iter().map(|p| p.fits.len()).sum::<usize>(),
        64,
        "the shards cover every texel once"
    );
    let order = [
        files[2].clone(),
        files[0].clone(),
        files[3].clone(),
        files[1].clone(),
    ];
    let merged = merge(&order).expect("merge");
    assert!(
        pack_bytes(&merged) == want,
        "4 shards merged differ from the unsharded fit"
    );
    assert_eq!(merged.report.overall, whole.report.overall);
    assert_eq!(merged.report.per_cluster, whole.report.per_cluster);

    // Refusals, each naming the files at fault.
    let err = |paths: &[PathBuf]| merge(paths).err().expect("refused").to_string();
    let e = err(&[
        files[0].clone(),
        files[1].clone(),
        files[1].clone(),
        files[3].clone(),
    ]);
    assert!(e.contains("p2.part") && e.contains("both shard 2/4"), "{e}");
    let e = err(&[files[0].clone(), files[1].clone(), files[3].clone()]);
    assert!(e.contains("shard(s) 3 of 4 missing"), "{e}");
    let halves = dir.path().join("half.part");
    std::fs::write(&halves, part(&btf, &s, 1, 2).encode()).expect("write");
    let e = err(&[files[0].clone(), halves.clone()]);
    assert!(
        e.contains("half.part") && e.contains("shard 1 of 2") && e.contains("of 4"),
        "{e}"
    );
    let other_seed = dir.path().join("seed.part");
    let s9 = FitSettings { seed: 9, ..s };
    std::fs::write(&other_seed, part(&btf, &s9, 2, 4).encode()).expect("write");
    let e = err(&[files[0].clone(), other_seed]);
    assert!(
        e.contains("seed.part") && e.contains("other options") && e.contains("seed 9"),
        "{e}"
    );
    let mut bytes = std::fs::read(&files[0]).expect("read");
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    let damaged = dir.path().join("damaged.part");
    std::fs::write(&damaged, &bytes).expect("write");
    let e = err(std::slice::from_ref(&damaged));
    assert!(e.contains("damaged.part") && e.contains("checksum"), "{e}");
    std::fs::write(&damaged, b"MESOPART").expect("write");
    let e = err(&[damaged]);
    assert!(e.contains("not a fit part"), "{e}");
    let e = err(&[dir.path().join("absent.part")]);
    assert!(
        e.contains("absent.part") && e.contains("cannot read"),
        "{e}"
    );
    assert!(matches!(
        merge_parts(Vec::new()),
        Err(MergeFailure::Parts(MergeError::NoParts))
    ));
}

#[test]
fn parts_of_another_input_are_refused() {
    let btf = weave_btf();
    let s = settings();
    // The same grid and directions with one value changed in every texel.
    let mut data = btf.data().to_vec();
    let per = btf.pairs() * 3;
    for t in 0..btf.texels() {
        data[t * per] += 0.25;
    }
    let other = Btf::new(
        "w".into(),
        "t".into(),
        btf.width(),
        btf.height(),
        btf.light_dirs().to_vec(),
        btf.view_dirs().to_vec(),
        data,
    )
    .expect("valid");
    let a = (PathBuf::from("a.part"), part(&btf, &s, 1, 2));
    let b = (PathBuf::from("b.part"), part(&other, &s, 2, 2));
    let e = merge_parts(vec![a, b]).err().expect("refused").to_string();
    assert!(
        e.contains("`b.part` fits a different input than `a.part`"),
        "{e}"
    );
}

#[test]
fn shards_parse_and_cover_the_texels() {
    assert_eq!(Shard::parse("2/4"), Ok(Shard { k: 2, n: 4 }));
    for bad in ["0/4", "5/4", "1/0", "a/4", "3", "-1/4"] {
        let e = Shard::parse(bad).expect_err(bad);
        assert!(e.contains(&format!("`{bad}`")), "{bad}: {e}");
    }
    assert!(Shard::parse("5/4").unwrap_err().contains("out of range"));
    // Every texel in exactly one shard, in order, for awkward counts.
    for (texels, n) in [(10usize, 4u32), (3, 5), (160_000, 7)] {
        let mut next = 0;
        for k in 1..=n {
            let r = Shard { k, n }.texels(texels);
            assert_eq!(r.start, next);
            next = r.end;
        }
        assert_eq!(next, texels);
    }
}

/// A model file spares shards the model stages and changes nothing: the unsharded fit
/// and two shards merged, both from the model read back from its bytes, give the
/// unsharded pack bit for bit. A model found with other options, on another input, or
/// damaged is refused with the file named, never a panic.
#[test]
fn a_model_file_gives_the_same_pack_and_is_used_only_where_it_was_found() {
    let btf = weave_btf();
    let s = settings();
    let no = AtomicBool::new(false);
    let want = pack_bytes(&fit_btf(&btf, "w", "t", &s, &no, &quiet).expect("fit"));
    let found = find_model(&btf, "w.btf", &s, &no, &quiet).expect("model");
    let bytes = found.encode();
    let path = std::path::Path::new("w.model");
    let load = || FitModel::decode(&bytes).expect("decodes");
    let from = fit_btf_from(
        &btf,
        ("w", "t"),
        &s,
        ModelFrom::File(Box::new(load()), path),
        &no,
        &quiet,
    )
    .expect("fit from the model file");
    assert!(pack_bytes(&from) == want, "the model file changed the pack");
    let parts: Vec<(PathBuf, Part)> = (1..=2)
        .map(|k| {
            let shard = Shard::new(k, 2).expect("shard");
            let from = ModelFrom::File(Box::new(load()), path);
            let p = fit_part_from(&btf, ("w", "t", "w.btf"), &s, shard, from, &no, &quiet)
                .expect("part");
            (PathBuf::from(format!("p{k}.part")), p)
        })
        .collect();
    // A part whose shard found the model itself merges with them: the same model.
    // (Timings aside: the stages' and the texels' seconds are the runs' own.)
    let mut own = part(&btf, &s, 2, 2);
    own.texel_seconds = parts[1].1.texel_seconds;
    own.tables.seconds = parts[1].1.tables.seconds;
    assert!(parts[1].1 == own, "a part from the file differs");
    let merged = merge_parts(parts).expect("merge");
    assert!(
        pack_bytes(&merged) == want,
        "shards from the model file differ"
    );

    let refused = |settings: &FitSettings, src: &Btf, model: FitModel| {
        fit_btf_from(
            src,
            ("w", "t"),
            settings,
            ModelFrom::File(Box::new(model), path),
            &no,
            &quiet,
        )
        .err()
        .expect("refused")
        .to_string()
    };
    let other = FitSettings { npca: 2, ..s };
    let e = refused(&other, &btf, load());
    assert!(e.contains("w.model") && e.contains("other options"), "{e}");
    let brighter = Btf::new(
        "w".into(),
        "t".into(),
        btf.width(),
        btf.height(),
        btf.light_dirs().to_vec(),
        btf.view_dirs().to_vec(),
        btf.data().iter().map(|v| v * 1.5).collect(),
    )
    .expect("a valid BTF");
    let e = refused(&s, &brighter, load());
    assert!(e.contains("w.model") && e.contains("another input"), "{e}");

    // Every truncation and a flipped byte in each part of the file: an error, no panic.
    for cut in (0..bytes.len()).step_by(97) {
        assert!(FitModel::decode(&bytes[..cut]).is_err(), "cut at {cut}");
    }
    for at in (8..bytes.len()).step_by(89) {
        let mut bad = bytes.clone();
        bad[at] ^= 0x40;
        assert!(FitModel::decode(&bad).is_err(), "flipped byte {at}");
    }
}
