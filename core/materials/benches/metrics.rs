//! Cost of `meso compare`'s metrics (RMSE, PSNR, MSSIM, max error) on a 1024x1024
//! pair: regression reports compare many renders, so this must stay well under a second.

use criterion::{Criterion, criterion_group, criterion_main};
use meso_materials::image::Image;
use meso_materials::metrics::compare;
use std::hint::black_box;

fn pair(n: u32) -> (Image, Image) {
    let pixels: Vec<[f32; 3]> = (0..n * n)
        .map(|i| {
            let t = i as f32 * 1e-3;
            [t.sin().abs(), t.cos().abs(), (0.3 * t).sin().abs()]
        })
        .collect();
    let a = Image::from_pixels(n, n, pixels).expect("n * n pixels");
    let mut b = a.clone();
    for (i, p) in b.pixels_mut().iter_mut().enumerate() {
        p[1] += if i % 7 == 0 { 0.05 } else { -0.01 };
    }
    (a, b)
}

fn bench_compare(c: &mut Criterion) {
    let (a, b) = pair(1024);
    c.bench_function("compare 1024x1024 (all threads)", |bench| {
        bench.iter(|| compare(black_box(&a), black_box(&b), 0.0).expect("same size"))
    });
}

criterion_group!(benches, bench_compare);
criterion_main!(benches);
