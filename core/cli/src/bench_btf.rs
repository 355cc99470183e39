//! `meso bench btf SCENE [--max-memory 256MB] [--block-bytes 4KB,256KB] [--frames 4]
//! [--size N] [--rounds 2] [--json]`: the scene's `btf` materials held whole and read
//! out of core through caches of `--max-memory` with each block size, rendered side by
//! side in one process (so every variant meets the same machine). Each variant's mode
//! is prepared once; each round renders `--frames` frames of every variant in turn and
//! the fastest round is reported, with the caches' hits, blocks read, bytes read and
//! seconds spent reading over all rounds. The images are compared bit for bit with the
//! whole table's: a variant whose image differs is an error (exit 1). The whole table
//! is held in memory while the others run, so this needs the BTF's size in memory;
//! peak memory of one variant alone is `meso render --max-memory` under `time -v`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::anyhow;
use clap::Args;
use meso_materials::btf::cache::CacheStats;
use meso_materials::btf::table::MemoryBound;
use meso_render::scene::{Material, load_scene_within};
use meso_render::{Prepare, RenderMode, run_frames};
use serde_json::json;

use crate::failure::CliError;
use crate::mode_args::mode_error;

#[derive(Args, Debug)]
pub struct BtfArgs {
    scene: PathBuf,
    /// The out-of-core variants' bound (powers of 1024: `256MB`, `1GB`).
    #[arg(long, default_value = "256MB")]
    max_memory: String,
    /// Block sizes of the out-of-core variants, comma-separated (`486B`, `4KB`, `256KB`;
    /// below one texel's bytes, blocks of rows; else of whole texels).
    #[arg(long, default_value = "4KB,256KB")]
    block_bytes: String,
    /// Frames each variant renders per round.
    #[arg(long, default_value_t = 4)]
    frames: u32,
    /// Rounds (the fastest is reported).
    #[arg(long, default_value_t = 2)]
    rounds: u32,
    /// Image side in pixels (default: the scene's width and height).
    #[arg(long)]
    size: Option<u32>,
    #[arg(long)]
    json: bool,
}

struct Variant {
    name: String,
    mode: Box<dyn RenderMode>,
    tables: Vec<std::sync::Arc<meso_materials::btf::table::BtfTable>>,
    best_s: f64,
    prepare_s: f64,
}

fn stats(v: &Variant) -> CacheStats {
    v.tables
        .iter()
        .filter_map(|t| t.cache())
        .map(|c| c.stats())
        .fold(CacheStats::default(), |a, b| CacheStats {
            hits: a.hits + b.hits,
            reads: a.reads + b.reads,
            bytes_read: a.bytes_read + b.bytes_read,
            read_seconds: a.read_seconds + b.read_seconds,
        })
}

pub fn run(args: &BtfArgs) -> Result<(), CliError> {
    let bad = |e: anyhow::Error| CliError::bad_input(e);
    let max_memory = meso_fit::memory::parse_bytes(&args.max_memory)
        .map_err(|e| bad(anyhow!("--max-memory {e}")))?;
    let blocks = args
        .block_bytes
        .split(',')
        .map(|b| {
            meso_fit::memory::parse_bytes(b.trim())
                .map_err(|e| bad(anyhow!("--block-bytes `{b}`: {e}")))
        })
        .collect::<Result<Vec<u64>, _>>()?;
    if args.frames == 0 || args.rounds == 0 {
        return Err(bad(anyhow!("--frames and --rounds must be at least 1")));
    }
    let threads = rayon::current_num_threads();
    let mut bounds = vec![("in core".to_string(), MemoryBound::new(u64::MAX))];
    for &block_bytes in &blocks {
        bounds.push((
            format!("out of core, {block_bytes}-byte blocks"),
            MemoryBound {
                max_bytes: max_memory,
                block_bytes,
                threads,
            },
        ));
    }
    let mut variants = Vec::new();
    for (name, bound) in bounds {
        let start = Instant::now();
        let scene = load_scene_within(&args.scene, bound).map_err(|e| bad(anyhow!(e)))?;
        let tables: Vec<_> = scene
            .materials
            .iter()
            .filter_map(|m| match m {
                Material::Btf { table, .. } => Some(table.clone()),
                _ => None,
            })
            .collect();
        if tables.is_empty() {
            return Err(bad(anyhow!(
                "`{}` has no btf material to measure",
                args.scene.display()
            )));
        }
        if variants.is_empty() != tables.iter().all(|t| t.is_resident()) {
            return Err(bad(anyhow!(
                "{name}: with --max-memory {} the btf materials are {} (a bound below the BTF's values is needed)",
                args.max_memory,
                if tables.iter().all(|t| t.is_resident()) {
                    "held whole"
                } else {
                    "out of core"
                }
            )));
        }
        let (w, h) = args
            .size
            .map_or((scene.render.width, scene.render.height), |s| (s, s));
        let (kind, device) = (scene.render.mode, scene.render.device);
        let mode = meso_modes::create(kind, device, scene, w, h, Prepare::quietly())
            .map_err(mode_error)?;
        variants.push(Variant {
            name,
            mode,
            tables,
            best_s: f64::INFINITY,
            prepare_s: start.elapsed().as_secs_f64(),
        });
    }
    for _ in 0..args.rounds {
        for v in &mut variants {
            let run = run_frames(v.mode.as_mut(), args.frames, |_, _| {});
            v.best_s = v.best_s.min(run.seconds / f64::from(args.frames));
        }
    }
    let bits = |v: &Variant| -> Vec<u32> {
        v.mode
            .image()
            .pixels()
            .iter()
            .flat_map(|p| p.iter().map(|c| c.to_bits()))
            .collect()
    };
    let want = bits(&variants[0]);
    let whole_s = variants[0].best_s;
    let mut rows = Vec::new();
    for v in &variants {
        if let Some(e) = v.tables.iter().find_map(|t| t.read_error()) {
            return Err(CliError::failure(anyhow!("{}: {e}", v.name)));
        }
        let same = bits(v) == want;
        let s = stats(v);
        let cache_bytes: u64 = v
            .tables
            .iter()
            .filter_map(|t| t.cache())
            .map(|c| c.bytes())
            .sum();
        let lookups = s.hits + s.reads;
        let frames = f64::from(args.frames * args.rounds);
        if !args.json {
            println!(
                "{:<34} {:>8.3} s/frame ({:>5.1}x in core)  prepare {:>6.1} s  hit rate {:>5.1}%  {:>8.1} MB read/frame  {:>6.3} s reading/frame  cache {} MB  image {}",
                v.name,
                v.best_s,
                v.best_s / whole_s,
                v.prepare_s,
                if lookups == 0 {
                    100.0
                } else {
                    100.0 * s.hits as f64 / lookups as f64
                },
                s.bytes_read as f64 / frames / 1e6,
                s.read_seconds / frames,
                cache_bytes / 1_000_000,
                if same { "bit-identical" } else { "DIFFERS" },
            );
        }
        rows.push(json!({
            "variant": v.name,
            "seconds_per_frame": v.best_s,
            "times_in_core": v.best_s / whole_s,
            "prepare_seconds": v.prepare_s,
            "hits": s.hits,
            "blocks_read": s.reads,
            "bytes_read": s.bytes_read,
            "read_seconds": s.read_seconds,
            "cache_bytes": cache_bytes,
            "block_rows": v.tables.iter().find_map(|t| t.cache()).map(|c| c.shape().rows_per_block),
            "bit_identical": same,
        }));
        if !same {
            return Err(CliError::failure(anyhow!(
                "{}: the image differs from the in-core image",
                v.name
            )));
        }
    }
    if args.json {
        return crate::print_json(&json!({
            "scene": args.scene.display().to_string(),
            "max_memory": max_memory,
            "frames": args.frames,
            "rounds": args.rounds,
            "threads": threads,
            "variants": rows,
        }));
    }
    Ok(())
}
