//! Renderer speed (issue 6's benchmark list), side by side in one process:
//! - rays per second by kind (primary = closest hit, shadow and AO = occlusion) on the
//!   bunny (3.7k triangles), the bunny subdivided to 59k, and the tablecloth subdivided
//!   to 1.25M triangles, on 1 thread and on all threads;
//! - BVH build against refit (same triangles moved) for those meshes;
//! - milliseconds per frame of the default scene at 256^2 and 512^2, AO on and off,
//!   still and moving (residual skipped), 1 thread and all threads;
//! - the environment scene per frame: MIS, map sampling alone, no environment;
//! - many lights: the default scene lit by 1 to 10,000 scattered lights at 256^2, the
//!   automatic path (stochastic above 16 lights) against every light traced (forced),
//!   with the film's bytes; `MESO_MANY_LIGHTS_REPORT=1` instead prints the frame
//!   times, film bytes and an equal-time convergence comparison (docs/performance.md);
//! - the viewport denoiser on the default scene's first frame at 256^2, 512^2 and 1024^2: the
//!   filter as used against its straightforward reference, and the half-resolution
//!   filter of the first picture after an emission edit, 1 thread and all threads.

use std::collections::HashMap;
use std::path::Path;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group};
use glam::{DMat3, DVec2, DVec3};
use meso_materials::brdf::warp;
use meso_materials::rng::SampleStream;
use meso_modes::trace::SpmmMode;
use meso_render::Film;
use meso_render::geometry::SceneBvh;
use meso_render::layers::layer_count;
use meso_render::light_selection::LightSampling;
use meso_render::scene::mesh::{Placement, load_obj, vertex_normals};
use meso_render::scene::{Light, Scene, TriangleMesh, load_scene};
use meso_render::{Denoiser, Device, ModeKind, Prepare, RenderMode, SceneEdit};
use meso_render::{Pass, RenderModeExt};
use rayon::prelude::*;

fn root() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
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
    for i in 0..n as u64 {
        let mut rng = SampleStream::new(&[42, i]);
        let target = lo + (hi - lo) * DVec3::new(rng.next(), rng.next(), rng.next());
        let dir = (target - eye).normalize();
        out.primary.push((eye, dir));
        if let Some(h) = bvh.closest_hit(eye, dir, 0.0, f64::INFINITY) {
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
    let one = single_thread();
    let n = 65_536;
    for (label, mesh) in [
        ("bunny 3.7k", &bunny),
        ("bunny 59k", &bunny59k),
        ("cloth 1.25M", &cloth1m),
    ] {
        let bvh = SceneBvh::build(std::slice::from_ref(mesh));
        let r = rays(mesh, &bvh, n);
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
                            .filter(|(o, d)| bvh.closest_hit(*o, *d, 0.0, f64::INFINITY).is_some())
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

/// A rayon pool of one thread, for the benches' "1 thread" figures.
fn single_thread() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool")
}

fn default_scene() -> Scene {
    load_scene(&root().join("tests/scenes/default.toml")).expect("default scene")
}

fn create(scene: meso_render::scene::Scene, size: u32) -> Box<dyn RenderMode> {
    meso_modes::create(
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
    let scene = default_scene();
    let one = single_thread();
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

fn bench_denoise(c: &mut Criterion) {
    let scene = default_scene();
    let one = single_thread();
    for size in [256u32, 512, 1024] {
        let mut mode = create(scene.clone(), size);
        mode.render_frame();
        let (image, guides) = (
            mode.image(),
            mode.guides(Pass::Frame).expect("the spmm mode has guides"),
        );
        let denoiser = Denoiser::for_samples(1);
        let mut group = c.benchmark_group(format!("denoise {size}x{size}"));
        group.sample_size(10);
        group.throughput(Throughput::Elements(u64::from(size * size)));
        for threads in ["1 thread", "all threads"] {
            let run = |f: &(dyn Fn() -> Option<meso_materials::image::Image> + Sync)| {
                if threads == "1 thread" {
                    one.install(f)
                } else {
                    f()
                }
            };
            group.bench_function(BenchmarkId::new("reference", threads), |b| {
                b.iter(|| run(&|| denoiser.apply_reference(&image, &guides)))
            });
            group.bench_function(BenchmarkId::new("fast", threads), |b| {
                b.iter(|| run(&|| denoiser.apply(&image, &guides)))
            });
            // The studio's first picture after an emission edit (guides halved as
            // the render thread does, each time).
            group.bench_function(BenchmarkId::new("halved", threads), |b| {
                b.iter(|| run(&|| denoiser.apply_halved(&image, &guides.halved())))
            });
        }
        group.finish();
    }
}

/// The default scene lit by `n` lights scattered over the floor instead of its own:
/// every tenth a small one-sided area light (alternately facing down and up), the rest
/// point lights; the total emission does not grow with `n`.
fn many_lights(n: usize) -> Scene {
    let mut scene = default_scene();
    let rng = SampleStream::new(&[77]);
    let u = |k: usize, d: u64| rng.at(k as u64 * 8 + d);
    scene.lights = (0..n)
        .map(|k| {
            let p = DVec3::new(
                -2.0 + 4.0 * u(k, 0),
                0.4 + 2.0 * u(k, 1),
                -2.0 + 4.0 * u(k, 2),
            );
            let colour = DVec3::new(0.5, 0.5, 0.5) + 0.5 * DVec3::new(u(k, 3), u(k, 4), u(k, 5));
            if k % 10 == 9 {
                let (a, b) = (DVec3::new(0.15, 0.0, 0.0), DVec3::new(0.0, 0.0, 0.15));
                let (edge_u, edge_v) = if k % 20 == 9 { (a, b) } else { (b, a) };
                Light::Area {
                    corner: p,
                    edge_u,
                    edge_v,
                    radiance: colour * (80.0 / n as f64),
                }
            } else {
                Light::Point {
                    position: p,
                    intensity: colour * (3.0 / n as f64),
                }
            }
        })
        .collect();
    scene
}

fn spmm(scene: Scene, size: u32, sampling: LightSampling) -> SpmmMode {
    let mut m = SpmmMode::new(scene, size, size).expect("fits");
    m.set_light_sampling(sampling);
    m
}

/// What the film took before the bounded layout: one layer per light.
fn per_light_bytes(size: u32, lights: usize) -> u64 {
    Film::bytes_for(size, size, 3 + lights)
}

fn bench_many_lights(c: &mut Criterion) {
    let mut group = c.benchmark_group("many lights 256x256");
    group.sample_size(10);
    group.warm_up_time(std::time::Duration::from_secs(1));
    group.measurement_time(std::time::Duration::from_secs(4));
    group.throughput(Throughput::Elements(256 * 256));
    for n in [1usize, 10, 100, 1000, 10_000] {
        let mut auto = spmm(many_lights(n), 256, LightSampling::Auto);
        eprintln!(
            "{n} lights: film {} bytes ({} layers), one layer per light would take {}",
            auto.film().bytes(),
            layer_count(auto.scene()),
            per_light_bytes(256, n)
        );
        group.bench_function(BenchmarkId::new("automatic", n), |b| {
            b.iter(|| auto.render_frame())
        });
        // Every light traced: what one frame cost before (the film is the bounded one).
        if n > 16 && n <= 1000 {
            let mut exact = spmm(many_lights(n), 256, LightSampling::Exact);
            group.bench_function(BenchmarkId::new("every light", n), |b| {
                b.iter(|| exact.render_frame())
            });
        }
    }
    group.finish();
}

/// Median seconds of `frames` frames.
fn frame_seconds(m: &mut SpmmMode, frames: u32) -> f64 {
    let mut t: Vec<f64> = (0..frames).map(|_| m.render_frame().seconds).collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// The table of docs/performance.md: frame time and film bytes against the number
/// of lights, then MSSIM and RMSE after equal time against a converged image.
fn many_lights_report() {
    println!(
        "lights | layers | film bytes | per-light film bytes | ms/frame automatic | ms/frame every light"
    );
    for n in [1usize, 10, 100, 1000, 10_000] {
        let mut auto = spmm(many_lights(n), 256, LightSampling::Auto);
        let ta = frame_seconds(&mut auto, 9);
        let te = if n <= 1000 {
            let mut exact = spmm(many_lights(n), 256, LightSampling::Exact);
            format!(
                "{:.1}",
                frame_seconds(&mut exact, if n > 100 { 3 } else { 9 }) * 1e3
            )
        } else {
            "-".into()
        };
        println!(
            "{n} | {} | {} | {} | {:.1} | {te}",
            auto.film().layers(),
            auto.film().bytes(),
            per_light_bytes(256, n),
            ta * 1e3
        );
    }
    let size = 128;
    let n = 1000;
    // Another seed: the reference shares no random number with the images measured.
    let mut reference_scene = many_lights(n);
    reference_scene.render.seed += 1;
    let mut reference = spmm(reference_scene, size, LightSampling::Auto);
    let frames = std::env::var("MESO_MANY_LIGHTS_REFERENCE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4096);
    for _ in 0..frames {
        reference.render_frame();
    }
    let reference = reference.image();
    println!("\n{n} lights at {size}x{size}, reference {frames} stochastic frames");
    println!("estimator | frames | seconds | RMSE | MSSIM");
    let mut exact = spmm(many_lights(n), size, LightSampling::Exact);
    let mut budget = 0.0;
    for f in 1..=4 {
        budget += exact.render_frame().seconds;
        let c =
            meso_materials::metrics::compare(&reference, &exact.image(), 0.0).expect("same size");
        println!(
            "every light | {f} | {budget:.2} | {:.4} | {:.4}",
            c.rmse, c.mssim
        );
    }
    let mut auto = spmm(many_lights(n), size, LightSampling::Auto);
    let (mut spent, mut frames, mut next) = (0.0, 0, budget / 4.0);
    while spent < budget {
        spent += auto.render_frame().seconds;
        frames += 1;
        if spent >= next || spent >= budget {
            let c = meso_materials::metrics::compare(&reference, &auto.image(), 0.0)
                .expect("same size");
            println!(
                "stochastic | {frames} | {spent:.2} | {:.4} | {:.4}",
                c.rmse, c.mssim
            );
            next += budget / 4.0;
        }
    }
}

criterion_group!(
    benches,
    bench_rays,
    bench_frames,
    bench_environment,
    bench_many_lights,
    bench_denoise
);

fn main() {
    if std::env::var_os("MESO_MANY_LIGHTS_REPORT").is_some() {
        many_lights_report();
        return;
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
}
