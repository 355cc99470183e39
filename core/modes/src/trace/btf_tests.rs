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

/// A woven BTF read from disk through a cache of a few blocks (far smaller than its
/// values, so the renderer's workers keep evicting and re-reading blocks) renders
/// bit for bit like the same file held whole.
#[test]
fn an_out_of_core_btf_renders_bit_for_bit_like_the_btf_held_whole() {
    use meso_materials::btf::file::{BtfPrecision, write_btf};
    use meso_materials::btf::synth::{parse_recipe, synthesize};
    use meso_materials::btf::table::{BtfTable, MemoryBound};
    use std::sync::Arc;
    let recipe = r#"
version = 1
name = "weave"
width = 8
height = 8
direction_rings = [[0.0, 1], [30.0, 6], [60.0, 8]]
detail = 4
supersample = 1
[mesostructure]
kind = "weave"
depth = 2.0
threads = 4
[[region]]
name = "warp"
[[region.lobe]]
model = "lambertian"
weight = [0.1, 0.2, 0.6]
[[region]]
name = "weft"
[[region.lobe]]
model = "ward"
params = { ax = 0.3, ay = 0.1 }
weight = [0.6, 0.5, 0.2]
"#;
    let setup =
        parse_recipe(recipe, std::path::Path::new("."), "weave.toml").expect("valid recipe");
    let btf = synthesize(
        &setup,
        &std::sync::atomic::AtomicBool::new(false),
        &|_, _| {},
    )
    .expect("synthesis runs");
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("weave.btf");
    write_btf(&path, &btf, BtfPrecision::F16).expect("write");
    let texel_bytes = (btf.pairs() * 3 * 2) as u64;
    let whole = BtfTable::open(&path, MemoryBound::default()).expect("opens");
    // 8 resident blocks of one texel besides 4 workers' in flight; 64 texels.
    let tight = MemoryBound {
        max_bytes: 24 * texel_bytes,
        block_bytes: texel_bytes,
        threads: 4,
    };
    let cached = BtfTable::open(&path, tight).expect("opens");
    assert!(whole.is_resident() && !cached.is_resident());
    let light = DVec3::new(-1.0, 3.0, 0.5);
    let lit = |table: &Arc<BtfTable>| {
        let mut s = floor_scene(
            Material::Btf {
                table: Arc::clone(table),
                uv_scale: DVec2::splat(2.0),
            },
            light,
        );
        (s.render.width, s.render.height) = (48, 32);
        s
    };
    let cached = Arc::new(cached);
    let want = render(&lit(&Arc::new(whole)), 2);
    let got = render(&lit(&cached), 2);
    let bits = |i: &Image| -> Vec<u32> {
        i.pixels()
            .iter()
            .flat_map(|p| p.iter().map(|c| c.to_bits()))
            .collect()
    };
    assert_eq!(bits(&got), bits(&want));
    // Lit and textured: the image is not trivially equal.
    let lit_values = want.pixels().iter().filter(|p| p[0] > 1e-3).count();
    assert!(lit_values > 500, "{lit_values} lit pixels");
    let cache = cached.cache().expect("cached");
    assert!(cache.reads() > 8, "{} blocks read", cache.reads());
    assert_eq!(cached.read_error(), None);
}
