//! `meso bench stroke SCENE [--size 256] [--strokes 24] [--warm-frames 4] [--json]`:
//! stroke-to-updated-frame latency of the weight brush on the spmm mode. The scene's
//! first SPMM material is warmed up for `--warm-frames` frames at `size` x `size`;
//! then each stroke step is timed from the pointer event to the finished image: one
//! dab (picking, a disc of 2 texels), the pack edit of the whole stroke so far
//! (`with_weight_scale` within the stroke's mask, as the studio does), the mode's
//! `apply` (which restarts only the pixels whose shading reached a changed texel),
//! one frame and the resolved image. The frame after an edit traces only the pixels
//! the edit restarted (`SpmmMode::set_restarted_first`); the same steps run side by
//! side, interleaved, on a second mode whose next frame is a whole frame (the
//! behaviour before), reported as `whole_frame_ms`. The dabs walk along the middle
//! row of pixels that see the material. Reported: per part and in all, median and
//! largest, and the pixels restarted per step against the pixels that shaded the
//! material (what a whole-material restart would have cost).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::anyhow;
use clap::Args;
use glam::DVec2;
use meso_materials::spmm::{Falloff, TexelMask, WeightTarget};
use meso_modes::trace::SpmmMode;
use meso_render::geometry::brush::{self, Brush, BrushUnits};
use meso_render::geometry::{SceneBvh, pick};
use meso_render::scene::{Material, Scene, load_scene};
use meso_render::{Invalidation, RenderMode, SceneEdit};
use serde_json::json;

use crate::failure::{CliError, ResultExt};
use meso_render::RenderModeExt;

#[derive(Args, Debug)]
pub struct StrokeArgs {
    scene: PathBuf,
    /// Image side in pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Stroke steps timed.
    #[arg(long, default_value_t = 24)]
    strokes: usize,
    /// Frames rendered before the stroke.
    #[arg(long, default_value_t = 4)]
    warm_frames: u32,
    #[arg(long)]
    json: bool,
}

fn stats(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], *v.last().unwrap_or(&0.0))
}

pub fn run(args: &StrokeArgs) -> Result<(), CliError> {
    if !(16..=4096).contains(&args.size) || args.strokes == 0 {
        return Err(CliError::bad_input(anyhow!(
            "--size must lie in [16, 4096] and --strokes be at least 1"
        )));
    }
    let scene = load_scene(&args.scene).bad_input_ctx(|| format!("`{}`", args.scene.display()))?;
    let index = scene
        .materials
        .iter()
        .position(|m| matches!(m, Material::Spmm { .. }))
        .ok_or_else(|| {
            CliError::bad_input(anyhow!("`{}` has no SPMM material", args.scene.display()))
        })?;
    let Material::Spmm {
        material: original,
        uv_scale,
        residual,
        npca,
    } = scene.materials[index].clone()
    else {
        unreachable!("found above");
    };
    let n = args.size;
    let mut mode = SpmmMode::new(scene.clone(), n, n).map_err(CliError::bad_input)?;
    let mut whole = SpmmMode::new(scene.clone(), n, n).map_err(CliError::bad_input)?;
    whole.set_restarted_first(false);
    for _ in 0..args.warm_frames {
        mode.render_frame();
        whole.render_frame();
    }
    // Pixels of the middle rows that see the material: where the stroke walks.
    let sees = |&(x, y): &(u32, u32)| sees_material(&scene, mode.bvh(), n, index, (x, y));
    let on: Vec<(u32, u32)> = (n / 2..n)
        .flat_map(|y| (0..n).map(move |x| (x, y)))
        .filter(sees)
        .collect();
    let row = on.first().map(|p| p.1).ok_or_else(|| {
        CliError::bad_input(anyhow!(
            "the SPMM material is not seen in the lower half of the image"
        ))
    })?;
    let xs: Vec<u32> = on.iter().filter(|p| p.1 == row).map(|p| p.0).collect();
    let shaded = (0..n)
        .flat_map(|y| (0..n).map(move |x| (x, y)))
        .filter(sees)
        .count();
    // The pack edit of the whole stroke so far, as the studio makes it.
    let edit_within = |mask: &TexelMask| -> Result<SceneEdit, CliError> {
        let edited = original
            .with_weight_scale(&WeightTarget::default().within(mask), [1.3, 1.1, 0.8])
            .map_err(CliError::failure)?;
        Ok(SceneEdit::Material {
            index,
            material: Material::Spmm {
                material: Arc::new(edited),
                uv_scale,
                residual,
                npca,
            },
        })
    };
    let mut mask = TexelMask::empty(original.width(), original.height());
    let times = time_strokes(
        args,
        (&scene, index),
        (&mut mode, &mut whole),
        (&xs, row),
        &mut mask,
        edit_within,
    )?;
    report(args, (original.width(), original.height()), &times, shaded)
}

/// Whether the centre of pixel (x, y) of the `n` x `n` image sees material `index`.
fn sees_material(scene: &Scene, bvh: &SceneBvh, n: u32, index: usize, (x, y): (u32, u32)) -> bool {
    pick(scene, bvh, n, n, f64::from(x) + 0.5, f64::from(y) + 0.5)
        .is_some_and(|p| p.material == index)
}

/// Per stroke step, each part's time in milliseconds on the mode that traces only the
/// restarted pixels and on the one that traces a whole frame, and the pixels restarted.
#[derive(Default)]
struct StepTimes {
    dab_ms: Vec<f64>,
    edit_ms: Vec<f64>,
    apply_ms: Vec<f64>,
    frame_ms: Vec<f64>,
    total_ms: Vec<f64>,
    whole_apply_ms: Vec<f64>,
    whole_frame_ms: Vec<f64>,
    whole_total_ms: Vec<f64>,
    restarted: Vec<usize>,
}

/// Walks the stroke along row `row` of `xs` (every third pixel, wrapping), timing each
/// step from the dab to the finished image on both modes, interleaved so both see the
/// same load within a step.
fn time_strokes(
    args: &StrokeArgs,
    (scene, index): (&Scene, usize),
    (mode, whole): (&mut SpmmMode, &mut SpmmMode),
    (xs, row): (&[u32], u32),
    mask: &mut TexelMask,
    edit_within: impl Fn(&TexelMask) -> Result<SceneEdit, CliError>,
) -> Result<StepTimes, CliError> {
    let n = args.size;
    let brush = Brush {
        radius: 2.0,
        units: BrushUnits::Texels,
        strength: 1.0,
        falloff: Falloff::Constant,
    };
    let mut times = StepTimes::default();
    let mut last = DVec2::new(f64::from(xs[0]) + 0.5, f64::from(row) + 0.5);
    for k in 0..args.strokes {
        let x = xs[(k * 3) % xs.len()];
        let p = DVec2::new(f64::from(x) + 0.5, f64::from(row) + 0.5);
        let t0 = Instant::now();
        brush::stroke(scene, mode.bvh(), (n, n), last, p, &brush, index, mask);
        last = p;
        let t1 = Instant::now();
        let edit = edit_within(mask)?;
        let t2 = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        // The previous behaviour on the same step, then the current one: both see
        // the same load within a step.
        let w3 = Instant::now();
        whole.apply(edit.clone()).map_err(CliError::failure)?;
        let w4 = Instant::now();
        whole.render_frame();
        let _image = whole.image();
        let w5 = Instant::now();
        times.whole_apply_ms.push(ms(w3, w4));
        times.whole_frame_ms.push(ms(w4, w5));
        times.whole_total_ms.push(ms(t0, t2) + ms(w3, w5));
        let t3a = Instant::now();
        let inv = mode.apply(edit).map_err(CliError::failure)?;
        let t3 = Instant::now();
        mode.render_frame();
        let _image = mode.image();
        let t4 = Instant::now();
        times.dab_ms.push(ms(t0, t1));
        times.edit_ms.push(ms(t1, t2));
        times.apply_ms.push(ms(t3a, t3));
        times.frame_ms.push(ms(t3, t4));
        times.total_ms.push(ms(t0, t2) + ms(t3a, t4));
        times.restarted.push(match inv {
            Invalidation::Pixels(p) => p,
            Invalidation::All => (n * n) as usize,
            _ => 0,
        });
    }
    Ok(times)
}

/// Prints the medians and maxima per part (JSON with `--json`): `(width, height)` is
/// the pack's size in texels, `shaded` the pixels that see the material.
fn report(
    args: &StrokeArgs,
    (width, height): (u32, u32),
    times: &StepTimes,
    shaded: usize,
) -> Result<(), CliError> {
    let n = args.size;
    let threads = rayon::current_num_threads();
    let (dab, edit) = (stats(times.dab_ms.clone()), stats(times.edit_ms.clone()));
    let parts = [
        ("dab", dab),
        ("pack edit", edit),
        ("apply", stats(times.apply_ms.clone())),
        ("frame + image", stats(times.frame_ms.clone())),
        ("stroke to frame", stats(times.total_ms.clone())),
    ];
    let whole_parts = [
        ("dab", dab),
        ("pack edit", edit),
        ("apply", stats(times.whole_apply_ms.clone())),
        ("frame + image", stats(times.whole_frame_ms.clone())),
        ("stroke to frame", stats(times.whole_total_ms.clone())),
    ];
    let json_parts = |parts: &[(&str, (f64, f64))]| {
        parts
            .iter()
            .map(|(name, (med, max))| json!({"part": name, "median": med, "max": max}))
            .collect::<Vec<_>>()
    };
    let restarted_median = {
        let mut r = times.restarted.clone();
        r.sort_unstable();
        r[r.len() / 2]
    };
    if args.json {
        return crate::print_json(&json!({
            "scene": args.scene.display().to_string(),
            "size": n,
            "threads": threads,
            "strokes": args.strokes,
            "texels": width * height,
            "ms": json_parts(&parts),
            "whole_frame_ms": json_parts(&whole_parts),
            "restarted_pixels_median": restarted_median,
            "pixels_of_material": shaded,
        }));
    }
    println!(
        "{}: {n}x{n}, {threads} threads, {} stroke steps, pack {}x{} texels",
        args.scene.display(),
        args.strokes,
        width,
        height
    );
    println!("  the frame after each edit traces only the restarted pixels:");
    for (name, (med, max)) in parts {
        println!("  {name:<16} median {med:8.2} ms   max {max:8.2} ms");
    }
    println!("  side by side, the next frame a whole frame (before):");
    for (name, (med, max)) in whole_parts {
        println!("  {name:<16} median {med:8.2} ms   max {max:8.2} ms");
    }
    println!(
        "  restarted pixels per step: median {restarted_median} (a whole-material restart: {shaded})"
    );
    Ok(())
}
