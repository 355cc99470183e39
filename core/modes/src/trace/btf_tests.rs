//! `btf` materials in the spmm mode: a BTF tabulating a Lambertian BRDF renders like
//! the analytic BRDF, to rounding, at any incidence (the light side is interpolated
//! over value / cos theta_l, `DirectionTable::cosine_weights`; point light only, so
//! both renders draw the same numbers and differ by the table alone).

use glam::{DVec2, DVec3};

use super::SpmmMode;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::image::Image;
use meso_render::RenderMode;
use meso_render::RenderModeExt;
use meso_render::scene::test_scenes::{edit_test_scene, tabulated_btf};
use meso_render::scene::{Light, Material, Scene};

fn render(scene: &Scene, frames: u32) -> Image {
    let mut m = SpmmMode::new(scene.clone(), scene.render.width, scene.render.height)
        .expect("the spmm mode shades every material of the scene");
    for _ in 0..frames {
        m.render_frame();
    }
    m.image()
}

/// The Lambertian floor of the edit scene lit by one point light at `light`, no
/// ambient.
fn floor_scene(floor: Material, light: DVec3) -> Scene {
    let mut s = edit_test_scene();
    s.materials[0] = floor;
    s.lights = vec![Light::Point {
        position: light,
        intensity: DVec3::splat(4.0),
    }];
    s.ambient = None;
    s
}

#[test]
fn a_btf_of_a_lambertian_renders_like_the_brdf_at_any_incidence() {
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    let lambertian = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    // Above the floor's centre (incidence up to 43.3 degrees), and low beside it
    // (incidence from 84 to 89 degrees, beyond the Bonn set's last ring at 75
    // degrees, where the table is extrapolated).
    for light in [DVec3::new(0.0, 3.0, 0.0), DVec3::new(-3.0, 0.1, 0.0)] {
        let lit = |floor: Material| floor_scene(floor, light);
        let want = render(
            &lit(Material::Brdf {
                brdf: lambertian,
                albedo,
            }),
            2,
        );
        let got = render(
            &lit(tabulated_btf(&lambertian, albedo, DVec2::splat(3.0))),
            2,
        );
        let mut lit_pixels = 0;
        for (a, b) in want.pixels().iter().zip(got.pixels()) {
            for c in 0..3 {
                let (a, b) = (f64::from(a[c]), f64::from(b[c]));
                // The table's f32 values and the image's f32 pixels.
                assert!(
                    (a - b).abs() <= 1e-6 * a + 1e-7,
                    "light at {light}: {b} against {a}"
                );
                lit_pixels += usize::from(a > 1e-3);
            }
        }
        assert!(
            lit_pixels > 1000,
            "light at {light}: {lit_pixels} lit pixel values"
        );
    }
}
