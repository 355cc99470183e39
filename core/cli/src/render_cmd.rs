//! `meso render SCENE -o OUT.exr|OUT.png`: a progressive render of a scene file through
//! a render mode (docs/cli.md: `--mode`, `--device`; `--light-samples` overrides the
//! scene's); `--json` reports time, frames,
//! the mode and device, its counters (samples, shading points, rays by kind), rays
//! per second, the preparation's stages, the film's bytes and dropped non-finite
//! samples. `--max-memory` bounds the scene's `btf` materials' values held in memory
//! (an equal share each): a larger BTF is shaded from blocks read from its file
//! through a bounded cache.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::anyhow;
use clap::Args;
use meso_materials::btf::table::{DEFAULT_MAX_MEMORY, MemoryBound};
use meso_render::scene::{Material, RenderSettings, load_scene_within};
use meso_render::{Denoiser, Pass, Prepare, run_frames};
use serde_json::json;

use crate::failure::{CliError, ResultExt};
use crate::mode_args::{ModeArgs, mode_error};

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// The scene file (docs/scenes.md).
    scene: PathBuf,
    /// Output image: .exr (linear radiance) or .png (sRGB after exposure).
    #[arg(short = 'o', long)]
    output: PathBuf,
    /// Frames to accumulate (one sample per pixel each); default: the scene's.
    #[arg(long)]
    frames: Option<u32>,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    /// Samples per pixel in each frame.
    #[arg(long, default_value_t = 1)]
    spp_per_frame: u32,
    /// Points on each area light per frame in the spmm mode (1..=64); default: the
    /// scene's `[render] light_samples`.
    #[arg(long)]
    light_samples: Option<u32>,
    /// Exposure in stops for PNG output.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f64,
    #[command(flatten)]
    mode: ModeArgs,
    /// Filter the final image with the viewport denoiser (edge-avoiding a-trous, guided
    /// by normal, depth and albedo). Off by default: the image is the estimate itself.
    #[arg(long)]
    denoise: bool,
    /// Most bytes of the scene's `btf` materials' values held in memory (`256MB`,
    /// `4GB`; powers of 1024), an equal share each: a BTF within its share is held
    /// whole, a larger one is read from its file as it is shaded, through a cache of
    /// that size (CPU modes; the GPU refuses
    /// it). Images are the same either way.
    #[arg(long, default_value_t = default_max_memory())]
    max_memory: String,
    #[arg(long)]
    json: bool,
}

fn default_max_memory() -> String {
    format!("{}GB", DEFAULT_MAX_MEMORY >> 30)
}

pub fn run(args: &RenderArgs) -> Result<(), CliError> {
    let max_memory = meso_fit::memory::parse_bytes(&args.max_memory)
        .map_err(|e| CliError::bad_input(anyhow!("--max-memory {e}")))?;
    let mut scene = load_scene_within(&args.scene, MemoryBound::new(max_memory))
        .map_err(CliError::bad_input)?;
    // Out-of-core tables, to check after rendering that every block could be read.
    let on_disk: Vec<_> = scene
        .materials
        .iter()
        .filter_map(|m| match m {
            Material::Btf { table, .. } if !table.is_resident() => Some(table.clone()),
            _ => None,
        })
        .collect();
    if let Some(n) = args.light_samples {
        if let Some(p) = RenderSettings::light_samples_problem(n) {
            return Err(CliError::bad_input(anyhow!("--light-samples: {p}")));
        }
        scene.render.light_samples = n;
    }
    let light_samples = scene.render.light_samples;
    let frames = args.frames.unwrap_or(scene.render.frames);
    let width = args.width.unwrap_or(scene.render.width);
    let height = args.height.unwrap_or(scene.render.height);
    if frames == 0 {
        return Err(CliError::bad_input(anyhow!("--frames must be at least 1")));
    }
    if let Some(p) = RenderSettings::size_problem(width, height) {
        return Err(CliError::bad_input(anyhow!("--width/--height: {p}")));
    }
    let (kind, device) = args.mode.resolve(&scene)?;
    if !(1..=65536).contains(&args.spp_per_frame) {
        return Err(CliError::bad_input(anyhow!(
            "--spp-per-frame {} is outside [1, 65536]",
            args.spp_per_frame
        )));
    }
    if !args.exposure.is_finite() {
        return Err(CliError::bad_input(anyhow!(
            "--exposure {} is not finite",
            args.exposure
        )));
    }
    let start = Instant::now();
    let progress = std::io::stderr().is_terminal() && !args.json;
    let show = |stage: &str, fraction: f32| {
        if progress {
            eprint!("\rpreparing: {stage} {:3.0}%   ", fraction * 100.0);
        }
    };
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let mut mode = meso_modes::create(
        kind,
        device,
        scene,
        width,
        height,
        Prepare::new(&show, &cancel),
    )
    .map_err(mode_error)?;
    mode.set_samples_per_frame(args.spp_per_frame);
    let preparation = mode.diagnostics().preparation();
    if progress {
        eprintln!();
    }
    let run = run_frames(mode.as_mut(), frames, |done, _| {
        if progress {
            eprint!("\rrendering: frame {done}/{frames}");
        }
    });
    if progress {
        eprintln!();
    }
    // A device that failed mid-run (a GPU lost) leaves a partial image: no output.
    if let Some(e) = mode.failure() {
        return Err(CliError::failure(anyhow!(e)));
    }
    // A BTF file changed or damaged after it was opened shaded 0 where unreadable.
    if let Some(e) = on_disk.iter().find_map(|t| t.read_error()) {
        return Err(CliError::failure(anyhow!(
            "a btf material's file could not be read while rendering: {e}"
        )));
    }
    let counters = run.counters;
    let rays = counters.rays;
    let trace_s = run.seconds;
    let mut image = mode.image();
    if args.denoise {
        let guides = mode.guides(Pass::Frame).ok_or_else(|| {
            CliError::bad_input(anyhow!(
                "--denoise: the {} mode has no denoiser guides",
                mode.kind().name()
            ))
        })?;
        image = Denoiser::for_samples(mode.progress().min_samples)
            .apply(&image, &guides)
            .ok_or_else(|| {
                CliError::failure(anyhow!("--denoise: the guides do not match the image"))
            })?;
    }
    let dropped = mode.progress().dropped;
    meso_materials::image::write_image(&args.output, &image, args.exposure)
        .failure_ctx(|| format!("writing `{}`", args.output.display()))?;
    let total_s = start.elapsed().as_secs_f64();
    let rays_per_s = rays.total() as f64 / trace_s.max(1e-9);
    if args.json {
        return crate::print_json(&json!({
            "scene": args.scene.display().to_string(),
            "output": args.output.display().to_string(),
            "width": width,
            "height": height,
            "frames": frames,
            "mode": mode.kind().name(),
            "device": mode.device().name(),
            "spp_per_frame": args.spp_per_frame,
            "light_samples": light_samples,
            "samples_per_pixel": mode.progress().min_samples,
            "seconds": total_s,
            "trace_seconds": trace_s,
            "bvh_build_ms": preparation.seconds("bvh").map(|s| s * 1e3),
            "preparation": preparation,
            "samples": counters.samples,
            "shading_points": counters.shading_points,
            "rays": rays,
            "rays_total": rays.total(),
            "rays_per_second": rays_per_s,
            "nonfinite_dropped": dropped,
            "film_bytes": mode.progress().film_bytes,
            "material_bytes_resident": mode.diagnostics().material_bytes().map(|b| b.resident),
            "material_bytes_full": mode.diagnostics().material_bytes().map(|b| b.full),
            "ms_per_frame": trace_s * 1e3 / f64::from(frames),
            "adapter": mode.diagnostics().adapter(),
            "device_bytes": mode.diagnostics().device_memory()
                .into_iter()
                .map(|(kind, bytes)| (kind.to_string(), json!(bytes)))
                .collect::<serde_json::Map<String, serde_json::Value>>(),
            "traversal_overflows": mode.diagnostics().traversal_overflows(),
            "denoised": args.denoise,
            "btf_out_of_core": on_disk.len(),
            "btf_blocks_read": on_disk.iter().filter_map(|t| t.cache()).map(|c| c.reads()).sum::<u64>(),
        }));
    }
    println!(
        "wrote {} ({width}x{height}, {frames} frames) in {total_s:.2} s: {} rays ({:.2} M/s), {} non-finite samples dropped",
        args.output.display(),
        rays.total(),
        rays_per_s / 1e6,
        dropped
    );
    Ok(())
}
