//! `meso bench edits SCENE [--size 512] [--mode M] [--device D] [--edits 40] [--json]`
//! (docs/cli.md): edit-to-frame time of each edit kind as the studio runs the
//! renderer, without a window. The scene is loaded into the viewport's render thread
//! (`meso_viewport::RenderWorker`: the mode from the registry, tiles that yield to
//! edits, the preview after a restart, the denoiser beside it, the studio's sample
//! limit) at `size` square; then, round after round, one edit of each kind is sent at
//! a pseudo-random point of the frame in flight (after a pause of up to twice the
//! last frame's time) and timed until the first frame of its document version is
//! published: what the viewport would show next. The kinds take turns, so each sees
//! the film as edits leave it (young, denoised), as in a session. Edits are made on
//! the document as the edits before left it, as the studio's are, and each kind goes
//! back and forth (a weight scaled by 1.25 then back), so nothing drifts. The timed
//! interval starts before the edit reaches the studio's document
//! (`meso_session::Document`: its undo step, with a pack's delta, and its recovery
//! journal in a scratch folder), so what keeping work safe costs is in the figure.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::anyhow;
use clap::Args;
use glam::{DMat3, DVec3};
use meso_materials::brdf::BasisFunction;
use meso_materials::rng::SampleStream;
use meso_materials::spmm::{SpmmError, SpmmMaterial, WeightTarget};
use meso_render::scene::{Light, Material, Scene, load_scene};
use meso_render::{Device, ModeKind, SceneEdit};
use meso_session::Document;
use meso_viewport::{Command, Frame, RenderWorker};
use serde_json::json;

use crate::failure::{CliError, ResultExt};
use crate::mode_args::ModeArgs;

#[derive(Args, Debug)]
pub struct EditsArgs {
    scene: PathBuf,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512)]
    size: u32,
    #[command(flatten)]
    mode: ModeArgs,
    /// Edits timed per kind.
    #[arg(long, default_value_t = 40)]
    edits: usize,
    /// The studio's sample limit (its default): the renderer idles after it.
    #[arg(long, default_value_t = 1024)]
    max_samples: u32,
    #[arg(long)]
    json: bool,
}

/// The edit of a kind in round `i`, made on the document as it stands (edits add up,
/// as a session's do; each kind goes back and forth, so nothing drifts).
type MakeEdit = Box<dyn Fn(&Scene, usize) -> Result<SceneEdit, String>>;

/// An edit kind: its name and its edits, or why the scene has nothing to edit of
/// this kind.
struct Kind {
    name: &'static str,
    edit: Result<MakeEdit, String>,
}

/// The first SPMM material's slot and its pack, as `scene` has them now.
fn first_pack(scene: &Scene) -> Result<(usize, &Material, &SpmmMaterial), String> {
    (scene.materials.iter().enumerate())
        .find_map(|(i, m)| match m {
            Material::Spmm { material, .. } => Some((i, m, material.as_ref())),
            _ => None,
        })
        .ok_or_else(|| "the scene has no SPMM material".to_string())
}

/// The first SPMM material edited by `f`, as the material edit the studio sends.
fn pack_edit(
    scene: &Scene,
    f: impl Fn(&SpmmMaterial) -> Result<SpmmMaterial, SpmmError>,
) -> Result<SceneEdit, String> {
    let (index, m, pack) = first_pack(scene)?;
    let Material::Spmm {
        uv_scale,
        residual,
        npca,
        ..
    } = m
    else {
        unreachable!("first_pack finds packs");
    };
    Ok(SceneEdit::Material {
        index,
        material: Material::Spmm {
            material: Arc::new(f(pack).map_err(|e| e.to_string())?),
            uv_scale: *uv_scale,
            residual: *residual,
            npca: *npca,
        },
    })
}

/// The first light as `scene` has it now.
fn first_light(scene: &Scene) -> Result<Light, String> {
    (scene.lights.first().copied()).ok_or_else(|| "the scene has no light".to_string())
}

/// The kinds, in the order they take turns; a kind whose first edit cannot be made
/// on `scene` is skipped, with the reason.
fn kinds(scene: &Scene) -> Vec<Kind> {
    let weight: MakeEdit = Box::new(|scene, i| {
        // A basis's weights scaled by about 1.25, then back.
        let s = there_and_back(1.25, i);
        pack_edit(scene, |p| {
            p.with_weight_scale(&WeightTarget::basis(0, 0), [s; 3])
        })
    });
    let basis: MakeEdit = Box::new(|scene, i| {
        // The first basis with a parameter (a lobe's roughness or exponent): 10% up,
        // then back (about).
        let (_, _, pack) = first_pack(scene)?;
        let (c, j, b) = (pack.clusters().iter().enumerate())
            .flat_map(|(c, cl)| cl.bases.iter().enumerate().map(move |(j, b)| (c, j, b)))
            .find(|(_, _, b)| !b.brdf().model().param_specs().is_empty())
            .ok_or("no basis of the pack has a parameter")?;
        let brdf = b.brdf();
        let spec = &brdf.model().param_specs()[0];
        let value = brdf.param_values()[0] * there_and_back(1.1, i);
        let changed = (brdf.with_param(spec.name, value.clamp(spec.min, spec.max)))
            .map_err(|e| e.to_string())?;
        let basis = BasisFunction::new(changed, b.normal()).map_err(|e| e.to_string())?;
        pack_edit(scene, |p| p.with_basis(c, j, basis))
    });
    let light_colour: MakeEdit = Box::new(|scene, i| {
        let l = first_light(scene)?;
        let tint = DVec3::new(1.0, 0.8, 0.9).powf(back_and_forth(i));
        Ok(SceneEdit::Light {
            index: 0,
            light: l.with_emission(l.emission() * tint),
        })
    });
    let light_move: MakeEdit = Box::new(|scene, i| {
        let by = DVec3::X * 0.05 * back_and_forth(i);
        Ok(SceneEdit::Light {
            index: 0,
            light: moved_light(first_light(scene)?, by),
        })
    });
    let camera: MakeEdit = Box::new(|scene, i| {
        // One degree about the vertical through the point looked at, as a drag step.
        let turn = DMat3::from_rotation_y(back_and_forth(i).to_radians());
        let mut c = scene.camera;
        c.position = c.look_at + turn * (c.position - c.look_at);
        Ok(SceneEdit::Camera(c))
    });
    let environment: MakeEdit = Box::new(|scene, i| {
        let mut e = (scene.environment.clone()).ok_or("the scene has no environment")?;
        e.rotate_y_deg += 2.0 * back_and_forth(i);
        Ok(SceneEdit::Environment(Some(e)))
    });
    [
        ("material weight", weight),
        ("basis parameter", basis),
        ("light colour", light_colour),
        ("light move", light_move),
        ("camera", camera),
        ("environment rotation", environment),
    ]
    .into_iter()
    .map(|(name, edit)| Kind {
        name,
        edit: edit(scene, 0).map(|_| edit),
    })
    .collect()
}

/// +1 in even rounds, -1 in odd ones: an edit's two states.
fn back_and_forth(round: usize) -> f64 {
    if round.is_multiple_of(2) { 1.0 } else { -1.0 }
}

/// A factor `f` in even rounds and about 1/f in odd ones, a little different every
/// round (0.1%), so no edit repeats a state an analysis or cache has seen.
fn there_and_back(f: f64, round: usize) -> f64 {
    f.powf(back_and_forth(round)) * (1.0 + 1e-3 * (round % 7) as f64)
}

fn moved_light(light: Light, by: DVec3) -> Light {
    match light {
        Light::Point {
            position,
            intensity,
        } => Light::Point {
            position: position + by,
            intensity,
        },
        Light::Area {
            corner,
            edge_u,
            edge_v,
            radiance,
        } => Light::Area {
            corner: corner + by,
            edge_u,
            edge_v,
            radiance,
        },
    }
}

/// Waits for a frame `wanted` accepts; an error after a minute.
fn wait_for(
    worker: &RenderWorker,
    wanted: impl Fn(&Frame) -> bool,
) -> Result<(Frame, Instant), CliError> {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let rejected = worker.take_rejected();
        if let Some(r) = rejected.first() {
            return Err(CliError::bad_input(anyhow!(
                "the renderer refused version {}: {}",
                r.version,
                r.message
            )));
        }
        if let Some(f) = worker.take_frame().filter(&wanted) {
            return Ok((f, Instant::now()));
        }
        if Instant::now() > deadline || !worker.is_running() {
            return Err(CliError::failure(anyhow!("no frame came within a minute")));
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// Median and 95th percentile (nearest rank) of `ms`.
fn percentiles(mut ms: Vec<f64>) -> (f64, f64) {
    ms.sort_by(f64::total_cmp);
    let rank = |q: f64| ms[((q * ms.len() as f64).ceil() as usize).clamp(1, ms.len()) - 1];
    (rank(0.5), rank(0.95))
}

pub fn run(args: &EditsArgs) -> Result<(), CliError> {
    if !(16..=4096).contains(&args.size) || args.edits == 0 {
        return Err(CliError::bad_input(anyhow!(
            "--size must lie in [16, 4096] and --edits be at least 1"
        )));
    }
    let scene = load_scene(&args.scene).bad_input_ctx(|| format!("`{}`", args.scene.display()))?;
    let (kind, device) = args.mode.resolve(&scene)?;
    let kinds = kinds(&scene);
    let worker = RenderWorker::spawn(None);
    worker.send(Command::MaxSamples(args.max_samples));
    worker.send(Command::Load {
        version: 1,
        scene: Box::new(scene.clone()),
        mode: kind,
        device,
        width: args.size,
        height: args.size,
    });
    // The studio's document: each edit is applied to it as the studio applies it,
    // with undo and a journal (removed at the end).
    let mut document = Document::new(scene, Some(args.scene.clone()));
    let journal_dir = std::env::temp_dir().join(format!("meso-bench-edits-{}", std::process::id()));
    document.journal_to(&journal_dir);
    let timed = time_edits(args, &worker, &kinds, &mut document);
    document.close_journal(true);
    let _ = std::fs::remove_dir_all(&journal_dir);
    report(args, (kind, device), &kinds, timed?);
    Ok(())
}

/// Sends `args.edits` rounds of each kind's edit and times each to its first frame.
fn time_edits(
    args: &EditsArgs,
    worker: &RenderWorker,
    kinds: &[Kind],
    document: &mut Document,
) -> Result<Vec<Vec<f64>>, CliError> {
    // Untimed: the mode's preparation and a few whole frames.
    let (mut last, _) = wait_for(worker, |f| !f.preview && f.progress.min_samples >= 4)?;
    let mut version = 1u64;
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); kinds.len()];
    let mut pauses = SampleStream::new(&[0xed17]);
    for round in 0..args.edits {
        for (k, kind) in kinds.iter().enumerate() {
            let Ok(make) = &kind.edit else { continue };
            let edit = make(&document.scene, round)
                .map_err(|e| CliError::failure(anyhow!("{} edit {round}: {e}", kind.name)))?;
            // The edit lands at a random point of the frame in flight.
            let frame_ms = last.frame_ms.clamp(1.0, 2_000.0);
            std::thread::sleep(Duration::from_secs_f64(
                2.0 * frame_ms * pauses.next() / 1e3,
            ));
            while let Some(f) = worker.take_frame() {
                last = f;
            }
            version += 1;
            let sent = Instant::now();
            // As the studio does: a camera turn is a view edit, the rest undo steps.
            let applied = if matches!(edit, SceneEdit::Camera(_)) {
                document.apply_view(&edit)
            } else {
                document.apply(&edit).map(|()| document.close_group())
            };
            applied.map_err(|e| CliError::failure(anyhow!("{} edit {round}: {e}", kind.name)))?;
            worker.send(Command::Edit {
                version,
                edit: Box::new(edit),
            });
            let (frame, at) = wait_for(worker, |f| f.version >= version)?;
            times[k].push((at - sent).as_secs_f64() * 1e3);
            if frame.frame_ms > 0.0 {
                last = frame;
            }
        }
    }
    Ok(times)
}

fn report(
    args: &EditsArgs,
    (kind, device): (ModeKind, Device),
    kinds: &[Kind],
    times: Vec<Vec<f64>>,
) {
    let rows: Vec<_> = kinds
        .iter()
        .zip(times)
        .map(|(k, t)| match &k.edit {
            Ok(_) => {
                let (median, p95) = percentiles(t.clone());
                json!({"kind": k.name, "edits": t.len(), "median_ms": median, "p95_ms": p95})
            }
            Err(why) => json!({"kind": k.name, "edits": 0, "median_ms": null, "p95_ms": null, "skipped": why}),
        })
        .collect();
    if args.json {
        let out = json!({
            "scene": args.scene.display().to_string(),
            "size": args.size,
            "mode": kind.name(),
            "device": device.name(),
            "kinds": rows,
        });
        println!("{out:#}");
        return;
    }
    println!(
        "{} at {} x {}, {} on the {}: edit to first frame of its version",
        args.scene.display(),
        args.size,
        args.size,
        kind.name(),
        device.name()
    );
    println!(
        "{:<22} {:>6} {:>11} {:>9}",
        "kind", "edits", "median ms", "p95 ms"
    );
    for r in rows {
        let name = r["kind"].as_str().unwrap_or_default();
        match r.get("skipped").and_then(|s| s.as_str()) {
            Some(why) => println!("{name:<22} skipped: {why}"),
            None => println!(
                "{name:<22} {:>6} {:>11.1} {:>9.1}",
                r["edits"],
                r["median_ms"].as_f64().unwrap_or(f64::NAN),
                r["p95_ms"].as_f64().unwrap_or(f64::NAN)
            ),
        }
    }
}
