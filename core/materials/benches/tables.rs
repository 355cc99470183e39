//! The table lookups of a MERL or environment sample, each against the way it was done
//! before, in one process (docs/performance.md, "Table lookups"):
//! - `atan2`: libm's against `angle::atan2`;
//! - `merl_angles`: the Rusinkiewicz angles of a direction pair (three atan2 and a
//!   hypot), with libm's functions as before and as `HalfDiff::from_directions` now;
//! - `cdf_find`: inverting the CDF rows of a real table by binary search and through
//!   `cdf`'s guide tables: the MERL sampler's column CDFs of the dragon's jade (a
//!   Blinn-Phong n = 150 tabulated, 2,880 rows of 128 bins, 3 MB) and the sky map's
//!   rows (256 rows of 512 pixels, 1 MB).

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel, warp};
use meso_materials::cdf;
use meso_materials::merl::HalfDiff;
use meso_materials::merl::tabulate;
use meso_materials::rng::SampleStream;

const QUERIES: usize = 4096;

fn numbers(seed: u64, n: usize) -> Vec<f64> {
    let rng = SampleStream::new(&[seed]);
    (0..n as u64).map(|k| rng.at(k)).collect()
}

fn bench_atan2(c: &mut Criterion) {
    let u = numbers(1, 2 * QUERIES);
    let args: Vec<(f64, f64)> = u
        .chunks_exact(2)
        .map(|p| (p[0] - 0.5, p[1] - 0.5))
        .collect();
    let mut group = c.benchmark_group("atan2");
    group.throughput(Throughput::Elements(QUERIES as u64));
    group.bench_function("libm", |b| {
        b.iter(|| {
            args.iter()
                .map(|&(y, x)| black_box(y).atan2(x))
                .sum::<f64>()
        })
    });
    group.bench_function("polynomial", |b| {
        b.iter(|| {
            args.iter()
                .map(|&(y, x)| meso_materials::angle::atan2(black_box(y), x))
                .sum::<f64>()
        })
    });
    group.finish();
}

/// The Rusinkiewicz angles as the lookup computed them before the fast atan2.
fn half_diff_libm(wi: DVec3, wo: DVec3) -> [f64; 3] {
    let s = wi + wo;
    let d = wi - wo;
    let s_len = s.length();
    let s_xy = s.x.hypot(s.y);
    let theta_h = s_xy.atan2(s.z);
    let theta_d = d.length().atan2(s_len);
    let (cos_ph, sin_ph) = if s_xy > 0.0 {
        (s.x / s_xy, s.y / s_xy)
    } else {
        (1.0, 0.0)
    };
    let (cos_th, sin_th) = (s.z / s_len, s_xy / s_len);
    let mut x = cos_th * (cos_ph * d.x + sin_ph * d.y) - sin_th * d.z;
    let mut y = cos_ph * d.y - sin_ph * d.x;
    if y < 0.0 || (y == 0.0 && x < 0.0) {
        x = -x;
        y = -y;
    }
    [theta_h, theta_d, y.abs().atan2(x)]
}

fn bench_merl_angles(c: &mut Criterion) {
    let u = numbers(2, 4 * QUERIES);
    let pairs: Vec<(DVec3, DVec3)> = u
        .chunks_exact(4)
        .map(|p| {
            (
                warp::cosine_hemisphere(glam::DVec2::new(p[0], p[1])),
                warp::cosine_hemisphere(glam::DVec2::new(p[2], p[3])),
            )
        })
        .collect();
    let mut group = c.benchmark_group("merl_angles");
    group.throughput(Throughput::Elements(QUERIES as u64));
    group.bench_function("libm", |b| {
        b.iter(|| {
            pairs
                .iter()
                .map(|&(wi, wo)| half_diff_libm(black_box(wi), wo)[2])
                .sum::<f64>()
        })
    });
    group.bench_function("polynomial", |b| {
        b.iter(|| {
            pairs
                .iter()
                .map(|&(wi, wo)| HalfDiff::from_directions(black_box(wi), wo).phi_d)
                .sum::<f64>()
        })
    });
    group.finish();
}

/// Normalised CDFs (each `bins + 1` entries) of `rows` rows of `weights`.
fn cdf_rows(weights: &[f64], bins: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(weights.len() / bins * (bins + 1));
    for row in weights.chunks_exact(bins) {
        let total: f64 = row.iter().sum();
        let mut acc = 0.0;
        out.push(0.0);
        for w in row {
            acc += w;
            out.push(if total > 0.0 { acc / total } else { 0.0 });
        }
    }
    out
}

/// Random (row, u) queries on `cdfs` (rows of `bins + 1`), by binary search and by
/// guide tables of `bins` entries per row.
fn bench_rows(c: &mut Criterion, name: &str, cdfs: &[f64], bins: usize) {
    let rows = cdfs.len() / (bins + 1);
    let mut guides = Vec::with_capacity(rows * bins);
    for row in cdfs.chunks_exact(bins + 1) {
        cdf::build_guide(row, bins, &mut guides);
    }
    let u = numbers(3, 2 * QUERIES);
    let queries: Vec<(usize, f64)> = u
        .chunks_exact(2)
        .map(|p| (((p[0] * rows as f64) as usize).min(rows - 1), p[1]))
        .collect();
    let row = |r: usize| &cdfs[r * (bins + 1)..(r + 1) * (bins + 1)];
    let mut group = c.benchmark_group(format!("cdf_find/{name}"));
    group.throughput(Throughput::Elements(QUERIES as u64));
    group.bench_function("binary search", |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|&(r, u)| row(r)[1..].partition_point(|&c| c <= black_box(u)))
                .sum::<usize>()
        })
    });
    group.bench_function("guide table", |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|&(r, u)| cdf::find(row(r), &guides[r * bins..(r + 1) * bins], black_box(u)))
                .sum::<usize>()
        })
    });
    group.finish();
}

fn bench_cdf_find(c: &mut Criterion) {
    let jade = AnalyticBrdf::new(BrdfModel::BlinnPhong, &[("n", 150.0)]).expect("in range");
    let merl = tabulate(&jade, DVec3::new(0.25, 0.7, 0.4)).expect("finite");
    let (cell_prob, _, _) = merl.sampler().tables();
    bench_rows(c, "merl_jade", &cdf_rows(cell_prob, 128), 128);
    let sky = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../materials/env/env_sky.exr"
    );
    let map = meso_materials::image::read_image(std::path::Path::new(sky)).expect("the sky map");
    let luminance: Vec<f64> = map
        .pixels()
        .iter()
        .map(|p| f64::from(meso_materials::image::luminance(*p)))
        .collect();
    bench_rows(
        c,
        "sky",
        &cdf_rows(&luminance, map.width() as usize),
        map.width() as usize,
    );
}

criterion_group!(benches, bench_atan2, bench_merl_angles, bench_cdf_find);
criterion_main!(benches);
