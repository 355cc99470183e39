//! The editor's responsiveness (issues 7 and 16), side by side in one process:
//! - edit to first updated frame at 256, 512 and 1024 pixels square: a material edit
//!   (a basis normal tilted, which re-prepares the pack and restarts the pixels that
//!   show it), a light-colour edit (which keeps every sample) while the view is still
//!   denoised and once it has 32 samples per pixel, and a camera edit (which restarts
//!   every pixel: to its preview, and to its whole frame), from sending the versioned
//!   edit to the render thread until a frame of that version is published; each with
//!   the frame in flight yielding to the edit between tiles (and previews) and without
//!   (the edit waits for the whole frame);
//! - the adaptive mode's camera edit on the MERL dragon at 256 and 512 pixels square,
//!   to its preview and to its first whole frame (issue 14);
//! - the studio's UI frame (all panels, headless egui) while the renderer works.

use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use glam::DVec3;
use meso_materials::brdf::BasisFunction;
use meso_render::denoise;
use meso_render::scene::{Material, load_scene};
use meso_render::{ModeKind, SceneEdit};
use meso_studio::studio::{Settings, Studio, default_scene_path};
use meso_viewport::worker::{Command, Frame, RenderWorker};

/// Waits for a frame `wanted` accepts.
fn wait_until(worker: &RenderWorker, wanted: impl Fn(&Frame) -> bool) -> Frame {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Some(f) = worker.take_frame().filter(&wanted) {
            return f;
        }
        assert!(Instant::now() < deadline, "no frame came");
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// Waits for a frame of `version` or newer (not a preview if `whole`).
fn wait_for(worker: &RenderWorker, version: u64, whole: bool) -> Frame {
    wait_until(worker, |f| f.version >= version && !(whole && f.preview))
}

/// What the film holds when a timed edit arrives.
#[derive(Clone, Copy, PartialEq)]
enum FilmState {
    /// Whatever the edits before left.
    Any,
    /// Under 16 samples per pixel: the viewport denoiser is on (a camera edit, not
    /// timed, restarts the film when it has more).
    Denoised,
    /// `denoise::FADE_SAMPLES` or more: the denoiser is off (the film is left to
    /// reach them first, not timed).
    Clean,
}

/// An edit timed: its name, the edit for an iteration number, whether the time is to
/// the first whole frame (a preview, `Frame::preview`, does not count) and the film's
/// state when it arrives.
struct Timed<'a> {
    name: &'a str,
    edit: Box<dyn Fn(u64) -> SceneEdit + 'a>,
    whole: bool,
    film: FilmState,
}

/// A render thread with `scene` loaded in `mode` at `size` square, and its first
/// whole frame.
fn timed<'a>(
    name: &'a str,
    edit: Box<dyn Fn(u64) -> SceneEdit + 'a>,
    whole: bool,
    film: FilmState,
) -> Timed<'a> {
    Timed {
        name,
        edit,
        whole,
        film,
    }
}

/// A camera edit for an iteration number: `camera`, moved 5 cm sideways on odd ones.
fn nudge(camera: meso_render::scene::Camera) -> impl Fn(u64) -> SceneEdit + Copy {
    move |v: u64| {
        let mut moved = camera;
        moved.position.x += if v.is_multiple_of(2) { 0.0 } else { 0.05 };
        SceneEdit::Camera(moved)
    }
}

fn load(scene: &meso_render::scene::Scene, mode: ModeKind, size: u32) -> (RenderWorker, Frame) {
    let worker = RenderWorker::spawn(None);
    worker.send(Command::Load {
        version: 1,
        scene: Box::new(scene.clone()),
        mode,
        device: meso_render::Device::Cpu,
        width: size,
        height: size,
    });
    let first = wait_for(&worker, 1, true);
    (worker, first)
}

/// Times each of `edits` on `worker` with the frame in flight yielding to the edit
/// (tiles) and without (the edit waits for the whole frame). An edit is sent at a
/// pseudo-random point of a frame: after a pause of a random fraction of the last
/// frame's time, as a user's edit falls anywhere in the frame in flight. `restart`
/// (a camera edit) resets a film that has too many samples for the edit's state.
fn time_edits(
    c: &mut Criterion,
    group: &str,
    (worker, first): (&RenderWorker, Frame),
    edits: &[Timed],
    restart: &dyn Fn(u64) -> SceneEdit,
) {
    let (mut frame_ms, mut spp) = (first.frame_ms, first.progress.min_samples);
    let mut version = first.version;
    let mut phase = 0x9e37_79b9_7f4a_7c15u64;
    let mut group = c.benchmark_group(group);
    group.sample_size(10);
    for t in edits {
        // A preview is shown only when tiles yield.
        for yielding in [true, false].into_iter().filter(|y| *y || !t.whole) {
            worker.send(Command::YieldToEdits(yielding));
            let label = if yielding {
                "tiles yield"
            } else {
                "whole frames"
            };
            group.bench_function(format!("{}, {label}", t.name), |b| {
                b.iter_custom(|iters| {
                    let mut total = Duration::ZERO;
                    for _ in 0..iters {
                        // The film as the edit wants it, not timed.
                        if t.film == FilmState::Denoised && spp >= 16 {
                            version += 1;
                            worker.send(Command::Edit {
                                version,
                                edit: Box::new(restart(version)),
                            });
                            spp = wait_for(worker, version, true).progress.min_samples;
                        }
                        if t.film == FilmState::Clean && spp < denoise::FADE_SAMPLES {
                            spp = wait_until(worker, |f| {
                                f.progress.min_samples >= denoise::FADE_SAMPLES
                            })
                            .progress
                            .min_samples;
                        }
                        phase = phase
                            .wrapping_mul(6_364_136_223_846_793_005)
                            .wrapping_add(1);
                        let fraction = (phase >> 11) as f64 / (1u64 << 53) as f64;
                        std::thread::sleep(Duration::from_secs_f64(
                            fraction * frame_ms.max(1.0) * 1e-3,
                        ));
                        version += 1;
                        let start = Instant::now();
                        worker.send(Command::Edit {
                            version,
                            edit: Box::new((t.edit)(version)),
                        });
                        let f = wait_for(worker, version, t.whole);
                        total += start.elapsed();
                        spp = f.progress.min_samples;
                        if f.frame_ms > 0.0 && !f.preview {
                            frame_ms = f.frame_ms;
                        }
                    }
                    total
                })
            });
        }
    }
    group.finish();
}

fn bench_latency(c: &mut Criterion) {
    let scene = load_scene(&default_scene_path()).expect("default scene");
    let index = scene
        .materials
        .iter()
        .position(|m| matches!(m, Material::Spmm { .. }))
        .expect("an SPMM material");
    let Material::Spmm {
        material,
        uv_scale,
        residual,
        npca,
    } = scene.materials[index].clone()
    else {
        unreachable!("position found an SPMM material")
    };
    let basis = material.clusters()[0].bases[0];
    let tilted = BasisFunction::new(*basis.brdf(), DVec3::new(0.3, 0.0, 1.0).normalize())
        .expect("unit normal");
    let variants: Vec<Material> = [
        material.as_ref().clone(),
        material.with_basis(0, 0, tilted).expect("valid"),
    ]
    .into_iter()
    .map(|m| Material::Spmm {
        material: Arc::new(m),
        uv_scale,
        residual,
        npca,
    })
    .collect();
    let light = scene.lights[0];
    let camera_edit = nudge(scene.camera);
    let light_edit = move |v: u64| SceneEdit::Light {
        index: 0,
        light: light.with_emission(light.emission() * if v.is_multiple_of(2) { 1.0 } else { 0.8 }),
    };
    let edits: Vec<Timed> = vec![
        timed(
            "material edit (basis normal)",
            Box::new(move |v| SceneEdit::Material {
                index,
                material: variants[(v % 2) as usize].clone(),
            }),
            false,
            FilmState::Any,
        ),
        timed(
            "light colour edit (samples kept), view denoised",
            Box::new(light_edit),
            false,
            FilmState::Denoised,
        ),
        timed(
            "light colour edit (samples kept), 32 spp or more",
            Box::new(light_edit),
            false,
            FilmState::Clean,
        ),
        timed(
            "camera edit (every pixel restarts; a preview first when tiles yield)",
            Box::new(camera_edit),
            false,
            FilmState::Any,
        ),
        timed(
            "camera edit to the whole frame (after its preview)",
            Box::new(camera_edit),
            true,
            FilmState::Any,
        ),
    ];

    // Each size, each edit, with the frame in flight yielding to the edit (tiles) and
    // without (the edit waits for the whole frame), alternated in one process.
    for size in [256u32, 512, 1024] {
        let (worker, first) = load(&scene, ModeKind::Spmm, size);
        let group = format!("edit to first frame {size}x{size}");
        time_edits(c, &group, (&worker, first), &edits, &camera_edit);
    }

    // The adaptive mode on the shipped MERL dragon: a camera edit restarts its
    // bandwidth pass (1.6 s at 512 x 512 on 2 cores), which yields to edits and is
    // preceded by a preview when tiles yield; whole frames are what the mode did before.
    let dragon = load_scene(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/scenes/merl_dragon.toml"),
    )
    .expect("the shipped MERL dragon scene");
    let dragon_edit = nudge(dragon.camera);
    let adaptive_edits = [
        timed(
            "adaptive: camera edit (a preview first when tiles yield)",
            Box::new(dragon_edit),
            false,
            FilmState::Any,
        ),
        timed(
            "adaptive: camera edit to the whole first frame",
            Box::new(dragon_edit),
            true,
            FilmState::Any,
        ),
    ];
    for size in [256u32, 512] {
        let (worker, first) = load(&dragon, ModeKind::Adaptive, size);
        let group = format!("adaptive edit to first frame {size}x{size}");
        time_edits(c, &group, (&worker, first), &adaptive_edits, &dragon_edit);
    }

    // The whole window, headless, while its render thread renders the default scene.
    let ctx = egui::Context::default();
    let mut studio = Studio::new(None, None, Settings::default());
    let input = || egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(
            egui::Pos2::ZERO,
            egui::vec2(1280.0, 800.0),
        )),
        ..Default::default()
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while studio.busy() || studio.doc.is_none() {
        let _ = ctx.run_ui(input(), |ui| studio.show(ui));
        assert!(Instant::now() < deadline, "the default scene did not load");
        std::thread::sleep(Duration::from_millis(5));
    }
    for _ in 0..3 {
        let _ = ctx.run_ui(input(), |ui| studio.show(ui));
    }
    c.bench_function("studio UI frame while rendering (1280x800)", |b| {
        b.iter(|| ctx.run_ui(input(), |ui| studio.show(ui)))
    });
}

criterion_group!(benches, bench_latency);
criterion_main!(benches);
