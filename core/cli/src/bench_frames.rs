//! `meso bench frames SCENE [--size 512] [--frames 8] [--devices cpu,gpu] [--json]`:
//! the spmm mode's frame time on each device side by side in one process, for the
//! scene as it is, with ambient occlusion off, with the SPMM residual off, and as the
//! viewport renders it while the camera moves (where the scene has AO or a residual). Per run: preparation seconds, milliseconds per frame (the
//! mean of `--frames` frames after one warm-up frame), rays per second, and the
//! edit-to-frame time of a light-colour edit along the viewport's path: apply, one
//! frame, the resolved image (on the GPU left on the device, through the device's
//! denoiser while the studio would blend it in, until the device has made it), and,
//! for comparison, the same with the image read back to the host. A device without an
//! adapter is reported, not fatal.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::anyhow;
use clap::Args;
use meso_render::scene::{Material, Scene, load_scene};
use meso_render::{Device, ModeKind, Prepare, SceneEdit, run_frames};
use serde_json::json;

use crate::failure::{CliError, ResultExt};
use meso_render::RenderModeExt;

#[derive(Args, Debug)]
pub struct FramesArgs {
    scene: PathBuf,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512)]
    size: u32,
    /// Frames timed per run (after one warm-up frame).
    #[arg(long, default_value_t = 8)]
    frames: u32,
    /// Devices, comma-separated.
    #[arg(long, default_value = "cpu,gpu")]
    devices: String,
    #[arg(long)]
    json: bool,
}

/// A measured variant of the scene: its name, the scene, and whether the moving flag
/// is on (the residual cut to `MOVING_NPCA` components, docs/rendering.md).
type Variant = (&'static str, Scene, bool);

/// The variants of the scene that are measured: as it is, AO off, residual off, moving.
fn variants(scene: &Scene) -> Vec<Variant> {
    let mut out = vec![("as_is", scene.clone(), false)];
    if scene.ambient.is_some() {
        let mut s = scene.clone();
        s.ambient = None;
        out.push(("ao_off", s, false));
    }
    let has_residual = scene.materials.iter().any(|m| {
        matches!(m, Material::Spmm { material, residual: true, .. } if material.residual().is_some())
    });
    if has_residual {
        let mut s = scene.clone();
        for m in &mut s.materials {
            if let Material::Spmm { residual, .. } = m {
                *residual = false;
            }
        }
        out.push(("residual_off", s, false));
        out.push(("moving", scene.clone(), true));
    }
    out
}

fn measure(
    device: Device,
    scene: Scene,
    moving: bool,
    size: u32,
    frames: u32,
) -> Result<serde_json::Value, String> {
    let start = Instant::now();
    let mut mode = meso_modes::create(
        ModeKind::Spmm,
        device,
        scene,
        size,
        size,
        Prepare::quietly(),
    )
    .map_err(|e| e.to_string())?;
    let prepare_s = start.elapsed().as_secs_f64();
    if moving {
        mode.apply(SceneEdit::Moving(true))
            .map_err(|e| e.to_string())?;
    }
    run_frames(mode.as_mut(), 1, |_, _| {});
    let run = run_frames(mode.as_mut(), frames, |_, _| {});
    let rays = run.counters.rays.total();
    // A light-colour edit keeps every sample: its cost is the next frame and image.
    let mut edit = |read_back: bool| {
        let light = mode.scene().lights.first().copied()?;
        let light = light.with_emission(light.emission() * 1.01);
        let start = Instant::now();
        let _ = mode.apply(SceneEdit::Light { index: 0, light });
        mode.render_frame();
        viewport_picture(mode.as_ref(), read_back);
        Some(start.elapsed().as_secs_f64() * 1e3)
    };
    // Untimed first: the device's denoiser and guides kernels are made on first use.
    edit(false);
    let (edit_ms, edit_read_back_ms) = (edit(false), edit(true));
    if let Some(e) = mode.failure() {
        return Err(e.to_string());
    }
    Ok(json!({
        "adapter": mode.diagnostics().adapter(),
        "prepare_seconds": prepare_s,
        "ms_per_frame": run.seconds * 1e3 / f64::from(frames),
        "rays_per_second": rays as f64 / run.seconds.max(1e-12),
        "edit_to_frame_ms": edit_ms,
        "edit_to_host_image_ms": edit_read_back_ms,
        "traversal_overflows": mode.diagnostics().traversal_overflows(),
        "device_bytes": mode.diagnostics().device_memory()
            .into_iter()
            .map(|(k, v)| (k.to_string(), json!(v)))
            .collect::<serde_json::Map<String, serde_json::Value>>(),
    }))
}

/// The picture the viewport shows of `mode`'s last frame, made as the render thread
/// makes it (`meso_viewport::worker`): on a GPU mode's device, blended through the
/// device's denoiser while the studio's fade is above zero, and waited for; on the
/// host (or with `read_back`), the image read back.
fn viewport_picture(mode: &dyn meso_render::RenderMode, read_back: bool) {
    let Some(image) = mode.image_on_device().filter(|_| !read_back) else {
        let _ = mode.image();
        return;
    };
    let picture = meso_render::denoise::viewport_filter(mode.progress().min_samples)
        .and_then(|(denoiser, strength)| {
            mode.denoised_on_device(image.as_ref(), &denoiser, strength)
        })
        .unwrap_or(image);
    let _ = picture.wait();
}

pub fn run(args: &FramesArgs) -> Result<(), CliError> {
    if !(1..=8192).contains(&args.size) {
        return Err(CliError::bad_input(anyhow!(
            "--size {} is outside [1, 8192]",
            args.size
        )));
    }
    if args.frames == 0 {
        return Err(CliError::bad_input(anyhow!("--frames must be at least 1")));
    }
    let devices = args
        .devices
        .split(',')
        .map(|d| {
            Device::from_name(d.trim()).ok_or_else(|| {
                CliError::bad_input(anyhow!("--devices: `{d}`: devices are cpu, gpu"))
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let scene = load_scene(&args.scene).bad_input_ctx(|| format!("`{}`", args.scene.display()))?;
    let mut runs = Vec::new();
    for (variant, s, moving) in variants(&scene) {
        for &device in &devices {
            let result = measure(device, s.clone(), moving, args.size, args.frames);
            if !args.json {
                match &result {
                    Ok(v) => println!(
                        "{variant:<13} {:<4} {:>9.1} ms/frame {:>7.2} Mrays/s  edit-to-frame {} ms (read back: {} ms){}",
                        device.name(),
                        v["ms_per_frame"].as_f64().unwrap_or(f64::NAN),
                        v["rays_per_second"].as_f64().unwrap_or(f64::NAN) / 1e6,
                        v["edit_to_frame_ms"]
                            .as_f64()
                            .map_or("-".into(), |m| format!("{m:.1}")),
                        v["edit_to_host_image_ms"]
                            .as_f64()
                            .map_or("-".into(), |m| format!("{m:.1}")),
                        v["adapter"]
                            .as_str()
                            .map_or(String::new(), |a| format!("  ({a})")),
                    ),
                    Err(e) => println!("{variant:<13} {:<4} not measured: {e}", device.name()),
                }
            }
            runs.push(match result {
                Ok(mut v) => {
                    v["variant"] = json!(variant);
                    v["device"] = json!(device.name());
                    v
                }
                Err(e) => json!({"variant": variant, "device": device.name(), "error": e}),
            });
        }
    }
    if args.json {
        return crate::print_json(&json!({
            "scene": args.scene.display().to_string(),
            "size": args.size,
            "frames": args.frames,
            "runs": runs,
        }));
    }
    Ok(())
}
