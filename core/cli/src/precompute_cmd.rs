//! `meso precompute SCENE --mode biscale [-o CACHE] [--json]` (docs/cli.md): the
//! biscale mode's precomputation with a progress line, its report (stage times, sizes,
//! FLOP ratio, losslessness, the SH and CPCA baselines), and the cache written to
//! `-o` or to the cache folder the mode reads (`MESO_CACHE_DIR`, docs/rendering.md).

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::anyhow;
use clap::Args;
use meso_modes::biscale::{BiscaleSettings, cache};
use meso_render::scene::load_scene;
use meso_render::{ModeKind, Prepare};
use meso_reports::biscale::precompute_report;

use crate::failure::{CliError, ResultExt};

#[derive(Args, Debug)]
pub struct PrecomputeArgs {
    /// The scene file.
    scene: PathBuf,
    /// The mode whose precomputation to run (only `biscale` has one).
    #[arg(long)]
    mode: String,
    /// Cache file to write (default: the cache folder, named by the inputs' hash).
    #[arg(short = 'o', long)]
    output: Option<PathBuf>,
    /// Cube-map side n (6 n^2 environment pixels).
    #[arg(long, default_value_t = 32)]
    cube_n: u32,
    /// Local directions per side (M = res^2): 8 or 12.
    #[arg(long, default_value_t = 8)]
    local_res: u32,
    /// At most about this many vertices added where visibility varies (receivers'
    /// shadows); 0 keeps the scene's own vertices.
    #[arg(long, default_value_t = meso_modes::biscale::DEFAULT_REFINE_VERTICES)]
    refine_vertices: usize,
    /// Skip the SH and CPCA baselines.
    #[arg(long)]
    no_baselines: bool,
    #[arg(long)]
    json: bool,
}

pub fn run(args: &PrecomputeArgs) -> Result<(), CliError> {
    if ModeKind::from_name(&args.mode) != Some(ModeKind::Biscale) {
        return Err(CliError::bad_input(anyhow!(
            "--mode `{}`: only the biscale mode has a precomputation",
            args.mode
        )));
    }
    let scene = load_scene(&args.scene).map_err(CliError::bad_input)?;
    let settings = BiscaleSettings {
        cube_n: args.cube_n,
        local_res: args.local_res,
        refine_vertices: args.refine_vertices,
        ..BiscaleSettings::default()
    };
    if let Some(p) = settings.problem() {
        return Err(CliError::bad_input(anyhow!("{p}")));
    }
    let verbose = std::io::stderr().is_terminal() && !args.json;
    let show = |stage: &str, fraction: f32| {
        if verbose {
            eprint!("\rprecomputing: {stage:<13} {:3.0}%   ", fraction * 100.0);
        }
    };
    let cancel = crate::progress::cancel_flag();
    let (pre, report) = precompute_report(
        &scene,
        &settings,
        !args.no_baselines,
        &Prepare::new(&show, cancel),
    )
    .map_err(|e| CliError::failure(anyhow!(e)))?;
    if verbose {
        eprintln!();
    }
    let path = match (&args.output, &settings.cache_dir) {
        (Some(p), _) => Some(p.clone()),
        (None, Some(dir)) => Some(cache::path_in(dir, pre.key)),
        (None, None) => None,
    };
    if let Some(path) = &path {
        cache::write(path, pre.key, &settings, &pre.transfer, &pre.biclusters)
            .failure_ctx(|| format!("writing the cache `{}`", path.display()))?;
    }
    let mut value = serde_json::to_value(&report)
        .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
    value["cache"] = serde_json::json!(path.as_ref().map(|p| p.display().to_string()));
    if args.json {
        return crate::print_json(&value);
    }
    println!(
        "{} vertices x {} local directions, {} environment pixels, {} nonzeros",
        report.vertices, report.local_dirs, report.env_pixels, report.dense_nonzeros
    );
    println!(
        "stages: bvh {:.2} s, visibility {:.2} s, binning {:.2} s, biclustering {:.2} s",
        report.bvh_seconds,
        report.stages.visibility_seconds,
        report.stages.binning_seconds,
        report.stages.biclustering_seconds
    );
    println!(
        "{} biclusters, FLOP ratio {:.3}, bytes dense {} / biclustered {} / SH {} / CPCA {}",
        report.biclusters,
        report.flop_ratio,
        report.bytes_dense,
        report.bytes_biclustered,
        report.bytes_sh,
        report.bytes_cpca
    );
    println!(
        "lossless check: max |biclustered - dense| = {:.3e} ({:.2e} relative)",
        report.max_abs_error, report.max_rel_error
    );
    for (name, b) in [("SH", &report.sh), ("CPCA", &report.cpca)] {
        if let Some(b) = b {
            println!(
                "{name}: {} bytes, built in {:.2} s, product {:.2} ms, relative RMS error {:.3}",
                b.bytes, b.build_seconds, b.apply_ms, b.relative_rms_error
            );
        }
    }
    if let Some(p) = &path {
        println!("wrote {}", p.display());
    }
    println!("total {:.1} s", report.seconds);
    Ok(())
}
