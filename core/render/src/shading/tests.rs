//! The shading core against independent estimates: for every material kind, the
//! directions it draws carry the pdf it reports for them, and the response integrated
//! with its own sampler equals the same integral over uniform directions (a sampler
//! whose pdf lies would bias the first and not the second).

use std::f64::consts::PI;
use std::sync::Arc;

use glam::{DVec2, DVec3};

use super::*;
use crate::scene::test_scenes::tabulated_btf;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel, warp};
use meso_materials::rng::SampleStream;
use meso_materials::spmm::testing::sample_material;

fn scene_of(materials: Vec<Material>) -> Scene {
    let mut scene = crate::scene::test_scenes::edit_test_scene();
    scene.materials = materials;
    scene
}

fn glossy() -> AnalyticBrdf {
    AnalyticBrdf::with_defaults(BrdfModel::CookTorrance)
        .with_param("m", 0.3)
        .expect("valid")
}

/// One of each material kind with a finite response.
fn every_kind() -> Vec<(&'static str, Material)> {
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    vec![
        (
            "lambertian",
            Material::Brdf {
                brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
                albedo,
            },
        ),
        (
            "cook_torrance",
            Material::Brdf {
                brdf: glossy(),
                albedo,
            },
        ),
        (
            "merl",
            Material::Merl {
                brdf: Arc::new(meso_materials::merl::tabulate(&glossy(), albedo).expect("table")),
                tint: DVec3::ONE,
            },
        ),
        (
            "spmm",
            Material::Spmm {
                material: Arc::new(sample_material(4, 4, 2, Some(2))),
                uv_scale: DVec2::ONE,
                residual: true,
                npca: 2,
            },
        ),
        ("btf", tabulated_btf(&glossy(), albedo, DVec2::ONE)),
    ]
}

const VIEW: DVec3 = DVec3::new(0.42, -0.18, 0.889);
const UV: DVec2 = DVec2::new(0.37, 0.61);

/// A surface frame with the normal along +z at `UV`, material 0.
fn flat_frame() -> Shading {
    Shading {
        p: DVec3::ZERO,
        t: DVec3::X,
        b: DVec3::Z.cross(DVec3::X),
        n: DVec3::Z,
        uv: UV,
        material: 0,
    }
}

/// The luminance-like sum of a response, for comparing integrals.
fn sum(v: DVec3) -> f64 {
    v.x + v.y + v.z
}

#[test]
fn every_drawn_direction_carries_the_pdf_the_material_reports_for_it() {
    for sampling in [PackSampling::Bases, PackSampling::Defensive] {
        for (name, material) in every_kind() {
            let scene = scene_of(vec![material]);
            let mut shaders = Shaders::new(&scene.materials);
            shaders.set_pack_sampling(sampling);
            let m = shaders.material(&scene, 0, false);
            let lo = VIEW.normalize();
            let rng = SampleStream::new(&[7, 0x5AD]);
            let mut drawn = 0;
            for i in 0..2_000u64 {
                let u = DVec2::new(rng.at(2 * i), rng.at(2 * i + 1));
                let Some((li, pdf)) = m.sample_local(UV, lo, u) else {
                    continue;
                };
                drawn += 1;
                let reported = m.pdf_local(UV, li, lo);
                assert!(
                    (pdf - reported).abs() <= 1e-6 * pdf.max(1.0),
                    "{name} ({sampling:?}): drew {li} with pdf {pdf}, reports {reported}"
                );
            }
            assert!(drawn > 1_000, "{name}: only {drawn} of 2000 draws");
        }
    }
}

#[test]
fn each_sampler_integrates_the_response_like_uniform_directions() {
    let n = 200_000u64;
    for (name, material) in every_kind() {
        let scene = scene_of(vec![material]);
        let shaders = Shaders::new(&scene.materials);
        let m = shaders.material(&scene, 0, false);
        let lo = VIEW.normalize();
        let rng = SampleStream::new(&[11, 0x1A7]);
        let (mut own, mut uniform) = (0.0, 0.0);
        for i in 0..n {
            let u = DVec2::new(rng.at(4 * i), rng.at(4 * i + 1));
            if let Some((li, pdf)) = m.sample_local(UV, lo, u) {
                own += sum(m.response_local(UV, li, lo)) / pdf;
            }
            let u = DVec2::new(rng.at(4 * i + 2), rng.at(4 * i + 3));
            let li = warp::spherical(u.x, 2.0 * PI * u.y);
            uniform += sum(m.response_local(UV, li, lo)) * 2.0 * PI;
        }
        let (own, uniform) = (own / n as f64, uniform / n as f64);
        assert!(uniform > 0.05, "{name}: integral {uniform}");
        assert!(
            (own - uniform).abs() <= 0.03 * uniform,
            "{name}: own sampler {own}, uniform directions {uniform}"
        );
    }
}

#[test]
fn ambient_directions_weigh_the_response_by_their_inverse_pdf() {
    // E[weight x response] over the ambient samples is the response's integral over
    // the hemisphere, whichever strategy the material uses.
    let n = 200_000u64;
    let frame = flat_frame();
    for (name, material) in every_kind() {
        let scene = scene_of(vec![material]);
        let shaders = Shaders::new(&scene.materials);
        let m = shaders.material(&scene, 0, false);
        let wo = VIEW.normalize();
        let rng = SampleStream::new(&[13, 0xA3B]);
        let (mut ambient, mut uniform) = (0.0, 0.0);
        for i in 0..n {
            let u = DVec2::new(rng.at(4 * i), rng.at(4 * i + 1));
            if let Some((wi, weight)) = m.ambient_sample(&frame, wo, u) {
                assert!(
                    wi.z > 0.0,
                    "{name}: ambient direction {wi} below the surface"
                );
                ambient += sum(m.response(&frame, wi, wo)) * weight;
            }
            let u = DVec2::new(rng.at(4 * i + 2), rng.at(4 * i + 3));
            let wi = warp::spherical(u.x, 2.0 * PI * u.y);
            uniform += sum(m.response(&frame, wi, wo)) * 2.0 * PI;
        }
        let (ambient, uniform) = (ambient / n as f64, uniform / n as f64);
        assert!(
            (ambient - uniform).abs() <= 0.03 * uniform,
            "{name}: ambient {ambient}, uniform {uniform}"
        );
    }
}

/// Per-sample mean and variance of `response x weight` over `n` ambient directions of
/// `m` at the frame of `ambient_directions_weigh_the_response_by_their_inverse_pdf`,
/// drawn by `draw`.
fn ambient_moments(
    m: &ShadedMaterial,
    n: u64,
    draw: impl Fn(&Shading, DVec3, DVec2) -> Option<(DVec3, f64)>,
) -> (f64, f64) {
    let frame = flat_frame();
    let wo = VIEW.normalize();
    let rng = SampleStream::new(&[17, 0xA3B]);
    let (mut s1, mut s2) = (0.0, 0.0);
    for i in 0..n {
        let u = DVec2::new(rng.at(2 * i), rng.at(2 * i + 1));
        if let Some((wi, weight)) = draw(&frame, wo, u) {
            let v = sum(m.response(&frame, wi, wo)) * weight;
            s1 += v;
            s2 += v * v;
        }
    }
    let mean = s1 / n as f64;
    (mean, s2 / n as f64 - mean * mean)
}

/// A glossy lobe's ambient estimate draws half its directions from the lobe: against
/// cosine directions alone (what glossy BRDFs and MERL tables drew before), the same
/// mean with a fraction of the variance; a Lambertian keeps its cosine directions, bit
/// for bit.
#[test]
fn glossy_lobes_draw_ambient_directions_from_the_lobe_too() {
    let sharp = AnalyticBrdf::with_defaults(BrdfModel::CookTorrance)
        .with_param("m", 0.1)
        .expect("valid");
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    let cases = [
        (
            "cook-torrance m = 0.1",
            Material::Brdf {
                brdf: sharp,
                albedo,
            },
        ),
        (
            "its merl table",
            Material::Merl {
                brdf: Arc::new(meso_materials::merl::tabulate(&sharp, albedo).expect("table")),
                tint: DVec3::ONE,
            },
        ),
    ];
    let cosine = |s: &Shading, _: DVec3, u: DVec2| {
        let local = warp::cosine_hemisphere(u);
        (local.z > 0.0).then(|| (s.to_world(local), PI / local.z))
    };
    for (name, material) in cases {
        let scene = scene_of(vec![material]);
        let shaders = Shaders::new(&scene.materials);
        let m = shaders.material(&scene, 0, false);
        let n = 200_000;
        let (mean, var) = ambient_moments(&m, n, |s, wo, u| m.ambient_sample(s, wo, u));
        let (cos_mean, cos_var) = ambient_moments(&m, n, cosine);
        eprintln!(
            "{name}: mean {mean:.5} (cosine {cos_mean:.5}), variance {var:.4e} (cosine {cos_var:.4e}, ratio {:.3})",
            var / cos_var
        );
        assert!((mean - cos_mean).abs() <= 0.03 * cos_mean, "{name}: means");
        assert!(var <= 0.25 * cos_var, "{name}: variance");
    }
    let scene = scene_of(vec![Material::Brdf {
        brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        albedo,
    }]);
    let shaders = Shaders::new(&scene.materials);
    let m = shaders.material(&scene, 0, false);
    let frame = flat_frame();
    for u in [DVec2::new(0.1, 0.2), DVec2::new(0.7, 0.9)] {
        let got = m.ambient_sample(&frame, VIEW.normalize(), u);
        assert_eq!(
            got,
            cosine(&frame, VIEW, u),
            "a Lambertian's cosine direction"
        );
    }
}

#[test]
fn a_mirror_is_a_delta_lobe_the_caller_follows() {
    let reflectance = DVec3::new(0.9, 0.8, 0.7);
    let scene = scene_of(vec![Material::Mirror { reflectance }]);
    let shaders = Shaders::new(&scene.materials);
    let m = shaders.material(&scene, 0, false);
    let lo = VIEW.normalize();
    let mirrored = DVec3::new(-lo.x, -lo.y, lo.z);
    assert_eq!(m.specular(), Some(reflectance));
    assert_eq!(m.response_local(UV, mirrored, lo), DVec3::ZERO);
    assert_eq!(m.sample_local(UV, lo, DVec2::splat(0.5)), None);
    assert_eq!(m.uniform_albedo(), Some(reflectance));
    for (name, material) in every_kind() {
        let scene = scene_of(vec![material]);
        let shaders = Shaders::new(&scene.materials);
        assert_eq!(
            shaders.material(&scene, 0, false).specular(),
            None,
            "{name}"
        );
    }
}

#[test]
fn a_lambertian_reflects_its_albedo_and_is_reciprocal() {
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    let scene = scene_of(vec![Material::Brdf {
        brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        albedo,
    }]);
    let shaders = Shaders::new(&scene.materials);
    let m = shaders.material(&scene, 0, false);
    let (a, b) = (DVec3::new(0.3, 0.1, 0.95).normalize(), VIEW.normalize());
    // albedo / pi x cos_i, and f itself symmetric.
    let want = albedo / PI * a.z;
    assert!((m.response_local(UV, a, b) - want).abs().max_element() < 1e-12);
    let (fa, fb) = (
        m.response_local(UV, a, b) / a.z,
        m.response_local(UV, b, a) / b.z,
    );
    assert!((fa - fb).abs().max_element() < 1e-12, "{fa} {fb}");
    assert_eq!(m.uniform_albedo(), Some(albedo));
}
