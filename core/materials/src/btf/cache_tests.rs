//! The out-of-core table against the in-memory one: every texel and direction pair of a
//! synthesized BTF through a cache a fraction of its size (so blocks are evicted and
//! read again), from one thread and from several; and what a bad file does.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use glam::DVec3;

use super::*;
use crate::btf::file::{BtfPrecision, read_btf, write_btf};
use crate::btf::synth::{parse_recipe, synthesize};
use crate::btf::table::{BtfOpenError, BtfTable, MemoryBound};
use crate::btf::{Btf, directions};

/// An 8x8 woven BTF on 12 directions (144 pairs, 432 values a texel).
fn woven() -> Btf {
    let recipe = r#"
version = 1
name = "weave"
width = 8
height = 8
direction_rings = [[0.0, 1], [40.0, 5], [75.0, 6]]
detail = 4
supersample = 1
[mesostructure]
kind = "weave"
depth = 2.0
threads = 4
[[region]]
name = "warp"
[[region.lobe]]
model = "lambertian"
weight = [0.3, 0.2, 0.6]
[[region.lobe]]
model = "ward"
params = { ax = 0.3, ay = 0.1 }
weight = [0.2, 0.2, 0.2]
[[region]]
name = "weft"
[[region.lobe]]
model = "lambertian"
weight = [0.7, 0.6, 0.5]
"#;
    let setup = parse_recipe(recipe, Path::new("."), "weave.toml").expect("valid recipe");
    synthesize(&setup, &AtomicBool::new(false), &|_, _| {}).expect("synthesis runs")
}

/// A bound that leaves the cache 4 blocks of 2 texels (the BTF has 32 blocks) besides
/// 2 workers' blocks in flight, the blocks' overhead and the index.
fn tight(texel_bytes: u64) -> MemoryBound {
    let block = 2 * texel_bytes;
    MemoryBound {
        max_bytes: (TRANSIENT_BLOCKS_PER_THREAD * 2 + 4) * block
            + 4 * BLOCK_OVERHEAD
            + (32 + MAX_SHARDS as u64) * INDEX_BYTES,
        block_bytes: block,
        threads: 2,
    }
}

/// A bound that leaves the cache 6 blocks of 5 rows (texel x light; a texel has 12)
/// besides 2 workers' blocks in flight: blocks smaller than a texel are runs of rows.
fn rows_tight(row_bytes: u64, rows: usize) -> MemoryBound {
    let block = 5 * row_bytes;
    MemoryBound {
        max_bytes: (TRANSIENT_BLOCKS_PER_THREAD * 2 + 6) * block
            + 6 * BLOCK_OVERHEAD
            + (rows.div_ceil(5) + MAX_SHARDS) as u64 * INDEX_BYTES,
        block_bytes: block,
        threads: 2,
    }
}

/// Every (texel, light, view) in an order that sweeps the grid twice with a stride,
/// so a 4-block cache keeps evicting.
fn sweep(btf: &Btf, start: usize) -> impl Iterator<Item = (usize, DVec3, DVec3)> + '_ {
    let n = btf.texels();
    (0..2 * n).flat_map(move |k| {
        let t = (start + k * 7) % n;
        let (l, v) = (btf.light_dirs(), btf.view_dirs());
        (0..l.len()).flat_map(move |i| (0..v.len()).map(move |j| (t, l[i], v[j])))
    })
}

/// Off the tabulated pairs too: between directions and beyond the last ring.
fn between() -> [(DVec3, DVec3); 3] {
    [
        (
            DVec3::new(0.3, 0.2, 0.9).normalize(),
            DVec3::new(-0.5, 0.1, 0.6).normalize(),
        ),
        (
            DVec3::new(0.99, 0.0, 0.05).normalize(),
            DVec3::new(0.0, 0.7, 0.7).normalize(),
        ),
        (DVec3::Z, DVec3::new(0.2, -0.9, 0.3).normalize()),
    ]
}

#[test]
fn out_of_core_values_equal_the_in_memory_table_at_every_pair() {
    let dir = tempfile::tempdir().expect("temp dir");
    let btf = woven();
    // F16 file (F16 storage), F32 file of synthesized values (F32 storage), and an
    // F32 file whose values are all f16 (F16 storage, as `BtfTable::new` decides).
    let halves = Btf::new(
        "h".into(),
        "t".into(),
        8,
        8,
        btf.light_dirs().to_vec(),
        btf.view_dirs().to_vec(),
        btf.data()
            .iter()
            .map(|&x| half::f16::from_f32(x).to_f32())
            .collect(),
    )
    .expect("valid");
    for (source, precision, storage) in [
        (&btf, BtfPrecision::F16, Storage::F16),
        (&btf, BtfPrecision::F32, Storage::F32),
        (&halves, BtfPrecision::F32, Storage::F16),
    ] {
        let path = dir.path().join("w.btf");
        write_btf(&path, source, precision).expect("write");
        let whole = BtfTable::new(&read_btf(&path).expect("read")).expect("shadeable");
        let texel_bytes = (source.pairs() * 3) as u64 * if storage == Storage::F16 { 2 } else { 4 };
        let table = BtfTable::open(&path, tight(texel_bytes)).expect("opens out of core");
        assert!(!table.is_resident());
        assert_eq!((whole.storage(), table.storage()), (storage, storage));
        assert_eq!(table.value_bytes(), whole.bytes() as u64);
        let cache = table.cache().expect("cached");
        assert_eq!(cache.shape().rows_per_block, 2 * source.light_dirs().len());
        assert_eq!(cache.shape().shards * cache.shape().blocks_per_shard, 4);
        assert!(table.bytes() < whole.bytes() / 2, "{} bytes", table.bytes());
        for (t, wi, wo) in sweep(source, 0) {
            let (a, b) = (table.eval_texel(t, wi, wo), whole.eval_texel(t, wi, wo));
            assert_eq!(
                a.to_array().map(f64::to_bits),
                b.to_array().map(f64::to_bits)
            );
        }
        for t in 0..source.texels() {
            for (wi, wo) in between() {
                assert_eq!(table.eval_texel(t, wi, wo), whole.eval_texel(t, wi, wo));
            }
        }
        // Two sweeps of 32 blocks through 4 slots: nearly every visit is a miss.
        assert!(cache.reads() >= 60, "{} reads", cache.reads());
        assert_eq!(table.read_error(), None);

        // Blocks of 5 rows, which straddle texels: the same values again.
        let rows = source.texels() * source.light_dirs().len();
        let row_bytes = texel_bytes / source.light_dirs().len() as u64;
        let table = BtfTable::open(&path, rows_tight(row_bytes, rows)).expect("opens");
        let cache = table.cache().expect("cached");
        assert_eq!(cache.shape().rows_per_block, 5);
        assert_eq!(cache.shape().shards * cache.shape().blocks_per_shard, 6);
        assert!(cache.bytes() <= rows_tight(row_bytes, rows).max_bytes);
        for (t, wi, wo) in sweep(source, 3) {
            let (a, b) = (table.eval_texel(t, wi, wo), whole.eval_texel(t, wi, wo));
            assert_eq!(
                a.to_array().map(f64::to_bits),
                b.to_array().map(f64::to_bits)
            );
        }
        for t in 0..source.texels() {
            for (wi, wo) in between() {
                assert_eq!(table.eval_texel(t, wi, wo), whole.eval_texel(t, wi, wo));
            }
        }
        let stats = cache.stats();
        assert!(stats.hits > 0 && stats.reads > 100, "{stats:?}");
        assert!(stats.bytes_read <= stats.reads * 5 * row_bytes, "{stats:?}");
        assert_eq!(table.read_error(), None);
    }
}

#[test]
fn concurrent_lookups_through_an_evicting_cache_agree() {
    let dir = tempfile::tempdir().expect("temp dir");
    let btf = woven();
    let path = dir.path().join("w.btf");
    write_btf(&path, &btf, BtfPrecision::F32).expect("write");
    let whole = BtfTable::new(&btf).expect("shadeable");
    let table = BtfTable::open(&path, tight((btf.pairs() * 3 * 4) as u64)).expect("opens");
    assert!(!table.is_resident());
    std::thread::scope(|s| {
        for start in 0..6 {
            let (table, whole, btf) = (&table, &whole, &btf);
            s.spawn(move || {
                for (t, wi, wo) in sweep(btf, start * 11) {
                    assert_eq!(table.eval_texel(t, wi, wo), whole.eval_texel(t, wi, wo));
                }
            });
        }
    });
    assert_eq!(table.read_error(), None);
}

#[test]
fn a_btf_within_the_bound_is_held_whole_like_new_holds_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    let btf = woven();
    let path = dir.path().join("w.btf");
    write_btf(&path, &btf, BtfPrecision::F16).expect("write");
    let whole = BtfTable::new(&read_btf(&path).expect("read")).expect("shadeable");
    // Exactly its values' size: held whole.
    let table = BtfTable::open(&path, MemoryBound::new(whole.bytes() as u64)).expect("opens");
    assert!(table.is_resident());
    assert_eq!(table.bytes(), whole.bytes());
    assert_eq!(table.path(), Some(path.as_path()));
    let (Some(a), Some(b)) = (table.parts(), whole.parts()) else {
        panic!("both are resident");
    };
    match (a.values, b.values) {
        (crate::btf::table::BtfValues::F16(a), crate::btf::table::BtfValues::F16(b)) => {
            assert!(a == b)
        }
        _ => panic!("an F16 file is held as f16"),
    }
    // One byte less: read through a cache, no values for a device to upload.
    let bound = MemoryBound {
        max_bytes: whole.bytes() as u64 - 1,
        block_bytes: (btf.pairs() * 3 * 2) as u64,
        threads: 1,
    };
    let cached = BtfTable::open(&path, bound).expect("opens");
    assert!(!cached.is_resident() && cached.parts().is_none());
}

#[test]
fn bad_files_and_bounds_are_refused_naming_the_file_and_the_place() {
    let dir = tempfile::tempdir().expect("temp dir");
    let dirs = directions::rings(&[(0.0, 1), (45.0, 4)]);
    let n = 16 * dirs.len() * dirs.len() * 3;
    let data: Vec<f32> = (0..n).map(|i| 0.01 * (i % 89) as f32 + 0.1).collect();
    let btf = Btf::new("s".into(), "p".into(), 4, 4, dirs.clone(), dirs, data).expect("valid");
    let path = dir.path().join("s.btf");
    write_btf(&path, &btf, BtfPrecision::F32).expect("write");
    let good = std::fs::read(&path).expect("read");
    let texel_bytes = (btf.pairs() * 3 * 4) as u64;
    // One worker's blocks in flight and two resident: less than the 16 texels.
    let bound = MemoryBound {
        max_bytes: (TRANSIENT_BLOCKS_PER_THREAD + 2) * texel_bytes
            + 2 * BLOCK_OVERHEAD
            + (16 + MAX_SHARDS as u64) * INDEX_BYTES,
        block_bytes: texel_bytes,
        threads: 1,
    };

    // A NaN in the last texel: found by the opening scan, named by texel.
    let mut bad = good.clone();
    let end = bad.len();
    bad[end - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&path, &bad).expect("write");
    let e = BtfTable::open(&path, bound).expect_err("NaN").to_string();
    assert!(
        e.contains("s.btf") && e.contains("texel 15") && e.contains("not finite"),
        "{e}"
    );

    // Cut short: refused at opening, naming the sizes.
    std::fs::write(&path, &good[..good.len() - 10]).expect("write");
    let e = BtfTable::open(&path, bound).expect_err("cut").to_string();
    assert!(e.contains("s.btf") && e.contains("the file has"), "{e}");

    // Cut short after opening (the file replaced under a render): the texels it no
    // longer holds shade as 0 and the table keeps the error, naming file and texels.
    std::fs::write(&path, &good).expect("write");
    let table = BtfTable::open(&path, bound).expect("opens");
    assert!(!table.is_resident());
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .and_then(|f| f.set_len(good.len() as u64 - texel_bytes))
        .expect("truncate");
    assert_eq!(table.eval_texel(15, DVec3::Z, DVec3::Z), DVec3::ZERO);
    let e = table.read_error().expect("kept");
    assert!(e.contains("s.btf"), "{e}");
    assert!(table.eval_texel(0, DVec3::Z, DVec3::Z).x > 0.0);

    // A bound that cannot hold one block besides the workers' is refused, naming
    // what is needed.
    std::fs::write(&path, &good).expect("write");
    let tiny = MemoryBound {
        max_bytes: 100,
        block_bytes: texel_bytes,
        threads: 1,
    };
    match BtfTable::open(&path, tiny) {
        Err(BtfOpenError::Memory { path: p, problem }) => {
            assert_eq!(p, path);
            assert!(problem.contains("at least"), "{problem}");
        }
        other => panic!("expected a memory error, got {other:?}"),
    }
}

#[test]
fn shapes_keep_resident_and_in_flight_blocks_within_the_bound() {
    // Bonn 81 x 81 as f16: 486-byte rows, 81 a texel; 256x256 texels; 256 MiB; 16 workers.
    let rows = 65536 * 81;
    // Blocks of whole texels (a source that reads texels): 6 texels of 39366 bytes.
    let shape = CacheShape::fit(486, 81, rows, 256 << 20, 256 << 10, 16).expect("fits");
    assert_eq!(shape.rows_per_block, 6 * 81);
    assert!(shape.bytes(486, rows, 16) <= 256 << 20);
    assert_eq!(shape.shards, MAX_SHARDS);
    // Blocks of rows: the same bytes, 539 rows; by default one row, and the index
    // is counted too.
    let shape = CacheShape::fit(486, 1, rows, 256 << 20, 256 << 10, 16).expect("fits");
    assert_eq!(shape.rows_per_block, 539);
    let shape = CacheShape::fit(486, 1, rows, 256 << 20, BLOCK_BYTES, 16).expect("fits");
    assert_eq!(shape.rows_per_block, 1);
    let bytes = shape.bytes(486, rows, 16);
    assert!(bytes <= 256 << 20 && bytes > 255 << 20, "{bytes}");
    let resident = (shape.shards * shape.blocks_per_shard) as u64;
    // 21 MB of index and 128 bytes a block besides the values.
    assert!(resident * 486 < (256 << 20) - rows as u64 * 4 - resident * BLOCK_OVERHEAD);
    // A unit larger than a block is a block by itself.
    let shape = CacheShape::fit(1 << 20, 1, 100, 64 << 20, BLOCK_BYTES, 2).expect("fits");
    assert_eq!(shape.rows_per_block, 1);
    assert_eq!(shape.shards * shape.blocks_per_shard, 55);
    // Never more blocks resident than the BTF has.
    let shape = CacheShape::fit(1000, 1, 10, 1 << 30, 2000, 1).expect("fits");
    assert_eq!(shape.shards * shape.blocks_per_shard, 5);
    let e = CacheShape::fit(1000, 1, 10, 3999, 1000, 1).expect_err("no room");
    assert!(e.contains("at least") && e.contains("index"), "{e}");
}
