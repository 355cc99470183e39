//! `meso bench rays MESH.obj [--size 512] [--threads N] [--json]` (docs/cli.md):
//! closest-hit throughput of the tracer's BVH without shading, on rays the spec fixes
//! so other tracers can be measured on the same rays. Coherent: one ray through each
//! pixel centre of a `size` x `size` pinhole camera at c + (0, 0.3, 1.6) r looking at
//! c (c the bounding box's centre, r its diagonal, 40 degrees vertical field, +y up).
//! Incoherent: as many rays from uniform points of uniformly chosen triangles,
//! uniform over the hemisphere of the face normal, offset by 1e-4 r. Rays are made
//! before timing; each kind is traced three times and the fastest run is reported.
//! `--baseline` also traces with obvhs's own traversal, alternating with the tracer's
//! so both see the same machine load; `--embree LIB` does the same with Embree 4 loaded
//! from LIB (`embree.rs`), so the ratio to Embree comes from one process; `--save-rays
//! DIR` writes the triangles, the rays and the tracer's hit distances as raw
//! little-endian f32 for other tracers.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::anyhow;
use clap::{Args, Subcommand};
use glam::{DMat3, DVec2, DVec3};
use meso_materials::brdf::warp;
use meso_materials::rng::SampleStream;
use meso_render::geometry::{PinholeCamera, SceneBvh};
use meso_render::scene::mesh::{Placement, load_obj};
use meso_render::scene::{Camera, TriangleMesh};
use rayon::prelude::*;
use serde_json::json;

use crate::embree::Embree;
use crate::failure::CliError;

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Closest-hit rays per second on a mesh, coherent and incoherent.
    Rays(RaysArgs),
    /// Weight-brush stroke to updated frame latency on a scene's SPMM material.
    Stroke(crate::bench_stroke::StrokeArgs),
    /// The spmm mode's frame time on the CPU and the GPU side by side.
    Frames(crate::bench_frames::FramesArgs),
    /// Edit-to-frame time of each edit kind as the studio renders, without a window.
    Edits(crate::bench_edits::EditsArgs),
    /// A scene's btf materials rendered held whole and out of core, side by side.
    Btf(crate::bench_btf::BtfArgs),
}

#[derive(Args, Debug)]
pub struct RaysArgs {
    /// The mesh (Wavefront OBJ), used as it is in the file.
    mesh: PathBuf,
    /// Side of the coherent camera's image; as many incoherent rays as its pixels.
    #[arg(long, default_value_t = 512)]
    size: u32,
    /// Threads (default: all).
    #[arg(long)]
    threads: Option<usize>,
    #[arg(long)]
    json: bool,
    /// Also trace with obvhs's own CWBVH traversal (the previous tracer), alternating.
    #[arg(long)]
    baseline: bool,
    /// Write triangles.f32 (9 floats each), coherent.f32 and incoherent.f32 (origin,
    /// direction: 6 floats per ray) and *_t.f32 (hit distance, inf on a miss) to DIR.
    #[arg(long, value_name = "DIR")]
    save_rays: Option<PathBuf>,
    /// Also trace with Embree 4 (`rtcIntersect1`, one ray at a time, on the same
    /// threads), loaded from this shared library (e.g. libembree4.so.4), alternating.
    #[arg(long, value_name = "LIB")]
    embree: Option<PathBuf>,
}

pub fn run(command: BenchCommand) -> Result<(), CliError> {
    match command {
        BenchCommand::Rays(args) => rays(&args),
        BenchCommand::Stroke(args) => crate::bench_stroke::run(&args),
        BenchCommand::Frames(args) => crate::bench_frames::run(&args),
        BenchCommand::Edits(args) => crate::bench_edits::run(&args),
        BenchCommand::Btf(args) => crate::bench_btf::run(&args),
    }
}

/// Rays as (origin, unit direction).
type Rays = Vec<(DVec3, DVec3)>;

fn coherent_rays(centre: DVec3, diagonal: f64, size: u32) -> Rays {
    let camera = Camera {
        position: centre + DVec3::new(0.0, 0.3, 1.6) * diagonal,
        look_at: centre,
        up: DVec3::Y,
        fov_y_deg: 40.0,
    };
    let pinhole = PinholeCamera::new(&camera, size, size);
    (0..size)
        .flat_map(|y| (0..size).map(move |x| (x, y)))
        .map(|(x, y)| {
            let r = pinhole.ray(x, y, DVec2::splat(0.5));
            (r.origin, r.dir)
        })
        .collect()
}

fn incoherent_rays(mesh: &TriangleMesh, diagonal: f64, count: usize) -> Rays {
    // Only proper triangles can give a point and a face normal.
    let faces: Vec<[DVec3; 3]> = mesh
        .indices
        .iter()
        .map(|t| t.map(|i| mesh.positions[i as usize]))
        .filter(|[a, b, c]| (*b - *a).cross(*c - *a).length_squared() > 0.0)
        .collect();
    (0..count as u64)
        .map(|i| {
            let mut rng = SampleStream::new(&[0x8a7e, i]);
            let pick = rng.next_2d();
            let [a, b, c] = faces[((pick.x * faces.len() as f64) as usize).min(faces.len() - 1)];
            // Uniform on the triangle: the square-root warp of two uniforms.
            let u = rng.next_2d();
            let s = u.x.sqrt();
            let p = a * (1.0 - s) + b * (s * (1.0 - u.y)) + c * (s * u.y);
            let n = (b - a).cross(c - a).normalize();
            // Uniform over the hemisphere: cos theta uniform in [0, 1).
            let h = rng.next_2d();
            let (z, phi) = (h.x, std::f64::consts::TAU * h.y);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let (t, bt) = warp::orthonormal_basis(n);
            let dir = t * (r * phi.cos()) + bt * (r * phi.sin()) + n * z;
            (p + n * (1e-4 * diagonal), dir)
        })
        .collect()
}

/// Which traversal a run times.
#[derive(Clone, Copy)]
enum Tracer<'a> {
    /// The tracer's own (what rendering uses).
    Cpu,
    /// obvhs's CWBVH traversal (`--baseline`).
    Obvhs,
    /// Embree 4 (`--embree`) on the rays in f32, as it takes them.
    Embree(&'a Embree, &'a [([f32; 3], [f32; 3])]),
}

/// The tracer first, then obvhs's traversal and Embree where asked (Embree's rays in
/// f32), in the order `trace` alternates them.
fn tracers<'a>(
    baseline: bool,
    embree: Option<&'a Embree>,
    embree_rays: Option<&'a [([f32; 3], [f32; 3])]>,
) -> Vec<Tracer<'a>> {
    let mut t = vec![Tracer::Cpu];
    if baseline {
        t.push(Tracer::Obvhs);
    }
    if let (Some(e), Some(rays)) = (embree, embree_rays) {
        t.push(Tracer::Embree(e, rays));
    }
    t
}

/// Traces every ray once; returns (seconds, rays that hit).
fn trace_once(bvh: &SceneBvh, rays: &Rays, tracer: Tracer) -> (f64, usize) {
    let start = Instant::now();
    let hits = match tracer {
        Tracer::Cpu => rays
            .par_iter()
            .filter(|(o, d)| bvh.closest_hit(*o, *d, 0.0, f64::INFINITY).is_some())
            .count(),
        Tracer::Obvhs => rays
            .par_iter()
            .filter(|(o, d)| {
                bvh.closest_hit_reference(*o, *d, 0.0, f64::INFINITY)
                    .is_some()
            })
            .count(),
        Tracer::Embree(embree, rays) => rays
            .par_iter()
            .filter(|(o, d)| embree.closest(*o, *d).is_some())
            .count(),
    };
    (start.elapsed().as_secs_f64(), hits)
}

/// Traces every ray three times with each tracer, alternating; per tracer (fastest
/// Mrays/s, rays that hit).
fn trace(bvh: &SceneBvh, rays: &Rays, tracers: &[Tracer]) -> Vec<(f64, usize)> {
    let mut best = vec![(f64::INFINITY, 0); tracers.len()];
    for _ in 0..3 {
        for (b, &tracer) in best.iter_mut().zip(tracers) {
            let (seconds, hits) = trace_once(bvh, rays, tracer);
            *b = (b.0.min(seconds), hits);
        }
    }
    best.into_iter()
        .map(|(seconds, hits)| (rays.len() as f64 / seconds.max(1e-12) / 1e6, hits))
        .collect()
}

fn f32s(v: DVec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// The fraction of rays on which Embree and the tracer agree: both miss, or both hit
/// within 1e-4 of the tracer's distance (Embree's triangle test is not
/// Moller-Trumbore, so rays through a silhouette or an edge may differ).
fn agreement(bvh: &SceneBvh, embree: &Embree, rays: &Rays) -> f64 {
    let agree = rays
        .par_iter()
        .filter(|(o, d)| {
            let ours = bvh
                .closest_hit(*o, *d, 0.0, f64::INFINITY)
                .map(|h| h.t as f32);
            match (ours, embree.closest(f32s(*o), f32s(*d))) {
                (None, None) => true,
                (Some(a), Some(b)) => (a - b).abs() <= 1e-4 * a,
                _ => false,
            }
        })
        .count();
    agree as f64 / rays.len() as f64
}

/// `--save-rays`: the BVH's triangles, both kinds of rays and the tracer's hit
/// distances, as raw little-endian f32.
fn save_rays(
    dir: &std::path::Path,
    bvh: &SceneBvh,
    kinds: [(&str, &Rays); 2],
) -> Result<(), CliError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::bad_input(anyhow!("cannot create `{}`: {e}", dir.display())))?;
    let write = |name: &str, floats: Vec<f32>| {
        let bytes: Vec<u8> = floats.iter().flat_map(|f| f.to_le_bytes()).collect();
        meso_materials::atomic::write_bytes_atomic(&dir.join(name), &bytes)
            .map_err(|e| CliError::failure(anyhow!(e)))
    };
    write(
        "triangles.f32",
        bvh.primitives()
            .flat_map(|(t, _)| [t.v0, t.v1, t.v2].into_iter().flat_map(|v| v.to_array()))
            .collect(),
    )?;
    for (kind, rays) in kinds {
        write(
            &format!("{kind}.f32"),
            rays.iter()
                .flat_map(|(o, d)| f32s(*o).into_iter().chain(f32s(*d)))
                .collect(),
        )?;
        write(
            &format!("{kind}_t.f32"),
            rays.iter()
                .map(|(o, d)| {
                    bvh.closest_hit(*o, *d, 0.0, f64::INFINITY)
                        .map_or(f32::INFINITY, |h| h.t as f32)
                })
                .collect(),
        )?;
    }
    Ok(())
}

fn rays(args: &RaysArgs) -> Result<(), CliError> {
    if !(1..=8192).contains(&args.size) {
        return Err(CliError::bad_input(anyhow!(
            "--size {} is outside [1, 8192]",
            args.size
        )));
    }
    if args.threads == Some(0) {
        return Err(CliError::bad_input(anyhow!("--threads must be at least 1")));
    }
    let (mesh, centre, diagonal) = load_mesh(&args.mesh)?;
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = args.threads {
        pool = pool.num_threads(n);
    }
    let pool = pool
        .build()
        .map_err(|e| CliError::failure(anyhow!("cannot start the threads: {e}")))?;
    let meshes = std::slice::from_ref(&mesh);
    let bvh = SceneBvh::build(meshes);
    let (triangles, _) = bvh.triangle_counts();
    if triangles == 0 {
        return Err(CliError::bad_input(anyhow!(
            "`{}`: every triangle is degenerate",
            args.mesh.display()
        )));
    }
    let n = args.size as usize * args.size as usize;
    let coherent = coherent_rays(centre, diagonal, args.size);
    let incoherent = incoherent_rays(&mesh, diagonal, n);
    if let Some(dir) = &args.save_rays {
        save_rays(
            dir,
            &bvh,
            [("coherent", &coherent), ("incoherent", &incoherent)],
        )?;
    }
    let embree = match &args.embree {
        Some(path) => {
            let triangles: Vec<[[f32; 3]; 3]> = bvh
                .primitives()
                .map(|(t, _)| [t.v0, t.v1, t.v2].map(|v| v.to_array()))
                .collect();
            Some(Embree::load(path, &triangles).map_err(CliError::bad_input)?)
        }
        None => None,
    };
    let as_f32 = |rays: &Rays| -> Vec<([f32; 3], [f32; 3])> {
        rays.iter().map(|(o, d)| (f32s(*o), f32s(*d))).collect()
    };
    let embree_rays = embree
        .as_ref()
        .map(|_| (as_f32(&coherent), as_f32(&incoherent)));
    if args.baseline {
        // obvhs's CWBVH is made on first use: make it now, outside the timed runs.
        bvh.nodes();
    }
    let (coherent_runs, incoherent_runs) = pool.install(|| {
        let (c, i) = embree_rays
            .as_ref()
            .map(|(c, i)| (c.as_slice(), i.as_slice()))
            .unzip();
        (
            trace(&bvh, &coherent, &tracers(args.baseline, embree.as_ref(), c)),
            trace(
                &bvh,
                &incoherent,
                &tracers(args.baseline, embree.as_ref(), i),
            ),
        )
    });
    // Embree's runs, and on how many rays its hits agree with the tracer's.
    let embree_runs = embree.as_ref().map(|e| {
        let last = coherent_runs.len() - 1;
        pool.install(|| {
            (
                (coherent_runs[last], agreement(&bvh, e, &coherent)),
                (incoherent_runs[last], agreement(&bvh, e, &incoherent)),
            )
        })
    });
    let measured = Measured {
        triangles,
        rays_per_kind: n,
        threads: pool.current_num_threads(),
        build_ms: bvh.build_time().as_secs_f64() * 1e3,
        coherent: coherent_runs[0],
        incoherent: incoherent_runs[0],
        baseline: args
            .baseline
            .then(|| (coherent_runs[1], incoherent_runs[1])),
        embree: embree.as_ref().zip(embree_runs),
    };
    if args.json {
        return crate::print_json(&rays_json(args, &measured));
    }
    print_rays(args, &measured);
    Ok(())
}

/// The mesh of `path` as it is in the file, with its bounding box's centre and
/// diagonal (what the rays are placed by); a mesh without extent is refused.
fn load_mesh(path: &std::path::Path) -> Result<(TriangleMesh, DVec3, f64), CliError> {
    let placement = Placement {
        scale: 1.0,
        rotation: DMat3::IDENTITY,
        translate: DVec3::ZERO,
    };
    let mesh = load_obj(path, &placement, 0).map_err(CliError::bad_input)?;
    let (lo, hi) = mesh.positions.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let (centre, diagonal) = ((lo + hi) * 0.5, (hi - lo).length());
    if diagonal.is_nan() || diagonal <= 0.0 {
        return Err(CliError::bad_input(anyhow!(
            "`{}`: the mesh has no extent",
            path.display()
        )));
    }
    Ok((mesh, centre, diagonal))
}

/// One tracer's result on one kind of rays: (Mrays/s, rays that hit).
type Run = (f64, usize);

/// An Embree run and the fraction of the rays on which its hits agree with the tracer's.
type Agreed = (Run, f64);

/// What `bench rays` measured, for its report.
struct Measured<'a> {
    triangles: usize,
    rays_per_kind: usize,
    threads: usize,
    build_ms: f64,
    /// The tracer's own runs.
    coherent: Run,
    incoherent: Run,
    /// obvhs's traversal (`--baseline`): coherent, incoherent.
    baseline: Option<(Run, Run)>,
    /// Embree (`--embree`) and its runs with their agreement with the tracer's hits:
    /// coherent, incoherent.
    embree: Option<(&'a Embree, (Agreed, Agreed))>,
}

impl Measured<'_> {
    /// The fraction of one kind's rays that `hits` is.
    fn fraction(&self, hits: usize) -> f64 {
        hits as f64 / self.rays_per_kind as f64
    }
}

/// The `--json` report of `bench rays`.
fn rays_json(args: &RaysArgs, m: &Measured) -> serde_json::Value {
    let ((coherent_mrays, coherent_hits), (incoherent_mrays, incoherent_hits)) =
        (m.coherent, m.incoherent);
    let fraction = |hits: usize| m.fraction(hits);
    let mut report = json!({
        "mesh": args.mesh.display().to_string(),
        "triangles": m.triangles,
        "size": args.size,
        "rays_per_kind": m.rays_per_kind,
        "threads": m.threads,
        "build_ms": m.build_ms,
        "coherent_mrays": coherent_mrays,
        "incoherent_mrays": incoherent_mrays,
        "coherent_hit_fraction": fraction(coherent_hits),
        "incoherent_hit_fraction": fraction(incoherent_hits),
    });
    if let Some(((c, c_hits), (i, i_hits))) = m.baseline {
        report["baseline_coherent_mrays"] = json!(c);
        report["baseline_incoherent_mrays"] = json!(i);
        report["baseline_coherent_hit_fraction"] = json!(fraction(c_hits));
        report["baseline_incoherent_hit_fraction"] = json!(fraction(i_hits));
    }
    if let Some((e, ((c, c_agree), (i, i_agree)))) = m.embree {
        report["embree_version"] = json!(e.version);
        report["embree_build_ms"] = json!(e.build_ms);
        for (kind, (mrays, hits), agree, ours) in [
            ("coherent", c, c_agree, coherent_mrays),
            ("incoherent", i, i_agree, incoherent_mrays),
        ] {
            report[format!("embree_{kind}_mrays")] = json!(mrays);
            report[format!("embree_{kind}_hit_fraction")] = json!(fraction(hits));
            report[format!("embree_{kind}_agreement")] = json!(agree);
            report[format!("{kind}_over_embree")] = json!(ours / mrays);
        }
    }
    report
}

/// The text report of `bench rays`: the tracer, then obvhs's traversal and Embree
/// where asked, with the tracer's speed-up over each.
fn print_rays(args: &RaysArgs, m: &Measured) {
    let ((coherent_mrays, coherent_hits), (incoherent_mrays, incoherent_hits)) =
        (m.coherent, m.incoherent);
    let fraction = |hits: usize| m.fraction(hits);
    let (triangles, build_ms, n, threads) = (m.triangles, m.build_ms, m.rays_per_kind, m.threads);
    println!(
        "{}: {triangles} triangles, BVH built in {build_ms:.1} ms; {n} rays per kind on {threads} threads: coherent {coherent_mrays:.2} Mrays/s ({:.0}% hit), incoherent {incoherent_mrays:.2} Mrays/s ({:.0}% hit)",
        args.mesh.display(),
        100.0 * fraction(coherent_hits),
        100.0 * fraction(incoherent_hits),
    );
    if let Some(((c, c_hits), (i, i_hits))) = m.baseline {
        println!(
            "baseline (obvhs traversal): coherent {c:.2} Mrays/s ({:.0}% hit), incoherent {i:.2} Mrays/s ({:.0}% hit); speed-up {:.2}x coherent, {:.2}x incoherent",
            100.0 * fraction(c_hits),
            100.0 * fraction(i_hits),
            coherent_mrays / c,
            incoherent_mrays / i,
        );
    }
    if let Some((e, (((c, _), c_agree), ((i, _), i_agree)))) = m.embree {
        println!(
            "Embree {} (built in {:.1} ms): coherent {c:.2} Mrays/s, incoherent {i:.2} Mrays/s; the tracer / Embree: {:.2}x coherent, {:.2}x incoherent; hits agree on {:.4}% and {:.4}% of the rays",
            e.version,
            e.build_ms,
            coherent_mrays / c,
            incoherent_mrays / i,
            100.0 * c_agree,
            100.0 * i_agree,
        );
    }
}
