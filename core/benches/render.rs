//! Renderer speed (issue 6's benchmark list), side by side in one process:
//! - rays per second by kind (primary = closest hit, shadow and AO = occlusion) on the
//!   bunny (3.7k triangles), the bunny subdivided to 59k, and the tablecloth subdivided
//!   to 1.25M triangles, on 1 thread and on all threads;
//! - BVH build against refit (same triangles moved) for those meshes;
//! - milliseconds per frame of the default scene at 256^2 and 512^2, AO on and off,
//!   still and moving (residual skipped), 1 thread and all threads;
//! - the environment scene per frame: MIS, map sampling alone, no environment.

use std::collections::HashMap;
use std::path::Path;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use glam::{DMat3, DVec2, DVec3};
use meso_core::brdf::warp;
use meso_core::geometry::SceneBvh;
use meso_core::modes;
use meso_core::render::{Device, ModeKind, Prepare, RenderMode, SceneEdit};
use meso_core::rng::SampleStream;
use meso_core::scene::mesh::{Placement, load_obj, vertex_normals};
use meso_core::scene::{TriangleMesh, load_scene};
use rayon::prelude::*;

fn root() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn load(name: &str) -> TriangleMesh {
    let placement = Placement {
        scale: 1.0,
        rotation: DMat3::IDENTITY,
        translate: DVec3::ZERO,
    };
    load_obj(
        &root().join("tests/scenes/meshes").join(name),
        &placement,
        0,
    )
    .expect("mesh")
}

/// Splits every triangle into four at its edge midpoints (shared midpoints welded).
fn subdivide(m: &TriangleMesh) -> TriangleMesh {
    let mut positions = m.positions.clone();
    let mut uvs = m.uvs.clone();
    let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
    let mut midpoint = |a: u32, b: u32| {
        *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
            positions.push((positions[a as usize] + positions[b as usize]) * 0.5);
            uvs.push((uvs[a as usize] + uvs[b as usize]) * 0.5);
            positions.len() as u32 - 1
        })
    };
    let mut indices = Vec::with_capacity(m.indices.len() * 4);
    for &[a, b, c] in &m.indices {
        let (ab, bc, ca) = (midpoint(a, b), midpoint(b, c), midpoint(c, a));
        indices.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    let normals = vertex_normals(&positions, &indices);
    TriangleMesh {
        positions,
        normals,
        uvs,
        indices,
        material: m.material,
    }
}

/// Rays of each kind for a mesh: primary rays from a camera on a circle around it
/// aimed at its bounding box, shadow rays from their hit points to a light above, and
/// cosine-distributed AO rays of radius 0.1 from the same points.
struct Rays {
    primary: Vec<(DVec3, DVec3)>,
    shadow: Vec<(DVec3, DVec3, f64)>,
    ambient: Vec<(DVec3, DVec3)>,
}

fn rays(mesh: &TriangleMesh, bvh: &SceneBvh, n: usize) -> Rays {
    let (lo, hi) = mesh.positions.iter().fold(
        (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let (centre, size) = ((lo + hi) * 0.5, (hi - lo).max_element());
    let eye = centre + DVec3::new(1.2, 0.6, 1.5) * size;
    let light = centre + DVec3::new(-0.5, 2.0, 0.8) * size;
    let mut out = Rays {
        primary: Vec::new(),
        shadow: Vec::new(),
        ambient: Vec::new(),
    };
    let meshes = std::slice::from_ref(mesh);
    for i in 0..n as u64 {
        let mut rng = SampleStream::new(&[42, i]);
        let target = lo + (hi - lo) * DVec3::new(rng.next(), rng.next(), rng.next());
        let dir = (target - eye).normalize();
        out.primary.push((eye, dir));
        if let Some(h) = bvh.closest_hit(meshes, eye, dir, 0.0, f64::INFINITY) {
            let p = eye + dir * h.t;
            let [a, b, c] = mesh.indices[h.triangle].map(|k| mesh.positions[k as usize]);
            let mut n = (b - a).cross(c - a).normalize();
            if n.dot(dir) > 0.0 {
                n = -n;
            }
            let p = p + n * 1e-5 * size;
            let to = light - p;
            out.shadow.push((p, to.normalize(), to.length()));
            let (t, bt) = warp::orthonormal_basis(n);
            let l = warp::cosine_hemisphere(DVec2::new(rng.next(), rng.next()));
            out.ambient.push((p, t * l.x + bt * l.y + n * l.z));
        }
    }
    out
}

fn bench_rays(c: &mut Criterion) {
    let bunny = load("bunny_lowres.obj");
    let bunny59k = subdivide(&subdivide(&bunny));
    let cloth = load("tablecloth.obj");
    let cloth1m = subdivide(&subdivide(&subdivide(&cloth)));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let n = 65_536;
    for (label, mesh) in [
        ("bunny 3.7k", &bunny),
        ("bunny 59k", &bunny59k),
        ("cloth 1.25M", &cloth1m),
    ] {
        let bvh = SceneBvh::build(std::slice::from_ref(mesh));
        let r = rays(mesh, &bvh, n);
        let meshes = std::slice::from_ref(mesh);
        let mut group = c.benchmark_group(format!("rays {label}"));
        group.sample_size(10);
        for threads in [1, 0] {
            let t = if threads == 1 {
                "1 thread"
            } else {
                "all threads"
            };
            let run = |f: &(dyn Fn() -> usize + Sync)| {
                if threads == 1 { one.install(f) } else { f() }
            };
            group.throughput(Throughput::Elements(r.primary.len() as u64));
            group.bench_function(BenchmarkId::new("primary", t), |b| {
                b.iter(|| {
                    run(&|| {
                        r.primary
                            .par_iter()
                            .filter(|(o, d)| {
                                bvh.closest_hit(meshes, *o, *d, 0.0, f64::INFINITY)
                                    .is_some()
                            })
                            .count()
                    })
                })
            });
            group.throughput(Throughput::Elements(r.shadow.len() as u64));
            group.bench_function(BenchmarkId::new("shadow", t), |b| {
                b.iter(|| {
                    run(&|| {
                        r.shadow
                            .par_iter()
                            .filter(|(o, d, l)| bvh.occluded(*o, *d, 0.0, *l))
                            .count()
                    })
                })
            });
            group.throughput(Throughput::Elements(r.ambient.len() as u64));
            group.bench_function(BenchmarkId::new("ambient r=0.1", t), |b| {
                b.iter(|| {
                    run(&|| {
                        r.ambient
                            .par_iter()
                            .filter(|(o, d)| bvh.occluded(*o, *d, 0.0, 0.1))
                            .count()
                    })
                })
            });
        }
        group.finish();

        let mut group = c.benchmark_group(format!("bvh {label}"));
        group.sample_size(10);
        group.bench_function("build", |b| {
            b.iter(|| SceneBvh::build(std::slice::from_ref(mesh)))
        });
        let mut moved = mesh.clone();
        let mut bvh = SceneBvh::build(std::slice::from_ref(mesh));
        let mut k = 0u32;
        group.bench_function("refit after a move", |b| {
            b.iter(|| {
                k += 1;
                let dy = if k.is_multiple_of(2) { 0.01 } else { -0.01 };
                for p in &mut moved.positions {
                    p.y += dy;
                }
                assert!(bvh.update(std::slice::from_ref(&moved)));
            })
        });
        group.finish();
    }
}

fn create(scene: meso_core::scene::Scene, size: u32) -> Box<dyn RenderMode> {
    modes::create(
        ModeKind::Spmm,
        Device::Cpu,
        scene,
        size,
        size,
        Prepare::quietly(),
    )
    .expect("the spmm mode renders the test scenes")
}

/// The environment scene at 256^2: map sampling alone against MIS (two rays), and
/// the same scene without its environment (primary rays and shading only).
fn bench_environment(c: &mut Criterion) {
    let scene = load_scene(&root().join("tests/scenes/env.toml")).expect("env scene");
    let mut group = c.benchmark_group("environment frame 256x256");
    group.sample_size(10);
    group.throughput(Throughput::Elements(256 * 256));
    for (label, mis, env) in [
        ("MIS", true, true),
        ("map only", false, true),
        ("no environment", false, false),
    ] {
        let mut s = scene.clone();
        match (&mut s.environment, env) {
            (Some(e), true) => e.mis = mis,
            (e, _) => *e = None,
        }
        let mut mode = create(s, 256);
        group.bench_function(BenchmarkId::new(label, "all threads"), |b| {
            b.iter(|| mode.render_frame())
        });
    }
    group.finish();
}

fn bench_frames(c: &mut Criterion) {
    let scene = load_scene(&root().join("tests/scenes/default.toml")).expect("default scene");
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    for size in [256u32, 512] {
        let mut group = c.benchmark_group(format!("frame {size}x{size}"));
        group.sample_size(10);
        group.throughput(Throughput::Elements(u64::from(size * size)));
        for (ao, moving) in [(true, false), (false, false), (true, true)] {
            let mut s = scene.clone();
            if !ao {
                s.ambient = None;
            }
            let mut mode = create(s, size);
            mode.apply(SceneEdit::Moving(moving)).expect("valid edit");
            let label = format!(
                "AO {}, residual {}",
                if ao { "on" } else { "off" },
                if moving { "skipped (moving)" } else { "on" }
            );
            group.bench_function(BenchmarkId::new(label.clone(), "1 thread"), |b| {
                b.iter(|| one.install(|| mode.render_frame()))
            });
            group.bench_function(BenchmarkId::new(label, "all threads"), |b| {
                b.iter(|| mode.render_frame())
            });
        }
        group.finish();
    }
}

criterion_group!(benches, bench_rays, bench_frames, bench_environment);
criterion_main!(benches);
