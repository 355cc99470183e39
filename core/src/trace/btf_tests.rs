//! `btf` materials in the spmm mode: a BTF tabulating a Lambertian BRDF renders like
//! the analytic BRDF within the interpolation bound derived in `btf::table` (point
//! light only, so both renders draw the same numbers and differ by the table alone).

use std::f64::consts::PI;

use glam::{DVec2, DVec3};

use super::SpmmMode;
use crate::brdf::{AnalyticBrdf, BrdfModel, warp};
use crate::image::Image;
use crate::metrics::compare;
use crate::render::RenderMode;
use crate::scene::test_scenes::{edit_test_scene, tabulated_btf};
use crate::scene::{Light, Material, Scene};

fn render(scene: &Scene, frames: u32) -> Image {
    let mut m = SpmmMode::new(scene.clone(), scene.render.width, scene.render.height)
        .expect("the spmm mode shades every material of the scene");
    for _ in 0..frames {
        m.render_frame();
    }
    m.image()
}

/// The Lambertian floor of the edit scene lit by one point light at height 3 above
/// its centre (incidence at most 43.3 degrees on the 4 x 4 floor), no ambient.
fn floor_scene(floor: Material) -> Scene {
    let mut s = edit_test_scene();
    s.materials[0] = floor;
    s.lights = vec![Light::Point {
        position: DVec3::new(0.0, 3.0, 0.0),
        intensity: DVec3::splat(4.0),
    }];
    s.ambient = None;
    s
}

/// The largest relative error bound of interpolating cos_i over the Bonn light set
/// for incidence up to `theta_max`: M/2 sum_i lambda_i |p_i - p|^2 with M = 1/z^3 at
/// the triangle's lowest vertex (derivation in `btf::table`'s tests), over dense
/// directions, divided by cos_i.
fn relative_bound(theta_max: f64) -> f64 {
    let Material::Btf { table, .. } = tabulated_btf(
        &AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        DVec3::ONE,
        DVec2::ONE,
    ) else {
        unreachable!("a btf material")
    };
    let mut worst = 0.0f64;
    for i in 0..200 {
        for j in 0..90 {
            let theta = theta_max * (i as f64 + 0.5) / 200.0;
            let wi = warp::spherical(theta.cos(), 2.0 * PI * j as f64 / 90.0);
            let w = table.light_weights(wi);
            let dirs = table.light_dirs();
            let z_min = w
                .iter()
                .map(|&(k, _)| dirs[k as usize].z)
                .fold(1.0, f64::min);
            let spread: f64 = w
                .iter()
                .map(|&(k, l)| l * (dirs[k as usize] - wi).truncate().length_squared())
                .sum();
            worst = worst.max(0.5 * spread / z_min.powi(3) / wi.z);
        }
    }
    worst
}

#[test]
fn a_btf_of_a_lambertian_renders_like_the_brdf_within_the_interpolation_bound() {
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    let lambertian = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    let want = render(
        &floor_scene(Material::Brdf {
            brdf: lambertian,
            albedo,
        }),
        2,
    );
    let got = render(
        &floor_scene(tabulated_btf(&lambertian, albedo, DVec2::splat(3.0))),
        2,
    );
    let bound = relative_bound(43.4f64.to_radians());
    let mut worst = 0.0f64;
    for (a, b) in want.pixels().iter().zip(got.pixels()) {
        for c in 0..3 {
            let (a, b) = (f64::from(a[c]), f64::from(b[c]));
            assert!(
                (a - b).abs() <= bound * a * 1.1 + 1e-6,
                "{b} against {a}: more than the bound {bound}"
            );
            if a > 1e-3 {
                worst = worst.max((a - b).abs() / a);
            }
        }
    }
    // The table is not the BRDF: the floor shows the interpolation error.
    assert!(worst > 1e-4, "largest relative pixel difference {worst}");
    let m = compare(&want, &got, 0.0).expect("same size");
    assert!(m.mssim > 0.999, "MSSIM {}", m.mssim);
}
