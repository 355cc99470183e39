//! Cost of evaluating the analytic dictionary: ns per `eval` for each model, and a
//! 9-term SPMM-like basis sum (mixed models, each on its own normal, RGB weights), the
//! inner loop of shading an SPMM texel.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::{DVec3, Vec3};
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel, warp};
use meso_materials::rng::SampleStream;

const PAIRS: usize = 1024;

fn direction_pairs() -> Vec<(DVec3, DVec3)> {
    (0..PAIRS as u64)
        .map(|k| {
            let mut s = SampleStream::new(&[42, k]);
            let wi = warp::cosine_hemisphere(s.next_2d());
            let wo = warp::cosine_hemisphere(s.next_2d());
            (wi, wo)
        })
        .collect()
}

fn bench_models(c: &mut Criterion) {
    let pairs = direction_pairs();
    let mut group = c.benchmark_group("eval");
    group.throughput(Throughput::Elements(PAIRS as u64));
    for model in BrdfModel::ALL {
        let brdf = AnalyticBrdf::with_defaults(model);
        group.bench_function(model.name(), |b| {
            b.iter(|| {
                let mut sum = 0.0;
                for &(wi, wo) in &pairs {
                    sum += brdf.eval(black_box(wi), black_box(wo));
                }
                sum
            })
        });
    }
    group.finish();
}

fn nine_term_basis() -> Vec<(BasisFunction, Vec3)> {
    let make = |model: BrdfModel, params: &[(&str, f64)]| {
        AnalyticBrdf::new(model, params).expect("valid parameters")
    };
    let brdfs = [
        make(BrdfModel::Lambertian, &[]),
        make(BrdfModel::OrenNayar, &[("sigma", 0.4)]),
        make(BrdfModel::Ward, &[("ax", 0.1), ("ay", 0.4)]),
        make(BrdfModel::Ward, &[("ax", 0.3), ("ay", 0.05)]),
        make(BrdfModel::CookTorrance, &[("m", 0.2), ("f0", 0.04)]),
        make(BrdfModel::BlinnPhong, &[("n", 80.0)]),
        make(
            BrdfModel::AshikhminShirley,
            &[("nu", 200.0), ("nv", 20.0), ("rs", 0.3)],
        ),
        make(
            BrdfModel::Lafortune,
            &[("cx", -1.0), ("cy", -0.8), ("cz", 0.9), ("n", 15.0)],
        ),
        make(BrdfModel::CookTorrance, &[("m", 0.05), ("f0", 0.9)]),
    ];
    brdfs
        .into_iter()
        .enumerate()
        .map(|(j, brdf)| {
            let normal = warp::spherical(0.85 + 0.015 * j as f64, 0.7 * j as f64);
            let weight = Vec3::new(0.1 + 0.02 * j as f32, 0.12, 0.3 - 0.02 * j as f32);
            (
                BasisFunction::new(brdf, normal).expect("unit normal"),
                weight,
            )
        })
        .collect()
}

fn bench_basis_sum(c: &mut Criterion) {
    let pairs = direction_pairs();
    let basis = nine_term_basis();
    let mut group = c.benchmark_group("spmm_basis_sum");
    group.throughput(Throughput::Elements(PAIRS as u64));
    group.bench_function("9 terms, RGB", |b| {
        b.iter(|| {
            let mut total = Vec3::ZERO;
            for &(wi, wo) in &pairs {
                for (rho, weight) in &basis {
                    total += *weight * rho.eval(black_box(wi), black_box(wo)) as f32;
                }
            }
            total
        })
    });
    group.finish();
}

criterion_group!(benches, bench_models, bench_basis_sum);
criterion_main!(benches);
