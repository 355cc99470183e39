//! The editor's responsiveness (issue 7's measure), side by side in one process:
//! - edit to first updated frame at a 256x256 preview: a material edit (a basis normal
//!   tilted, which re-prepares the pack and restarts the pixels that show it) and a
//!   light-colour edit (which keeps every sample), from sending the versioned edit to
//!   the render thread until a frame of that version is published;
//! - the studio's UI frame (all panels, headless egui) while the renderer works.

use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use glam::DVec3;
use meso_core::brdf::BasisFunction;
use meso_core::render::{ModeKind, SceneEdit};
use meso_core::scene::{Material, load_scene};
use meso_studio::render_worker::{Command, RenderWorker};
use meso_studio::studio::{Settings, Studio, default_scene_path};

fn wait_for(worker: &RenderWorker, version: u64) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        if worker.take_frame().is_some_and(|f| f.version >= version) {
            return;
        }
        assert!(Instant::now() < deadline, "no frame of version {version}");
        std::thread::sleep(Duration::from_micros(200));
    }
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

    let worker = RenderWorker::spawn(None);
    worker.send(Command::Load {
        version: 1,
        scene: Box::new(scene.clone()),
        mode: ModeKind::Spmm,
        device: meso_core::render::Device::Cpu,
        width: 256,
        height: 256,
    });
    wait_for(&worker, 1);
    let mut version = 1u64;
    let mut group = c.benchmark_group("edit to first frame 256x256");
    group.sample_size(30);
    group.bench_function("material edit (basis normal)", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                version += 1;
                let start = Instant::now();
                worker.send(Command::Edit {
                    version,
                    edit: Box::new(SceneEdit::Material {
                        index,
                        material: variants[(version % 2) as usize].clone(),
                    }),
                });
                wait_for(&worker, version);
                total += start.elapsed();
            }
            total
        })
    });
    group.bench_function("light colour edit (samples kept)", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                version += 1;
                let e = if version.is_multiple_of(2) { 1.0 } else { 0.8 };
                let start = Instant::now();
                worker.send(Command::Edit {
                    version,
                    edit: Box::new(SceneEdit::Light {
                        index: 0,
                        light: light.with_emission(light.emission() * e),
                    }),
                });
                wait_for(&worker, version);
                total += start.elapsed();
            }
            total
        })
    });
    group.finish();
    drop(worker);

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
