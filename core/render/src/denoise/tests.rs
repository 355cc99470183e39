//! The denoiser's tests: smoothing, edges, the halved filter, stopping, the
//! polynomial exp, and the vectorised rows against the portable ones and the reference.

use meso_materials::image::Image;

use super::planar::{Planar, PlanarGuides, RowPass};
use super::polynomial_exp::exp_neg;
use super::reference::compress;
use super::*;

fn flat_guides(w: u32, h: u32) -> Guides {
    let n = (w * h) as usize;
    Guides {
        width: w,
        height: h,
        normal: vec![[0.0, 0.0, 1.0]; n],
        depth: vec![1.0; n],
        albedo: vec![[0.5; 3]; n],
    }
}

fn noisy(w: u32, h: u32, level: f32, amplitude: f32) -> Image {
    let mut img = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let u =
                meso_materials::rng::SampleStream::new(&[u64::from(x), u64::from(y)]).at(0) as f32;
            img.set(x, y, [level + amplitude * (u - 0.5) * 2.0; 3]);
        }
    }
    img
}

fn rms(img: &Image, level: f32) -> f32 {
    (img.pixels()
        .iter()
        .map(|p| (p[0] - level).powi(2))
        .sum::<f32>()
        / img.pixels().len() as f32)
        .sqrt()
}

#[test]
fn noise_on_one_flat_surface_is_smoothed_and_its_level_kept() {
    let img = noisy(64, 64, 0.5, 0.2);
    let out = Denoiser::default()
        .apply(&img, &flat_guides(64, 64))
        .expect("sizes match");
    let (before, after) = (rms(&img, 0.5), rms(&out, 0.5));
    // Uniform noise of amplitude 0.2 has RMS 0.115; the filter must cut it by 4x.
    assert!(after < before / 4.0, "{before} -> {after}");
    let mean = out.pixels().iter().map(|p| p[0]).sum::<f32>() / 4096.0;
    assert!((mean - 0.5).abs() < 0.01, "mean {mean}");
}

#[test]
fn the_halved_filter_smooths_keeps_the_level_and_keeps_edges_within_two_pixels() {
    let (w, h) = (65u32, 48u32);
    let d = Denoiser::for_samples(1);
    // Noise on one flat surface: smoothed, its level kept.
    let img = noisy(w, h, 0.5, 0.2);
    let g = flat_guides(w, h);
    assert_eq!((g.halved().width, g.halved().height), (33, 24));
    let out = d.apply_halved(&img, &g.halved()).expect("sizes match");
    assert_eq!((out.width(), out.height()), (w, h));
    let (before, after) = (rms(&img, 0.5), rms(&out, 0.5));
    assert!(after < before / 4.0, "{before} -> {after}");
    assert!(
        d.apply_halved(&img, &g).is_none(),
        "full-size guides refused"
    );
    // A step at a depth edge (x = 30): pixels two or more away keep their side.
    let mut step = Image::new(w, h);
    let mut g = flat_guides(w, h);
    for y in 0..h {
        for x in 0..w {
            step.set(x, y, [if x < 30 { 0.2 } else { 0.8 }; 3]);
            if x >= 30 {
                g.depth[(y * w + x) as usize] = 2.0;
            }
        }
    }
    let out = d.apply_halved(&step, &g.halved()).expect("sizes match");
    for y in 0..h {
        for x in (0..28).chain(32..w) {
            let want = if x < 30 { 0.2 } else { 0.8 };
            let got = out.get(x, y)[0];
            assert!((got - want).abs() < 0.02, "({x}, {y}): {got} vs {want}");
        }
    }
}

#[test]
fn a_stopped_filter_gives_up_between_passes() {
    let (img, g) = (noisy(16, 16, 0.5, 0.2), flat_guides(16, 16));
    let d = Denoiser::default();
    let mut asked = 0;
    let mut after_two = || {
        asked += 1;
        asked > 2
    };
    assert!(d.apply_unless(&img, &g, &mut after_two).is_none());
    assert_eq!(asked, 3, "asked before each pass until it said yes");
    assert_eq!(d.apply_unless(&img, &g, &mut || false), d.apply(&img, &g));
}

#[test]
fn edges_in_every_guide_are_kept() {
    // Left half at 0.2, right half at 0.8, with an edge in one guide at a time:
    // the filter must keep the step (no pixel pulled across by more than 2%).
    let (w, h) = (32, 16);
    let mut img = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            img.set(x, y, [if x < w / 2 { 0.2 } else { 0.8 }; 3]);
        }
    }
    for guide in ["normal", "depth", "albedo", "background"] {
        let mut g = flat_guides(w, h);
        for y in 0..h {
            for x in w / 2..w {
                let p = (y * w + x) as usize;
                match guide {
                    "normal" => g.normal[p] = [1.0, 0.0, 0.0],
                    "depth" => g.depth[p] = 2.0,
                    "albedo" => g.albedo[p] = [0.9; 3],
                    _ => g.depth[p] = f32::INFINITY,
                }
            }
        }
        let out = Denoiser {
            // The colour weight alone would also keep this step; switch it off.
            sigma_color: 1e6,
            ..Denoiser::default()
        }
        .apply(&img, &g)
        .expect("sizes match");
        for y in 0..h {
            for x in 0..w {
                let want = img.get(x, y)[0];
                let got = out.get(x, y)[0];
                assert!(
                    (got - want).abs() < 0.02 * 0.6,
                    "{guide}: ({x}, {y}) {got} vs {want}"
                );
            }
        }
    }
}

#[test]
fn the_polynomial_exp_is_within_its_stated_error() {
    let mut worst = 0.0f64;
    for k in 0..=200_000 {
        let x = k as f32 * 0.0005; // 0 to 100
        let want = (-f64::from(x)).exp();
        let got = f64::from(exp_neg(x));
        if want > 1e-37 {
            worst = worst.max((got - want).abs() / want);
        } else {
            assert!(got <= 2e-37, "exp(-{x}) = {got}");
        }
    }
    assert!(worst < 1e-5, "relative error {worst}");
    assert_eq!(exp_neg(0.0), 1.0);
    assert_eq!(exp_neg(f32::INFINITY), 0.0);
    assert_eq!(exp_neg(f32::NAN), 0.0);
}

/// Guides with surfaces at three depths, creases in the normals, albedo steps and
/// background, over a noisy image with highlights: every kind of edge, at sizes
/// that are not multiples of the kernel's steps.
fn busy_scene(w: u32, h: u32) -> (Image, Guides) {
    let mut g = flat_guides(w, h);
    let mut img = noisy(w, h, 0.4, 0.35);
    for y in 0..h {
        for x in 0..w {
            let p = (y * w + x) as usize;
            let u = meso_materials::rng::SampleStream::new(&[u64::from(x), u64::from(y), 9]);
            g.depth[p] = match (x * 3 / w, y % 7) {
                (_, 0) if x % 5 == 0 => f32::INFINITY,
                (0, _) => 1.0,
                (1, _) => 1.0 + 0.02 * u.at(0) as f32,
                _ => 4.0,
            };
            let tilt = if (x / 6 + y / 9) % 2 == 0 { 0.3 } else { -0.2 };
            let n: [f32; 3] = [tilt, 0.1, 1.0];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            g.normal[p] = n.map(|c| c / len);
            g.albedo[p] = [0.2 + 0.6 * ((x / 11) % 2) as f32, 0.5, 0.4];
            if u.at(1) < 0.02 {
                img.set(x, y, [25.0, 20.0, 18.0]);
            }
        }
    }
    (img, g)
}

/// The AVX2 build of a row pass gives the portable build's bits (docs/rendering.md
/// says so); on a CPU without AVX2 both calls run the portable code.
#[test]
fn the_avx512_avx2_and_portable_rows_are_bit_identical() {
    let (img, guides) = busy_scene(61, 37);
    let filter = Denoiser::for_samples(2);
    let g = PlanarGuides::new(&filter, &guides);
    let src = Planar::of(img.pixels());
    let compressed = Planar::of(
        &img.pixels()
            .iter()
            .map(|&c| compress(c))
            .collect::<Vec<_>>(),
    );
    for step in [1, 2, 4, 8] {
        let row = RowPass {
            filter: &filter,
            guides: &g,
            src: &src,
            compressed: &compressed,
            width: 61,
            height: 37,
            step,
            inv_color: 1.0 / (filter.sigma_color * filter.sigma_color),
        };
        for y in 0..37 {
            let portable = row.run_portable(y);
            let mut others = vec![("dispatched", row.run(y))];
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2 (checked above).
                others.push(("avx2", unsafe { row.run_avx2(y) }));
            }
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has AVX-512F (checked above).
                others.push(("avx512", unsafe { row.run_avx512(y) }));
            }
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for (name, other) in &others {
                for k in 0..3 {
                    assert_eq!(
                        bits(&other[k]),
                        bits(&portable[k]),
                        "{name}: step {step}, row {y}"
                    );
                }
            }
        }
    }
}

#[test]
fn the_fast_filter_agrees_with_the_reference() {
    for (w, h) in [(61, 37), (128, 96), (5, 3)] {
        let (img, g) = busy_scene(w, h);
        for samples in [1, 4, 16] {
            let d = Denoiser::for_samples(samples);
            let fast = d.apply(&img, &g).expect("sizes match");
            let slow = d.apply_reference(&img, &g).expect("sizes match");
            for (a, b) in fast.pixels().iter().zip(slow.pixels()) {
                for k in 0..3 {
                    assert!(
                        (a[k] - b[k]).abs() <= 1e-4 * b[k].abs().max(1.0),
                        "{w}x{h}, {samples} spp: {a:?} vs {b:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn the_viewport_blend_fades_out_and_guides_must_match() {
    assert_eq!(viewport_strength(1), 1.0);
    assert!(viewport_strength(16) > 0.0 && viewport_strength(16) < 1.0);
    assert_eq!(viewport_strength(FADE_SAMPLES), 0.0);
    let img = noisy(8, 8, 0.5, 0.2);
    let flat = Image::from_pixels(8, 8, vec![[0.5; 3]; 64]).expect("size");
    assert_eq!(blend(&img, &flat, 0.0), img);
    assert_eq!(blend(&img, &flat, 1.0), flat);
    assert!(
        Denoiser::default()
            .apply(&img, &flat_guides(8, 9))
            .is_none()
    );
}
