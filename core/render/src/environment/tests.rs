//! The environment's convention and sampler: directions round-trip through the lat-long
//! mapping, the rotation follows the spec's sense, the pdf integrates to one, is
//! positive wherever the map is, and sampled directions follow it (chi-square, with
//! bins that straddle pixel edges so the in-pixel distribution is tested too).

use std::f64::consts::{PI, TAU};
use std::sync::Arc;

use glam::DVec3;

use super::*;
use crate::scene::Environment;
use meso_materials::image::read_image;
use meso_materials::rng::SampleStream;

fn shipped(name: &str) -> Image {
    read_image(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../materials/env")
            .join(name),
    )
    .expect("shipped map")
}

/// A dim map with one very bright pixel (a "sun" of one pixel), 64 x 32.
fn hot_spot() -> Image {
    let mut img = Image::new(64, 32);
    for y in 0..32 {
        for x in 0..64 {
            img.set(
                x,
                y,
                [0.01 + 0.001 * x as f32, 0.02, 0.015 + 0.002 * y as f32],
            );
        }
    }
    img.set(40, 9, [5e4, 4e4, 3e4]);
    img
}

#[test]
fn directions_round_trip_and_follow_the_spec_convention() {
    // u = 0.5 looks along +x, u = 0.75 along +z, row 0 is the zenith.
    assert!(direction_at(0.5, 0.5).distance(DVec3::X) < 1e-12);
    assert!(direction_at(0.75, 0.5).distance(DVec3::Z) < 1e-12);
    assert!(direction_at(0.25, 0.5).distance(DVec3::NEG_Z) < 1e-12);
    assert!(direction_at(0.3, 0.0).distance(DVec3::Y) < 1e-12);
    assert_eq!(pixel_of(512, 256, DVec3::Y), (256, 0));
    assert_eq!(pixel_of(512, 256, DVec3::NEG_Y).1, 255);
    for (x, y) in [(0, 0), (17, 100), (511, 255), (256, 128)] {
        let d = direction_at((x as f64 + 0.5) / 512.0, (y as f64 + 0.5) / 256.0);
        assert_eq!(pixel_of(512, 256, d), (x, y));
    }
    // A right-handed quarter turn about +y takes +x to -z and +z to +x.
    assert!(rotate_y(DVec3::X, 90.0).distance(DVec3::NEG_Z) < 1e-12);
    assert!(rotate_y(DVec3::Z, 90.0).distance(DVec3::X) < 1e-12);
    // Pixel solid angles add up to the sphere.
    let sum: f64 = (0..256)
        .map(|y| 512.0 * pixel_solid_angle(512, 256, y))
        .sum();
    assert!((sum - 4.0 * PI).abs() < 1e-9, "{sum}");
}

#[test]
fn a_rotated_environment_shows_in_the_rotated_direction() {
    let env = Environment {
        map: Arc::new(hot_spot()),
        strength: 1.0,
        rotate_y_deg: 35.0,
        mis: true,
    };
    let d = direction_at(40.5 / 64.0, 9.5 / 32.0);
    let seen = env.radiance_unit(rotate_y(d, 35.0));
    assert_eq!(seen, DVec3::new(5e4, 4e4, 3e4));
}

#[test]
fn the_pdf_integrates_to_one_and_is_positive_wherever_the_map_is() {
    for map in [shipped("env_sky.exr"), hot_spot()] {
        let s = EnvironmentSampler::new(&map).expect("not black");
        let (w, h) = (map.width(), map.height());
        let mut integral = 0.0;
        for y in 0..h {
            for x in 0..w {
                let d = direction_at((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
                let pdf = s.pdf(d);
                let lum = meso_materials::image::luminance(map.get(x, y));
                assert!(pdf.is_finite() && pdf >= 0.0);
                assert_eq!(pdf > 0.0, lum > 0.0, "pixel ({x}, {y})");
                integral += pdf * pixel_solid_angle(w, h, y);
            }
        }
        assert!((integral - 1.0).abs() < 1e-9, "{integral}");
    }
    assert!(
        EnvironmentSampler::new(&Image::new(8, 4)).is_none(),
        "black map"
    );
}

/// Chi-square p-value (the BRDF samplers' harness: `brdf::chi2_tests`) of `s`'s samples
/// over a grid of `nu` x `nv` cells in (u, cos theta) whose edges fall inside pixels;
/// expected probabilities are exact (the pdf is constant over a pixel, so a cell's
/// mass is the sum over the pixels it overlaps of pdf x overlapping solid angle).
/// `claimed` may differ from the sampler, to show that the test can fail.
fn chi2_p(map: &Image, s: &EnvironmentSampler, claimed: &EnvironmentSampler) -> f64 {
    use meso_materials::brdf::chi2_tests::{histogram, p_value};
    let (nu, nv) = (37usize, 23usize);
    let (w, h) = (map.width() as usize, map.height() as usize);
    let cell = |d: DVec3| {
        let u = 0.5 + d.z.atan2(d.x) / TAU;
        let c = d.y.clamp(-1.0, 1.0);
        let iu = ((u * nu as f64) as usize).min(nu - 1);
        let iv = (((1.0 - c) / 2.0 * nv as f64) as usize).min(nv - 1);
        iv * nu + iu
    };
    let (observed, accepted) = histogram(|u| Some(s.sample(map, u).dir), cell, nu * nv, 3);
    let mut expected = vec![0.0; nu * nv];
    for y in 0..h {
        let (cy0, cy1) = (
            (PI * y as f64 / h as f64).cos(),
            (PI * (y + 1) as f64 / h as f64).cos(),
        );
        for x in 0..w {
            let d = direction_at((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            let pdf = claimed.pdf(d);
            if pdf == 0.0 {
                continue;
            }
            let (u0, u1) = (x as f64 / w as f64, (x + 1) as f64 / w as f64);
            for iv in 0..nv {
                // Cell iv spans cos theta from 1 - 2 iv / nv down to 1 - 2 (iv + 1) / nv.
                let (ca, cb) = (
                    1.0 - 2.0 * iv as f64 / nv as f64,
                    1.0 - 2.0 * (iv + 1) as f64 / nv as f64,
                );
                let dc = (cy0.min(ca) - cy1.max(cb)).max(0.0);
                if dc == 0.0 {
                    continue;
                }
                for iu in 0..nu {
                    let (a, b) = (iu as f64 / nu as f64, (iu + 1) as f64 / nu as f64);
                    let du = (u1.min(b) - u0.max(a)).max(0.0);
                    expected[iv * nu + iu] += pdf * TAU * du * dc;
                }
            }
        }
    }
    p_value(&observed, &expected, accepted, 1e-9).expect("the bins are usable")
}

#[test]
fn sampled_directions_follow_the_pdf() {
    for map in [shipped("env_sky.exr"), hot_spot()] {
        let s = EnvironmentSampler::new(&map).expect("not black");
        let p = chi2_p(&map, &s, &s);
        assert!(p > 1e-3, "chi-square p = {p}");
        // Every sample's pdf and radiance are those of the pixel it lies in.
        for k in 0..2000 {
            let smp = s.sample(&map, SampleStream::new(&[9, k]).next_2d());
            assert!((smp.pdf - s.pdf(smp.dir)).abs() <= 1e-12 * smp.pdf);
            assert!((smp.dir.length() - 1.0).abs() < 1e-12);
        }
    }
}

#[test]
fn the_chi_square_test_detects_a_wrong_distribution() {
    // Claim the pdf of a map whose hot spot is half as bright: sampling the real one
    // over-draws the spot, which the test must notice.
    let map = hot_spot();
    let mut dimmer = map.clone();
    dimmer.set(40, 9, [2.5e4, 2e4, 1.5e4]);
    let s = EnvironmentSampler::new(&map).expect("not black");
    let wrong = EnvironmentSampler::new(&dimmer).expect("not black");
    let p = chi2_p(&map, &s, &wrong);
    assert!(p < 1e-6, "p = {p}");
}

#[test]
fn maps_with_negative_or_non_finite_pixels_are_refused() {
    let mut m = hot_spot();
    m.set(3, 4, [0.0, -1.0, 0.0]);
    assert!(check_map(&m).expect("refused").contains("pixel (3, 4)"));
    m.set(3, 4, [f32::NAN, 0.0, 0.0]);
    assert!(check_map(&m).is_some());
    assert!(check_map(&Image::new(0, 0)).is_some());
    assert!(check_map(&hot_spot()).is_none());
}
