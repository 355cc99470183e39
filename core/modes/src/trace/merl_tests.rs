//! MERL tables in the spmm mode: a tabulated Lambertian renders like the analytic one
//! to rounding (same random numbers where no MIS is involved), a tabulated glossy
//! Cook-Torrance converges to the analytic BRDF's image within its tabulation error
//! under an area light (MIS of light and table samples, against light samples alone
//! for the analytic BRDF) and an environment (MIS of map and table samples), and an
//! edit to a MERL material restarts only its pixels.

use std::sync::Arc;

use glam::DVec3;

use super::SpmmMode;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::image::Image;
use meso_materials::merl::tabulate;
use meso_materials::metrics::compare;
use meso_render::RenderModeExt;
use meso_render::scene::test_scenes::edit_test_scene;
use meso_render::scene::{Environment, Light, Material, Scene};
use meso_render::{RenderMode, SceneEdit};

fn render(scene: &Scene, frames: u32) -> Image {
    let mut m = SpmmMode::new(scene.clone(), scene.render.width, scene.render.height)
        .expect("the spmm mode shades every material of the scene");
    for _ in 0..frames {
        m.render_frame();
    }
    m.image()
}

fn relative_rmse(a: &Image, reference: &Image) -> f64 {
    let m = compare(reference, a, 0.0).expect("same size");
    let mean: f64 = reference
        .pixels()
        .iter()
        .map(|p| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0)
        .sum::<f64>()
        / reference.pixels().len() as f64;
    m.rmse / mean
}

/// The image's mean colour.
fn mean(img: &Image) -> DVec3 {
    img.pixels()
        .iter()
        .map(|p| DVec3::new(p[0].into(), p[1].into(), p[2].into()))
        .sum::<DVec3>()
        / img.pixels().len() as f64
}

/// A bluish sky brighter towards the zenith with a warm band near the horizon.
fn sky() -> Arc<Image> {
    let (w, h) = (32, 16);
    let mut img = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let d = meso_render::environment::direction_at(
                (x as f64 + 0.5) / w as f64,
                (y as f64 + 0.5) / h as f64,
            );
            let c = DVec3::new(0.3, 0.45, 0.8) * (0.2 + d.y.max(0.0))
                + DVec3::new(0.6, 0.4, 0.2) * (1.0 - d.y.abs()).powi(8) * (0.5 + 0.5 * d.x);
            img.set(x, y, [c.x as f32, c.y as f32, c.z as f32]);
        }
    }
    Arc::new(img)
}

fn with_floor(material: Material) -> Scene {
    let mut s = edit_test_scene();
    s.materials[0] = material;
    s
}

#[test]
fn a_tabulated_lambertian_renders_like_the_analytic_one() {
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    let lambertian = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    let analytic = Material::Brdf {
        brdf: lambertian,
        albedo,
    };
    let table = Material::Merl {
        brdf: Arc::new(tabulate(&lambertian, albedo).expect("tabulates")),
        tint: DVec3::ONE,
    };
    // The point light only: both materials draw the same numbers, so the images
    // differ by the table's rounding alone. (The ambient term draws a MERL table's
    // directions from its lobe too, an analytic Lambertian's by cosine alone:
    // `shading::tests` checks both estimates against the response's integral.)
    let mut scene = with_floor(analytic);
    scene.lights.retain(|l| matches!(l, Light::Point { .. }));
    scene.ambient = None;
    let want = render(&scene, 4);
    scene.materials[0] = table;
    let got = render(&scene, 4);
    let e = relative_rmse(&got, &want);
    assert!(e < 1e-6, "relative RMSE {e:e}");
}

/// A Cook-Torrance floor (m = 0.25) under the area light, the point light and a sky,
/// analytic or tabulated; the SPMM panel stays.
fn glossy_scene(tabulated: bool) -> Scene {
    let brdf = AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.25), ("f0", 0.6)])
        .expect("valid parameters");
    let albedo = DVec3::new(0.9, 0.6, 0.3);
    let material = if tabulated {
        Material::Merl {
            brdf: Arc::new(tabulate(&brdf, albedo).expect("tabulates")),
            tint: DVec3::ONE,
        }
    } else {
        Material::Brdf { brdf, albedo }
    };
    let mut s = with_floor(material);
    s.environment = Some(Environment {
        map: sky(),
        strength: 1.0,
        rotate_y_deg: 30.0,
        mis: true,
    });
    s.ambient = None;
    s
}

/// Over the whole image: the panel and the background are the same in both scenes and
/// add only noise.
#[test]
fn a_tabulated_cook_torrance_converges_to_the_analytic_brdf_within_its_tabulation_error() {
    let frames: u32 = std::env::var("MESO_MERL_FRAMES").map_or(256, |f| f.parse().expect("frames"));
    let analytic = render(&glossy_scene(false), frames);
    let table = render(&glossy_scene(true), frames);
    // Measured (24 x 24): relative RMSE 3.0%, 1.6%, 0.83%, 0.41%, 0.20% at 256, 1024,
    // 4096, 16384, 65536 frames: it halves with every 4x, so it is noise; the
    // nearest-cell tabulation error of this lobe stays under 0.2% of the image (means
    // within 0.04% at 65536 frames). 4.5% is 1.5x the noise at 256 frames; a wrong
    // scale, cosine or pdf moves the floor by far more.
    let e = relative_rmse(&table, &analytic);
    eprintln!("relative RMSE tabulated vs analytic at {frames} frames: {e}");
    assert!(e < 0.045, "relative RMSE {e}");
    // Means agree more closely (0.14% at 256 frames): noise averages out.
    let (a, t) = (mean(&analytic), mean(&table));
    eprintln!("means {t} vs {a}");
    assert!(
        ((t - a) / a).abs().max_element() < 0.005,
        "means {t} vs {a}"
    );
}

/// Four light samples per frame at a MERL surface, each a light point and a material
/// direction combined by MIS with a quarter of the weight, against the analytic BRDF
/// at one: a missing or doubled share moves the mean by far more than its 0.5%.
#[test]
fn light_samples_at_a_merl_surface_keep_the_mis_estimate_unbiased() {
    let analytic = render(&glossy_scene(false), 256);
    let mut scene = glossy_scene(true);
    scene.render.light_samples = 4;
    let table = render(&scene, 256);
    let e = relative_rmse(&table, &analytic);
    eprintln!("relative RMSE tabulated (4 light samples) vs analytic: {e}");
    assert!(e < 0.045, "relative RMSE {e}");
    let (a, t) = (mean(&analytic), mean(&table));
    assert!(
        ((t - a) / a).abs().max_element() < 0.005,
        "means {t} vs {a}"
    );
}

#[test]
fn an_edit_to_a_merl_material_restarts_only_the_pixels_it_touched() {
    let scene = edit_test_scene();
    let mut mode = SpmmMode::new(scene, 24, 24).expect("valid");
    mode.render_frame();
    let brdf = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    let inv = mode
        .apply(SceneEdit::Material {
            index: 1,
            material: Material::Merl {
                brdf: Arc::new(tabulate(&brdf, DVec3::splat(0.5)).expect("tabulates")),
                tint: DVec3::ONE,
            },
        })
        .expect("the spmm mode shades MERL tables");
    match inv {
        meso_render::Invalidation::Pixels(n) => assert!(n > 0 && n < 24 * 24, "{n}"),
        other => panic!("{other:?}"),
    }
    assert!(matches!(mode.scene().materials[1], Material::Merl { .. }));
}

/// A MERL table's sampling tables are built for a table rays reach, before the first
/// frame when a pixel sees it, and never for one no ray reaches (a panel behind the
/// camera); `material_bytes` counts them.
#[test]
fn sampling_tables_are_built_only_for_tables_rays_reach() {
    use meso_materials::merl::MerlSampler;
    let glossy = AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.3), ("f0", 0.5)])
        .expect("valid parameters");
    let merl = |albedo: f64| Material::Merl {
        brdf: Arc::new(tabulate(&glossy, DVec3::splat(albedo)).expect("tabulates")),
        tint: DVec3::ONE,
    };
    let mut scene = with_floor(merl(0.6));
    scene.material_names.push("behind".into());
    scene.materials.push(merl(0.4));
    scene.meshes.push(meso_render::scene::mesh::quad(
        DVec3::new(-1.0, 0.0, 4.0),
        DVec3::new(2.0, 0.0, 0.0),
        DVec3::new(0.0, 2.0, 0.0),
        2,
    ));
    let built = |scene: &Scene, m: usize| match &scene.materials[m] {
        Material::Merl { brdf, .. } => brdf.sampler_if_built().is_some(),
        _ => unreachable!("a MERL material"),
    };
    let mut mode = SpmmMode::new(scene.clone(), 24, 24).expect("mode");
    assert!(
        built(&scene, 0),
        "the floor's tables are built while preparing"
    );
    meso_render::run_frames(&mut mode, 4, |_, _| {});
    assert!(
        !built(&scene, 2),
        "no ray shades the panel behind the camera"
    );
    let bytes = mode.diagnostics().material_bytes().expect("spmm reports");
    let spmm_panel = {
        let probe = SpmmMode::new(edit_test_scene(), 24, 24).expect("mode");
        probe.prepare_every_material();
        probe
            .diagnostics()
            .material_bytes()
            .expect("spmm reports")
            .full
    };
    assert_eq!(
        bytes.full,
        spmm_panel + 2 * MerlSampler::full_bytes() as u64
    );
    assert!(bytes.resident <= spmm_panel + MerlSampler::full_bytes() as u64);
    assert!(bytes.resident >= MerlSampler::full_bytes() as u64);
}
