//! Shading-point evaluations per second of a realistic SPMM material (32 clusters, 9
//! bases per texel, N_PCA = 8 on the 81 x 81 Bonn direction layout), with the residual
//! on and off, on one thread and on all threads. The residual's values are half floats,
//! as a pack file stores them by default; the prepared evaluation also runs on the same
//! material with values that are not (a pack stored with `--f32`), whose tables stay
//! f32: the side-by-side figure of the half-float tables.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::DVec3;
use meso_core::brdf::{AnalyticBrdf, BasisFunction, BrdfModel, warp};
use meso_core::rng::SampleStream;
use meso_core::spmm::{Cluster, PrepareRequest, Residual, SparseWeights, SpmmMaterial};
use rayon::prelude::*;

const SIDE: u32 = 64;
const CLUSTERS: usize = 32;
const BASES: usize = 9;
const NPCA: usize = 8;
const POINTS: usize = 65_536;

/// The Bonn/UBO BTF layout: rings at 0..75 deg holding 1, 6, 12, 18, 20, 24 directions.
fn bonn_directions() -> Vec<DVec3> {
    let mut d = Vec::new();
    for (theta, count) in [
        (0.0f64, 1),
        (15.0, 6),
        (30.0, 12),
        (45.0, 18),
        (60.0, 20),
        (75.0, 24),
    ] {
        for k in 0..count {
            d.push(warp::spherical(
                theta.to_radians().cos(),
                2.0 * std::f64::consts::PI * k as f64 / count as f64,
            ));
        }
    }
    d
}

/// The bench's material; `half`: residual values rounded to half floats.
fn realistic_material(half: bool) -> SpmmMaterial {
    let u = |k: &[u64]| SampleStream::new(k).at(0);
    let model = |c: usize, j: usize| -> AnalyticBrdf {
        let r = |d: u64| u(&[c as u64, j as u64, d]);
        match (c + j) % 5 {
            0 => Ok(AnalyticBrdf::with_defaults(BrdfModel::Lambertian)),
            1 => AnalyticBrdf::new(
                BrdfModel::Ward,
                &[("ax", 0.05 + 0.3 * r(0)), ("ay", 0.05 + 0.3 * r(1))],
            ),
            2 => AnalyticBrdf::new(
                BrdfModel::CookTorrance,
                &[("m", 0.05 + 0.4 * r(0)), ("f0", 0.04)],
            ),
            3 => AnalyticBrdf::new(
                BrdfModel::AshikhminShirley,
                &[("nu", 10.0 + 500.0 * r(0)), ("nv", 10.0), ("rs", 0.3)],
            ),
            _ => AnalyticBrdf::new(BrdfModel::OrenNayar, &[("sigma", 0.5 * r(0))]),
        }
        .expect("valid parameters")
    };
    let clusters: Vec<Cluster> = (0..CLUSTERS)
        .map(|c| Cluster {
            bases: (0..BASES)
                .map(|j| {
                    let n = warp::spherical(
                        0.85 + 0.15 * u(&[c as u64, j as u64, 9]),
                        std::f64::consts::TAU * u(&[c as u64, j as u64, 8]),
                    );
                    BasisFunction::new(model(c, j), n).expect("unit normal")
                })
                .collect(),
        })
        .collect();
    let texels = (SIDE * SIDE) as usize;
    let texel_cluster: Vec<u32> = (0..texels).map(|t| (t * 31 % CLUSTERS) as u32).collect();
    let mut weights = SparseWeights {
        offsets: vec![0],
        ..Default::default()
    };
    for t in 0..texels {
        for j in 0..BASES {
            weights.basis.push(j as u16);
            weights
                .rgb
                .push([0.1, 0.08, 0.05].map(|w| w * (1.0 + u(&[t as u64, j as u64]) as f32)));
        }
        weights.offsets.push(weights.basis.len() as u32);
    }
    let dirs = bonn_directions();
    let table = dirs.len() * dirs.len() * 3;
    let noise = |n: usize, key: u64| -> Vec<f32> {
        (0..n)
            .map(|i| (u(&[key, i as u64]) - 0.5) as f32 * 0.02)
            .map(|x| {
                if half {
                    half::f16::from_f32(x).to_f32()
                } else {
                    x
                }
            })
            .collect()
    };
    let residual = Residual {
        light_dirs: dirs.clone(),
        view_dirs: dirs,
        npca: NPCA,
        mean: noise(CLUSTERS * table, 1),
        components: noise(CLUSTERS * NPCA * table, 2),
        coefficients: noise(texels * NPCA, 3),
    };
    SpmmMaterial::new(
        "bench".into(),
        "bench".into(),
        SIDE,
        SIDE,
        clusters,
        texel_cluster,
        weights,
        Some(residual),
    )
    .expect("valid material")
}

fn shading_points() -> Vec<(usize, DVec3, DVec3)> {
    (0..POINTS as u64)
        .map(|k| {
            let mut s = SampleStream::new(&[77, k]);
            let t = (s.next() * (SIDE * SIDE) as f64) as usize;
            (
                t,
                warp::cosine_hemisphere(s.next_2d()),
                warp::cosine_hemisphere(s.next_2d()),
            )
        })
        .collect()
}

fn bench_eval(c: &mut Criterion) {
    let m = realistic_material(true);
    let points = shading_points();
    let mut group = c.benchmark_group("spmm_eval");
    group.throughput(Throughput::Elements(POINTS as u64));
    group.sample_size(10);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    for residual in [false, true] {
        let label = if residual {
            "residual on"
        } else {
            "residual off"
        };
        let run = || {
            points
                .par_iter()
                .map(|&(t, wi, wo)| m.eval_texel(t, black_box(wi), black_box(wo), residual, NPCA))
                .reduce(|| DVec3::ZERO, |a, b| a + b)
        };
        group.bench_function(format!("{label}, 1 thread"), |b| {
            b.iter(|| one.install(run))
        });
        group.bench_function(format!("{label}, all threads"), |b| b.iter(run));
    }
    // The prepared data (cell-major residual layout) against the reference layout, with
    // half-float tables and with f32 ones.
    let single = realistic_material(false);
    for (material, tables) in [(&m, "half"), (&single, "f32")] {
        let prepared = material.prepare(&PrepareRequest {
            used_clusters: None,
            residual: true,
            max_npca: NPCA,
        });
        let run = || {
            points
                .par_iter()
                .map(|&(t, wi, wo)| prepared.eval_texel(t, black_box(wi), black_box(wo)))
                .reduce(|| DVec3::ZERO, |a, b| a + b)
        };
        group.bench_function(
            format!("prepared, residual on, {tables} tables, 1 thread"),
            |b| b.iter(|| one.install(run)),
        );
        group.bench_function(
            format!("prepared, residual on, {tables} tables, all threads"),
            |b| b.iter(run),
        );
    }
    group.finish();
}

criterion_group!(benches, bench_eval);
criterion_main!(benches);
