//! `meso report fit BTF PACK [--scene SCENE] -o DIR [--json]`: how a fitted pack looks
//! against its BTF (`meso_reports::fidelity`): table-space RMSE (overall, grazing,
//! elsewhere, basis sum alone), then per scene the BTF and the pack rendered alike,
//! their `meso compare` metrics, and a side-by-side PNG (BTF, pack, difference); and
//! the image error split into the fit's part and the direction interpolation's, by a
//! third render of the pack tabulated at the BTF's pairs. The BTF is read from disk in
//! blocks and both it and the tabulation are shaded within `--max-memory` (each held
//! whole within half of it, else read on demand through a bounded cache).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::anyhow;
use clap::Args;
use meso_materials::atomic::write_bytes_atomic;
use meso_materials::btf::on_disk::OnDiskBtf;
use meso_materials::btf::table::{BtfTable, MemoryBound, SourceError};
use meso_materials::btf::texels::TexelSource;
use meso_materials::image::{write_exr, write_image};
use meso_materials::spmm::SpmmMaterial;
use meso_materials::spmm::pack::read_pack;
use meso_render::scene::{RenderSettings, load_scene};
use meso_reports::fidelity::{
    ImageErrors, PackTabulation, RenderRequest, TableErrors, image_errors, render_all,
    side_by_side, table_errors,
};
use serde_json::json;

use crate::failure::{CliError, ResultExt};

/// The default scenes, in the source tree: the bunny under an area light and the
/// studio environment, and a flat patch at grazing light.
const DEFAULT_SCENES: [&str; 2] = ["fit_bunny.toml", "fit_grazing.toml"];

#[derive(Args, Debug)]
pub struct FitReportArgs {
    /// The BTF (.btf) the pack was fitted to: the ground truth.
    btf: PathBuf,
    /// The fitted pack (.spmm).
    pack: PathBuf,
    /// Scene to render (repeatable); default: tests/scenes/fit_bunny.toml and
    /// fit_grazing.toml of the source tree.
    #[arg(long)]
    scene: Vec<PathBuf>,
    /// The scene material the BTF and the pack replace (keeping its tiling).
    #[arg(long, default_value = "sample")]
    material: String,
    /// Output folder (created if missing).
    #[arg(short = 'o', long)]
    output: PathBuf,
    #[arg(long, default_value_t = 160)]
    width: u32,
    #[arg(long, default_value_t = 160)]
    height: u32,
    /// Frames of each render (both use the same random numbers).
    #[arg(long, default_value_t = 256)]
    frames: u32,
    /// Exposure in stops of the PNG panels.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f64,
    /// Gain of the difference panel.
    #[arg(long, default_value_t = 4.0)]
    diff_gain: f32,
    /// Most bytes of BTF values held at once (`256MB`, `4GB`; powers of 1024): half
    /// for the BTF, half for the pack tabulated at its pairs, each held whole within
    /// its half, else shaded from blocks read (or evaluated) on demand.
    #[arg(long, default_value = "2GB")]
    max_memory: String,
    #[arg(long)]
    json: bool,
}

fn default_scenes() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/scenes");
    DEFAULT_SCENES.iter().map(|s| dir.join(s)).collect()
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map_or("scene".into(), |s| s.to_string_lossy().into_owned())
}

pub fn run(args: &FitReportArgs) -> Result<(), CliError> {
    let scenes = checked_scenes(args)?;
    let started = Instant::now();
    let inputs = read_inputs(args)?;
    std::fs::create_dir_all(&args.output)
        .failure_ctx(|| format!("creating `{}`", args.output.display()))?;
    let request = RenderRequest {
        width: args.width,
        height: args.height,
        frames: args.frames,
        material: args.material.clone(),
    };
    let out = |name: &str| args.output.join(name);
    let mut rows = Vec::new();
    let mut worst: Option<ImageErrors> = None;
    let mut worst_fit: Option<ImageErrors> = None;
    for path in &scenes {
        let (row, e, fit) = report_scene(args, path, &inputs, &request)?;
        worst = Some(worse(worst, e));
        worst_fit = Some(worse(worst_fit, fit));
        rows.push(row);
    }
    let (worst, worst_fit) = (
        worst.expect("at least one scene"),
        worst_fit.expect("at least one scene"),
    );
    let table = &inputs.table;
    let report = json!({
        "btf": args.btf.display().to_string(),
        "pack": args.pack.display().to_string(),
        "pack_bytes": inputs.pack_bytes,
        "btf_resident_bytes": inputs.shaded.bytes(),
        "width": args.width,
        "height": args.height,
        "frames": args.frames,
        "material": args.material,
        // Worst over the scenes: largest RMSE, smallest PSNR and MSSIM.
        "image_relative_rmse": worst.relative_rmse,
        "image_psnr_db": worst.psnr_db,
        "image_mssim": worst.mssim,
        "fit_image_relative_rmse": worst_fit.relative_rmse,
        "fit_image_mssim": worst_fit.mssim,
        "table_relative_rmse": table.relative_rmse,
        "table_grazing_relative_rmse": table.grazing_relative_rmse,
        "table_elsewhere_relative_rmse": table.elsewhere_relative_rmse,
        "table_grazing_fraction": table.grazing_fraction,
        "table_basis_relative_rmse": table.basis_relative_rmse,
        "mean_reflectance": table.mean_reflectance,
        "scenes": rows,
        "seconds": started.elapsed().as_secs_f64(),
    });
    let text = serde_json::to_string_pretty(&report)
        .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
    write_bytes_atomic(&out("report.json"), text.as_bytes())
        .failure_ctx(|| format!("writing `{}`", out("report.json").display()))?;
    if args.json {
        return crate::print_json(&report);
    }
    print_summary(args, &inputs, &rows);
    Ok(())
}

/// The scenes to render (the default ones unless `--scene` names some), after the
/// options are checked: their file names must differ, as they name the images.
fn checked_scenes(args: &FitReportArgs) -> Result<Vec<PathBuf>, CliError> {
    if let Some(p) = RenderSettings::size_problem(args.width, args.height) {
        return Err(CliError::bad_input(anyhow!("--width/--height: {p}")));
    }
    if args.frames == 0 {
        return Err(CliError::bad_input(anyhow!("--frames must be at least 1")));
    }
    if !(args.diff_gain.is_finite() && args.diff_gain > 0.0 && args.exposure.is_finite()) {
        return Err(CliError::bad_input(anyhow!(
            "--diff-gain must be positive and --exposure finite"
        )));
    }
    let scenes = if args.scene.is_empty() {
        default_scenes()
    } else {
        args.scene.clone()
    };
    let mut names: Vec<String> = scenes.iter().map(|s| stem(s)).collect();
    names.sort();
    names.dedup();
    if names.len() != scenes.len() {
        return Err(CliError::bad_input(anyhow!(
            "--scene: two scenes share a file name; their images would overwrite each other"
        )));
    }
    Ok(scenes)
}

/// What every scene's renders share, read and prepared once: the pack, its file size
/// and table-space errors, and the three materials rendered.
struct Inputs {
    pack: Arc<SpmmMaterial>,
    pack_bytes: u64,
    table: TableErrors,
    /// The BTF as the renderer shades it: the reference render's material.
    shaded: Arc<BtfTable>,
    /// The pack at the BTF's pairs, shown as a BTF: the third render's material.
    tabulated: Arc<BtfTable>,
}

/// Reads the pack, measures it against the BTF read in blocks, and opens the BTF and
/// the pack's tabulation as tables within `--max-memory`.
fn read_inputs(args: &FitReportArgs) -> Result<Inputs, CliError> {
    let max_memory = meso_fit::memory::parse_bytes(&args.max_memory)
        .map_err(|e| CliError::bad_input(anyhow!("--max-memory {e}")))?;
    let disk = OnDiskBtf::open(&args.btf).map_err(CliError::bad_input)?;
    let pack = Arc::new(read_pack(&args.pack).map_err(CliError::bad_input)?);
    let pack_bytes = std::fs::metadata(&args.pack)
        .failure_ctx(|| format!("reading `{}`", args.pack.display()))?
        .len();
    let texel_bytes = disk.pairs() as u64 * 3 * 4;
    let block = max_memory / 2 / texel_bytes;
    if block == 0 {
        return Err(CliError::bad_input(anyhow!(
            "--max-memory {max_memory} bytes: half of it cannot hold one texel of `{}` ({texel_bytes} bytes of values)",
            args.btf.display()
        )));
    }
    let table = table_errors(&disk, &pack, block as usize)
        .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", args.pack.display())))?;
    let half = MemoryBound::new(max_memory / 2);
    let shaded = Arc::new(BtfTable::open(&args.btf, half).map_err(CliError::bad_input)?);
    // The pack at the BTF's pairs, shown as a BTF: the third render's material.
    let tabulation = PackTabulation::new(&disk, Arc::clone(&pack))
        .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", args.pack.display())))?;
    let tabulated = Arc::new(
        BtfTable::from_source(Box::new(tabulation), half).map_err(|e| {
            let message = anyhow!("the pack tabulated at the BTF's pairs: {e}");
            match e {
                // A bound too small is the user's to raise.
                SourceError::Memory(_) => CliError::bad_input(anyhow!("--max-memory: {message}")),
                _ => CliError::failure(message),
            }
        })?,
    );
    Ok(Inputs {
        pack,
        pack_bytes,
        table,
        shaded,
        tabulated,
    })
}

/// Renders one scene three ways, writes its EXRs and side-by-side PNGs, and returns
/// its report row with its image errors (BTF against pack, and the fit's part alone).
fn report_scene(
    args: &FitReportArgs,
    path: &Path,
    inputs: &Inputs,
    request: &RenderRequest,
) -> Result<(serde_json::Value, ImageErrors, ImageErrors), CliError> {
    let out = |name: &str| args.output.join(name);
    let scene = load_scene(path).map_err(CliError::bad_input)?;
    let name = stem(path);
    let r = render_all(
        &scene,
        Arc::clone(&inputs.shaded),
        Arc::clone(&inputs.pack),
        Arc::clone(&inputs.tabulated),
        request,
    )
    .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", path.display())))?;
    // A block that could not be read shaded 0: the renders are wrong, say why.
    if let Some(e) = [&inputs.shaded, &inputs.tabulated]
        .iter()
        .find_map(|t| t.read_error())
    {
        return Err(CliError::failure(anyhow!(
            "rendering `{}`: {e}",
            path.display()
        )));
    }
    let e = image_errors(&r.btf, &r.pack).map_err(CliError::failure)?;
    let fit = image_errors(&r.btf, &r.tabulated).map_err(CliError::failure)?;
    let interpolation = image_errors(&r.tabulated, &r.pack).map_err(CliError::failure)?;
    let files = [
        "btf.exr",
        "pack.exr",
        "tabulated.exr",
        "side_by_side.png",
        "fit_side_by_side.png",
    ]
    .map(|suffix| format!("{name}_{suffix}"));
    let [btf_exr, pack_exr, tab_exr, panels, fit_panels] = &files;
    for (file, image) in [
        (btf_exr, &r.btf),
        (pack_exr, &r.pack),
        (tab_exr, &r.tabulated),
    ] {
        write_exr(&out(file), image).failure_ctx(|| format!("writing `{file}`"))?;
    }
    for (file, (a, b)) in [
        (panels, (&r.btf, &r.pack)),
        (fit_panels, (&r.btf, &r.tabulated)),
    ] {
        write_image(
            &out(file),
            &side_by_side(a, b, args.diff_gain),
            args.exposure,
        )
        .failure_ctx(|| format!("writing `{file}`"))?;
    }
    let row = json!({
        "scene": path.display().to_string(),
        "btf_image": btf_exr,
        "pack_image": pack_exr,
        "tabulated_image": tab_exr,
        "side_by_side": panels,
        "fit_side_by_side": fit_panels,
        "image_relative_rmse": e.relative_rmse,
        "image_rmse": e.rmse,
        "image_psnr_db": e.psnr_db,
        "image_mssim": e.mssim,
        "fit_image_relative_rmse": fit.relative_rmse,
        "fit_image_rmse": fit.rmse,
        "fit_image_mssim": fit.mssim,
        "interpolation_image_relative_rmse": interpolation.relative_rmse,
        "interpolation_image_rmse": interpolation.rmse,
        "interpolation_image_mssim": interpolation.mssim,
    });
    Ok((row, e, fit))
}

/// The text report: the pack, its table-space errors, then a line per scene.
fn print_summary(args: &FitReportArgs, inputs: &Inputs, rows: &[serde_json::Value]) {
    let (pack_bytes, table) = (inputs.pack_bytes, &inputs.table);
    println!("pack         {} ({pack_bytes} bytes)", args.pack.display());
    println!(
        "table        relative RMSE {:.2}% (grazing {:.2}%, elsewhere {:.2}%, basis sum alone {:.2}%)",
        100.0 * table.relative_rmse,
        100.0 * table.grazing_relative_rmse,
        100.0 * table.elsewhere_relative_rmse,
        100.0 * table.basis_relative_rmse
    );
    let number = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap_or(f64::NAN);
    for r in rows {
        println!(
            "{:<12} relative RMSE {:.2}%  PSNR {}  MSSIM {:.4}  (fit {:.2}%, MSSIM {:.4}; interpolation {:.2}%, MSSIM {:.4})",
            stem(Path::new(r["scene"].as_str().unwrap_or("scene"))),
            100.0 * number(r, "image_relative_rmse"),
            r["image_psnr_db"]
                .as_f64()
                .map_or("inf".into(), |p| format!("{p:.2} dB")),
            number(r, "image_mssim"),
            100.0 * number(r, "fit_image_relative_rmse"),
            number(r, "fit_image_mssim"),
            100.0 * number(r, "interpolation_image_relative_rmse"),
            number(r, "interpolation_image_mssim"),
        );
    }
    println!("wrote {}", args.output.display());
}

/// The worse of two scenes' errors: largest RMSE, smallest PSNR and MSSIM.
fn worse(w: Option<ImageErrors>, e: ImageErrors) -> ImageErrors {
    let Some(w) = w else { return e };
    ImageErrors {
        relative_rmse: w.relative_rmse.max(e.relative_rmse),
        rmse: w.rmse.max(e.rmse),
        psnr_db: match (w.psnr_db, e.psnr_db) {
            (Some(x), Some(y)) => Some(x.min(y)),
            (x, y) => x.or(y),
        },
        mssim: w.mssim.min(e.mssim),
    }
}
