//! Progressive rendering speed on the default scene (bunny 3.7k triangles in the
//! leather pack, floor, area light, AO): one frame at 256x256 on 1 thread and on all
//! threads, AO on and off, and the BVH build of the full-resolution bunny (75k triangles).

use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use meso_core::render::{ModeKind, RenderMode};
use meso_core::scene::load_scene;
use meso_core::scene::mesh::{Placement, load_obj};
use meso_core::trace::SceneBvh;

fn bench_render(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene = load_scene(&root.join("tests/scenes/default.toml")).expect("default scene");
    let mut no_ao = scene.clone();
    no_ao.ambient = None;
    let mut group = c.benchmark_group("render_frame_256");
    group.sample_size(10);
    group.throughput(Throughput::Elements(256 * 256));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    for (label, s) in [("AO on", &scene), ("AO off", &no_ao)] {
        let mut r = ModeKind::Spmm.create(s.clone(), 256, 256).expect("size");
        group.bench_function(format!("{label}, 1 thread"), |b| {
            b.iter(|| one.install(|| r.render_frame()))
        });
        group.bench_function(format!("{label}, all threads"), |b| {
            b.iter(|| r.render_frame())
        });
    }
    group.finish();

    let bunny = root.join("tests/scenes/meshes/bunny_lowres.obj");
    let placement = Placement {
        scale: 1.0,
        rotation: glam::DMat3::IDENTITY,
        translate: glam::DVec3::ZERO,
    };
    let mesh = load_obj(&bunny, &placement, 0).expect("bunny");
    c.bench_function("bvh build, bunny 3.7k triangles", |b| {
        b.iter(|| SceneBvh::build(std::slice::from_ref(&mesh)))
    });
}

criterion_group!(benches, bench_render);
criterion_main!(benches);
