//! `meso report convergence SCENE -o DIR [--mode M --device D]`: the speed-against-error
//! report of a render mode (`modes::convergence`): convergence.csv (one row per variant
//! and checkpoint), convergence.json (with per-variant summaries), two SVG charts
//! (RMSE and MSSIM against render time) and the converged reference as EXR and PNG.

use std::fmt::Write as _;
use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::anyhow;
use clap::{Args, Subcommand};
use meso_materials::atomic::write_bytes_atomic;
use meso_render::scene::{RenderSettings, load_scene};
use meso_reports::convergence::{ConvergenceReport, ConvergenceRequest, convergence_report};

use crate::failure::{CliError, ResultExt};
use crate::mode_args::ModeArgs;
use crate::svg_chart::{Chart, Series, render};

#[derive(Subcommand, Debug)]
pub enum ReportCommand {
    /// Error against a converged reference after 1, 2, 4, ... frames, with time.
    Convergence(ConvergenceArgs),
    /// The adaptive mode against the spmm brute force: speed-up at equal PSNR, the
    /// bandwidth pass, n_b 16 against 256, the pre-convolved variant.
    Adaptive(AdaptiveArgs),
    /// A fitted pack against its BTF: table-space error and the same scenes rendered
    /// with each (image RMSE, PSNR, MSSIM, side-by-side images).
    Fit(crate::report_fit_cmd::FitReportArgs),
}

#[derive(Args, Debug)]
pub struct AdaptiveArgs {
    /// The scene file.
    scene: PathBuf,
    /// Output folder (created if missing).
    #[arg(short = 'o', long)]
    output: PathBuf,
    #[arg(long, default_value_t = 128)]
    width: u32,
    #[arg(long, default_value_t = 128)]
    height: u32,
    /// Frames of the converged spmm reference.
    #[arg(long, default_value_t = 2048)]
    reference_frames: u32,
    /// Last checkpoint of the brute force.
    #[arg(long, default_value_t = 256)]
    spmm_frames: u32,
    /// Last checkpoint of the adaptive variants.
    #[arg(long, default_value_t = 64)]
    adaptive_frames: u32,
    /// Frames between two refinements of the adaptive mode's levels.
    #[arg(long)]
    refine_frames: Option<u32>,
    /// Mean samples per shaded pixel per frame of the adaptive mode.
    #[arg(long)]
    mean_samples: Option<f64>,
    /// Sample the environment map whole with one sampler, as the spmm mode does,
    /// instead of its peaks and its remainder each with its own (the split's baseline).
    #[arg(long)]
    whole_environment: bool,
    /// Runs of each curve; each checkpoint keeps its shortest time (the images are the
    /// same in every run), so a busy machine disturbs the figures less.
    #[arg(long, default_value_t = 1)]
    repeats: u32,
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
pub struct ConvergenceArgs {
    /// The scene file.
    scene: PathBuf,
    /// Output folder (created if missing).
    #[arg(short = 'o', long)]
    output: PathBuf,
    #[arg(long, default_value_t = 256)]
    width: u32,
    #[arg(long, default_value_t = 256)]
    height: u32,
    /// Frames of the converged references.
    #[arg(long, default_value_t = 2048)]
    reference_frames: u32,
    /// Last checkpoint (a power of two).
    #[arg(long, default_value_t = 256)]
    max_frames: u32,
    #[command(flatten)]
    mode: ModeArgs,
    #[arg(long)]
    json: bool,
}

pub fn run(command: ReportCommand) -> Result<(), CliError> {
    match command {
        ReportCommand::Convergence(args) => convergence(&args),
        ReportCommand::Adaptive(args) => adaptive(&args),
        ReportCommand::Fit(args) => crate::report_fit_cmd::run(&args),
    }
}

fn adaptive(args: &AdaptiveArgs) -> Result<(), CliError> {
    use meso_reports::adaptive::{SpeedupRequest, speedup_report};
    let scene = load_scene(&args.scene).map_err(CliError::bad_input)?;
    if let Some(p) = RenderSettings::size_problem(args.width, args.height) {
        return Err(CliError::bad_input(anyhow!("--width/--height: {p}")));
    }
    if args
        .mean_samples
        .is_some_and(|m| !(m.is_finite() && m >= 1.0))
    {
        return Err(CliError::bad_input(anyhow!(
            "--mean-samples must be finite and at least 1"
        )));
    }
    for (name, v) in [
        ("--refine-frames", args.refine_frames.unwrap_or(1)),
        ("--reference-frames", args.reference_frames),
        ("--spmm-frames", args.spmm_frames),
        ("--adaptive-frames", args.adaptive_frames),
        ("--repeats", args.repeats),
    ] {
        if v == 0 {
            return Err(CliError::bad_input(anyhow!("{name} must be at least 1")));
        }
    }
    std::fs::create_dir_all(&args.output)
        .failure_ctx(|| format!("creating `{}`", args.output.display()))?;
    let verbose = std::io::stderr().is_terminal() && !args.json;
    let report = speedup_report(
        &scene,
        &SpeedupRequest {
            width: args.width,
            height: args.height,
            reference_frames: args.reference_frames,
            spmm_frames: args.spmm_frames,
            adaptive_frames: args.adaptive_frames,
            repeats: args.repeats,
            options: {
                let d = meso_modes::adaptive::AdaptiveOptions::default();
                meso_modes::adaptive::AdaptiveOptions {
                    refine_frames: args.refine_frames.unwrap_or(d.refine_frames),
                    mean_samples: args.mean_samples.unwrap_or(d.mean_samples),
                    split_environment: !args.whole_environment,
                    ..d
                }
            },
        },
        |m| {
            if verbose {
                eprintln!("{m}");
            }
        },
    )
    .map_err(CliError::failure)?;
    let out = |name: &str| args.output.join(name);
    let mut csv = String::from("curve,frames,seconds,samples,psnr_db,rmse,speedup\n");
    for c in &report.curves {
        for k in &c.checkpoints {
            let _ = writeln!(
                csv,
                "{},{},{:.6},{},{:.3},{:.6e},{}",
                c.name,
                k.frames,
                k.seconds,
                k.samples,
                k.psnr_db,
                k.rmse,
                k.speedup.map_or(String::new(), |s| format!("{s:.3}"))
            );
        }
    }
    write_bytes_atomic(&out("adaptive.csv"), csv.as_bytes())
        .failure_ctx(|| format!("writing `{}`", out("adaptive.csv").display()))?;
    let json = serde_json::to_string_pretty(&report)
        .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
    write_bytes_atomic(&out("adaptive.json"), json.as_bytes())
        .failure_ctx(|| format!("writing `{}`", out("adaptive.json").display()))?;
    meso_materials::image::write_image(&out("reference.png"), &report.reference, 0.0)
        .failure_ctx(|| format!("writing `{}`", out("reference.png").display()))?;
    if args.json {
        let value = serde_json::to_value(&report)
            .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
        return crate::print_json(&value);
    }
    println!(
        "{:<16} {:>7} {:>10} {:>9} {:>9} {:>12}",
        "curve", "frames", "seconds", "PSNR dB", "speed-up", "pass (ms)"
    );
    for c in &report.curves {
        for k in &c.checkpoints {
            println!(
                "{:<16} {:>7} {:>10.3} {:>9.2} {:>9} {:>12}",
                c.name,
                k.frames,
                k.seconds,
                k.psnr_db,
                k.speedup.map_or("-".into(), |s| format!("{s:.2}x")),
                c.bandwidth_pass_seconds
                    .map_or("-".into(), |s| format!("{:.1}", s * 1e3))
            );
        }
    }
    let a = &report.allocation;
    println!(
        "allocation gain at equal samples ({} spp measured): oracle {:.2}x (scored on a second measurement {:.2}x), eq. 9 bound {:.2}x, sqrt(eq. 9) {:.2}x, predicted sigma {:.2}x",
        a.samples_per_pixel, a.oracle, a.oracle_held_out, a.eq9_bound, a.eq9_sqrt, a.predicted
    );
    println!("wrote {}", args.output.display());
    Ok(())
}

fn convergence(args: &ConvergenceArgs) -> Result<(), CliError> {
    let scene = load_scene(&args.scene).map_err(CliError::bad_input)?;
    if let Some(p) = RenderSettings::size_problem(args.width, args.height) {
        return Err(CliError::bad_input(anyhow!("--width/--height: {p}")));
    }
    let (mode, device) = args.mode.resolve(&scene)?;
    if args.max_frames == 0 || args.max_frames > args.reference_frames {
        return Err(CliError::bad_input(anyhow!(
            "--max-frames {} must be at least 1 and at most --reference-frames {}",
            args.max_frames,
            args.reference_frames
        )));
    }
    std::fs::create_dir_all(&args.output)
        .failure_ctx(|| format!("creating `{}`", args.output.display()))?;
    let request = ConvergenceRequest {
        width: args.width,
        height: args.height,
        reference_frames: args.reference_frames,
        max_frames: args.max_frames,
        mode,
        device,
    };
    let verbose = std::io::stderr().is_terminal() && !args.json;
    let report = convergence_report(&scene, &request, |m| {
        if verbose {
            eprintln!("{m}");
        }
    })
    .map_err(CliError::failure)?;
    write_outputs(args, &report)?;
    if args.json {
        let value = serde_json::to_value(&report)
            .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
        return crate::print_json(&value);
    }
    println!(
        "{:<14} {:>10} {:>9} {:>14} {:>12} {:>10}",
        "variant", "reference", "ms/frame", "frames->0.98", "s->0.98", "final RMSE"
    );
    for s in &report.summaries {
        println!(
            "{:<14} {:>10} {:>9.2} {:>14} {:>12} {:>10.3e}",
            s.variant,
            s.reference,
            s.ms_per_frame,
            s.frames_to_mssim_098
                .map_or("never".into(), |f| f.to_string()),
            s.seconds_to_mssim_098
                .map_or("-".into(), |t| format!("{t:.3}")),
            s.final_rmse
        );
    }
    for n in &report.notes {
        println!("note: {n}");
    }
    println!("wrote {}", args.output.display());
    Ok(())
}

fn write_outputs(args: &ConvergenceArgs, report: &ConvergenceReport) -> Result<(), CliError> {
    let out = |name: &str| args.output.join(name);
    let write = |name: &str, bytes: &[u8]| {
        write_bytes_atomic(&out(name), bytes)
            .failure_ctx(|| format!("writing `{}`", out(name).display()))
    };
    let mut csv = String::from("variant,reference,frames,seconds,rmse,psnr_db,mssim\n");
    for c in &report.checkpoints {
        let _ = writeln!(
            csv,
            "{},{},{},{:.6},{:.6e},{:.3},{:.6}",
            c.variant, c.reference, c.frames, c.seconds, c.rmse, c.psnr_db, c.mssim
        );
    }
    write("convergence.csv", csv.as_bytes())?;
    let json = serde_json::to_string_pretty(report)
        .map_err(|e| CliError::failure(anyhow!("cannot encode the report: {e}")))?;
    write("convergence.json", json.as_bytes())?;
    let series = |metric: fn(&meso_reports::convergence::Checkpoint) -> f64| -> Vec<Series> {
        report
            .summaries
            .iter()
            .map(|s| Series {
                name: format!("{} (vs {})", s.variant, s.reference),
                points: report
                    .checkpoints
                    .iter()
                    .filter(|c| c.variant == s.variant)
                    .map(|c| (c.seconds, metric(c)))
                    .collect(),
            })
            .collect()
    };
    let title = format!(
        "{} at {}x{}: error against {} reference frames",
        args.scene
            .file_name()
            .map_or("scene".into(), |n| n.to_string_lossy()),
        report.width,
        report.height,
        report.reference_frames
    );
    let rmse = render(
        &Chart {
            title: &title,
            x_label: "render time (s)",
            y_label: "RMSE (linear radiance)",
            log_x: true,
            log_y: true,
        },
        &series(|c| c.rmse),
    );
    write("convergence_rmse.svg", rmse.as_bytes())?;
    let mssim = render(
        &Chart {
            title: &title,
            x_label: "render time (s)",
            y_label: "1 - MSSIM",
            log_x: true,
            log_y: true,
        },
        &series(|c| (1.0 - c.mssim).max(1e-6)),
    );
    write("convergence_mssim.svg", mssim.as_bytes())?;
    meso_materials::image::write_image(&out("reference.exr"), &report.reference, 0.0)
        .failure_ctx(|| format!("writing `{}`", out("reference.exr").display()))?;
    meso_materials::image::write_image(&out("reference.png"), &report.reference, 0.0)
        .failure_ctx(|| format!("writing `{}`", out("reference.png").display()))?;
    Ok(())
}
