//! The spmm mode against closed forms: point and area lights, a light covering the
//! hemisphere (with one and several light samples per frame), ambient light on a tilted-basis SPMM plane, a plane seen in a mirror, AO
//! of an open plane and a corner, replay of single pixels and independence of the thread count.

use glam::DVec3;

use super::SpmmMode;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_render::RenderMode;
use meso_render::RenderModeExt;
use meso_render::scene::Ambient;
use meso_render::scene::{Light, Material, Scene};

const ALBEDO: f64 = 0.6;

/// The shared test floor (`scene::test_scenes::floor_scene`) in a Lambertian of
/// albedo `ALBEDO`, with these lights and ambient term.
fn floor_scene(lights: Vec<Light>, ambient: Option<Ambient>, wall: bool) -> Scene {
    let mut s = meso_render::scene::test_scenes::floor_scene(
        Material::Brdf {
            brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
            albedo: DVec3::splat(ALBEDO),
        },
        wall,
    );
    s.lights = lights;
    s.ambient = ambient;
    s
}

fn mode(scene: &Scene) -> SpmmMode {
    SpmmMode::new(scene.clone(), scene.render.width, scene.render.height).expect("valid size")
}

fn converge(scene: &Scene, frames: u32) -> DVec3 {
    let mut r = mode(scene);
    for _ in 0..frames {
        r.render_frame();
    }
    assert_eq!(r.progress().dropped, 0);
    let p = r.image().get(1, 1);
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

#[test]
fn lambertian_plane_under_a_point_light_matches_the_closed_form() {
    // L = albedo / pi * I cos(theta) / r^2 with the light 2 m above the origin.
    let scene = floor_scene(
        vec![Light::Point {
            position: DVec3::new(0.0, 2.0, 0.0),
            intensity: DVec3::splat(4.0),
        }],
        None,
        false,
    );
    let got = converge(&scene, 1);
    let expected = ALBEDO / std::f64::consts::PI * 4.0 / 4.0;
    assert!(
        (got.x - expected).abs() < 1e-5 * expected,
        "{got} vs {expected}"
    );
    // An oblique light at 60 degrees from the normal, 2 m away: cos = 0.5.
    let pos = DVec3::new(
        2.0 * 60f64.to_radians().sin(),
        2.0 * 60f64.to_radians().cos(),
        0.0,
    );
    let scene = floor_scene(
        vec![Light::Point {
            position: pos,
            intensity: DVec3::splat(4.0),
        }],
        None,
        false,
    );
    let got = converge(&scene, 1);
    // The pixel's footprint (1.5e-5 m) moves the oblique distance by ~3e-5 relative.
    assert!((got.x - 0.5 * expected).abs() < 1e-4 * expected, "{got}");
}

#[test]
fn a_small_area_light_approaches_a_point_light_of_intensity_le_times_area() {
    let side = 0.02;
    let light = Light::Area {
        corner: DVec3::new(-side / 2.0, 2.0, -side / 2.0),
        edge_u: DVec3::new(side, 0.0, 0.0),
        edge_v: DVec3::new(0.0, 0.0, side),
        radiance: DVec3::splat(10_000.0),
    };
    let scene = floor_scene(vec![light], None, false);
    let got = converge(&scene, 64);
    let expected = ALBEDO / std::f64::consts::PI * (10_000.0 * side * side) / 4.0;
    // The light subtends 1e-4 sr: cosines and distance vary by < 1e-4 over it.
    assert!(
        (got.x - expected).abs() < 1e-3 * expected,
        "{got} vs {expected}"
    );
    // Facing away (edge_u x edge_v up): no light reaches the floor.
    let up = Light::Area {
        corner: DVec3::new(-side / 2.0, 2.0, -side / 2.0),
        edge_u: DVec3::new(0.0, 0.0, side),
        edge_v: DVec3::new(side, 0.0, 0.0),
        radiance: DVec3::splat(1e4),
    };
    assert_eq!(
        converge(&floor_scene(vec![up], None, false), 4),
        DVec3::ZERO
    );
}

/// Cosine-weighted solid-angle fraction (the form factor) from a point to the
/// rectangle [0, a] x [0, b] at height h directly above one corner, parallel to the
/// surface: (1 / 2 pi) [A / sqrt(1 + A^2) atan(B / sqrt(1 + A^2)) + (A <-> B)] with
/// A = a / h, B = b / h (the standard closed form, e.g. Howell's catalogue, C-11).
fn corner_form_factor(a: f64, b: f64, h: f64) -> f64 {
    let (x, y) = (a / h, b / h);
    let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
    ((x / sx) * (y / sx).atan() + (y / sy) * (x / sy).atan()) / std::f64::consts::TAU
}

/// A 2s x 2s light at height h = s / 5 centred above the origin, off-centre by (dx,
/// dz) so all four corner rectangles differ, on the 64 x 64 floor; and the pixel value
/// it gives in closed form, the sum of the four corner form factors (0.97 of the
/// hemisphere).
fn hemisphere_light_scene(light_samples: u32) -> (Scene, f64) {
    let (s, h, dx, dz) = (1.0, 0.2, 0.1, -0.15);
    let light = Light::Area {
        corner: DVec3::new(dx - s, h, dz - s),
        edge_u: DVec3::new(2.0 * s, 0.0, 0.0),
        edge_v: DVec3::new(0.0, 0.0, 2.0 * s),
        radiance: DVec3::splat(2.0),
    };
    let fraction = corner_form_factor(s + dx, s + dz, h)
        + corner_form_factor(s - dx, s + dz, h)
        + corner_form_factor(s + dx, s - dz, h)
        + corner_form_factor(s - dx, s - dz, h);
    assert!(fraction > 0.95 && fraction < 1.0, "{fraction}");
    let mut scene = floor_scene(vec![light], None, false);
    (scene.render.width, scene.render.height) = (64, 64);
    scene.render.light_samples = light_samples;
    (scene, ALBEDO * 2.0 * fraction)
}

fn image_mean(r: &SpmmMode) -> f64 {
    let img = r.image();
    img.pixels().iter().map(|p| p[0] as f64).sum::<f64>() / img.pixels().len() as f64
}

#[test]
fn a_light_covering_the_hemisphere_matches_the_closed_form() {
    // One light sample per frame, and three (each weighted a third) over a third of
    // the frames: the same number of samples.
    for (light_samples, frames) in [(1, 400), (3, 134)] {
        let (scene, expected) = hemisphere_light_scene(light_samples);
        let mut r = mode(&scene);
        for _ in 0..frames {
            r.render_frame();
        }
        let mean = image_mean(&r);
        // Area sampling of this light has a relative standard deviation per sample of
        // about sqrt(4 s^2 / (3 pi h^2)) = 3.3; over 64^2 x 400 samples the mean's is
        // 0.26%: 1.2% is 4.5 standard errors.
        assert!(
            (mean - expected).abs() < 0.012 * expected,
            "{light_samples} light samples: {mean} vs {expected}"
        );
    }
}

#[test]
fn more_light_samples_per_frame_cut_the_error_of_a_frame() {
    // One frame of the hemisphere light: the per-pixel squared error against the
    // closed form falls with the number of points (1/4 for independent points; the
    // sets are stratified, so less). Equal points, or a wrong share, would not.
    let mse = |light_samples| {
        let (scene, expected) = hemisphere_light_scene(light_samples);
        let mut r = mode(&scene);
        r.render_frame();
        let img = r.image();
        img.pixels()
            .iter()
            .map(|p| (p[0] as f64 - expected).powi(2))
            .sum::<f64>()
            / img.pixels().len() as f64
    };
    let (one, four) = (mse(1), mse(4));
    assert!(
        four < 0.4 * one,
        "MSE {four} with four points, {one} with one"
    );
}

#[test]
fn a_point_light_is_one_exact_sample_whatever_the_light_samples() {
    // The layout draws one step per light either way, so the image keeps its bits.
    let scene = |light_samples| {
        let mut s = floor_scene(
            vec![Light::Point {
                position: DVec3::new(0.3, 1.5, -0.2),
                intensity: DVec3::splat(3.0),
            }],
            Some(Ambient {
                radiance: DVec3::splat(0.2),
                radius: 0.5,
            }),
            true,
        );
        (s.render.width, s.render.height) = (16, 16);
        s.render.light_samples = light_samples;
        s
    };
    let render = |s: &Scene| {
        let mut r = mode(s);
        let stats = (0..3)
            .map(|_| r.render_frame().counters.rays.shadow)
            .sum::<u64>();
        (r.image(), stats)
    };
    let (one, rays_one) = render(&scene(1));
    let (five, rays_five) = render(&scene(5));
    assert_eq!(one.pixels(), five.pixels());
    assert_eq!(rays_one, rays_five);
}

#[test]
fn ambient_light_on_an_spmm_plane_converges_to_the_integral_of_its_btf() {
    // One texel, one Ward basis whose normal is tilted 35 degrees (the shared test
    // material): its BTF does not vanish with the shading cosine.
    let material = meso_render::scene::test_scenes::tilted_spmm();
    let Material::Spmm { material: pack, .. } = &material else {
        unreachable!("an spmm material")
    };
    let basis = pack.clusters()[0].bases[0];
    let mut scene = floor_scene(
        vec![],
        Some(Ambient {
            radiance: DVec3::splat(0.8),
            radius: f64::INFINITY,
        }),
        false,
    );
    scene.materials[0] = material.clone();
    (scene.render.width, scene.render.height) = (32, 32);
    let mut r = mode(&scene);
    for _ in 0..200 {
        r.render_frame();
    }
    let img = r.image();
    let mean = img.pixels().iter().map(|p| p[0] as f64).sum::<f64>() / 1024.0;
    // The camera looks straight down: wo is the shading normal, in the frame the
    // renderer builds for the floor (tangent along +u = +x, normal +y).
    let wo = DVec3::Z;
    let n = 600;
    let mut integral = 0.0;
    for i in 0..n {
        let z = (i as f64 + 0.5) / n as f64;
        for j in 0..n {
            let phi = std::f64::consts::TAU * (j as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let wi = DVec3::new(r * phi.cos(), r * phi.sin(), z);
            integral += basis.eval(wi, wo);
        }
    }
    integral *= std::f64::consts::TAU / (n * n) as f64;
    let expected = 0.8 * 0.5 * integral;
    assert!(
        (mean - expected).abs() < 0.01 * expected,
        "{mean} vs {expected}"
    );
}

#[test]
fn ambient_occlusion_of_an_open_plane_is_one_and_half_in_a_corner() {
    let ambient = Some(Ambient {
        radiance: DVec3::splat(0.5),
        radius: f64::INFINITY,
    });
    // Every cosine-sampled ray escapes: each sample is exactly albedo * L_a.
    let got = converge(&floor_scene(vec![], ambient, false), 8);
    assert!((got.x - ALBEDO * 0.5).abs() < 1e-7, "{got}");
    // Next to an infinite wall the cosine-weighted visible fraction is 1/2
    // (the wall hides the half-space x < 0).
    let frames = 4000;
    let got = converge(&floor_scene(vec![], ambient, true), frames);
    let expected = ALBEDO * 0.5 * 0.5;
    // Binomial standard error of the visible fraction: sqrt(0.25 / 4000) ~ 0.008.
    assert!(
        (got.x - expected).abs() < 4.0 * 0.0079 * ALBEDO * 0.5,
        "{got} vs {expected}"
    );
}

#[test]
fn frames_are_replayable_and_independent_of_thread_count() {
    let light = Light::Area {
        corner: DVec3::new(-0.5, 2.0, -0.5),
        edge_u: DVec3::new(1.0, 0.0, 0.0),
        edge_v: DVec3::new(0.0, 0.0, 1.0),
        radiance: DVec3::splat(5.0),
    };
    let mut scene = floor_scene(
        vec![light],
        Some(Ambient {
            radiance: DVec3::splat(0.2),
            radius: 0.5,
        }),
        true,
    );
    scene.render.width = 16;
    scene.render.height = 12;
    scene.camera.fov_y_deg = 60.0;
    let render = |threads: usize, frames: u32| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let mut r = mode(&scene);
        let stats: Vec<_> = (0..frames)
            .map(|_| pool.install(|| r.render_frame()).counters.rays)
            .collect();
        (r.image(), stats)
    };
    let (a, ca) = render(2, 3);
    let (b, cb) = render(1, 3);
    assert_eq!(a, b);
    assert_eq!(ca, cb);
    assert_eq!(ca[0].primary, 16 * 12);
    assert_ne!(render(2, 4).0, a, "another frame adds other samples");
    // Every pixel replays alone: the film after two frames holds samples 0 and 1.
    let mut r = mode(&scene);
    r.render_frame();
    r.render_frame();
    let w = r.layer_weights();
    let img = r.image();
    let mut lit = 0;
    for (x, y) in (0..12).flat_map(|y| (0..16).map(move |x| (x, y))) {
        let v: DVec3 = (0..2)
            .flat_map(|i| r.sample(x, y, i).0.into_iter().zip(&w).map(|(l, w)| l * *w))
            .sum::<DVec3>()
            / 2.0;
        let got = img.get(x, y);
        assert!(
            (v.x as f32 - got[0]).abs() <= 1e-6 * got[0].abs().max(1e-6),
            "pixel {x},{y}: {v} vs {got:?}"
        );
        lit += usize::from(got[0] > 0.0);
    }
    assert!(lit > 100, "most pixels see lit surfaces");
}

#[test]
fn a_lambertian_plane_seen_in_a_mirror_is_the_reflectance_times_the_plane() {
    // The lit point is the origin, under a point light 2 m above it: L = albedo / pi *
    // I / 4 (closed form; view-independent). Seen directly from (0, 1, 0), and seen in a
    // vertical mirror of reflectance r at x = 0.5 from the same place, looking at
    // (0.5, 0.5, 0), whose reflection lands on the origin: r x L per channel.
    let light = Light::Point {
        position: DVec3::new(0.0, 2.0, 0.0),
        intensity: DVec3::splat(4.0),
    };
    let expected = ALBEDO / std::f64::consts::PI * 4.0 / 4.0;
    let reflectance = DVec3::new(0.8, 0.5, 0.25);
    let mut scene = floor_scene(vec![light], None, false);
    scene.materials.push(Material::Mirror { reflectance });
    scene.material_names.push("mirror".into());
    // Facing -x, from y = 0.2 up: it neither touches the floor nor shadows the origin.
    scene.meshes.push(meso_render::scene::mesh::quad(
        DVec3::new(0.5, 0.2, -5.0),
        DVec3::new(0.0, 0.0, 10.0),
        DVec3::new(0.0, 5.0, 0.0),
        1,
    ));
    let direct = converge(&scene, 1);
    assert!(
        (direct - DVec3::splat(expected)).abs().max_element() < 1e-5 * expected,
        "{direct} vs {expected}"
    );
    scene.camera.look_at = DVec3::new(0.5, 0.5, 0.0);
    scene.camera.up = DVec3::Y;
    let mirrored = converge(&scene, 1);
    // The pixel's footprint (about 2.5e-4 m wide at 1.4 m) moves cos / r^2 by < 1e-4.
    let want = reflectance * expected;
    assert!(
        (mirrored - want).abs().max_element() < 1e-4 * expected,
        "{mirrored} vs {want}"
    );
}

#[test]
fn packs_no_ray_reaches_hold_nothing_and_the_image_is_the_same_bit_for_bit() {
    // edit_test_scene's floor and SPMM panel, plus two larger packs on panels behind
    // the camera: shadow and AO rays may hit them but never shade them, so only the
    // visible pack is prepared, and the image equals the one rendered with every
    // pack prepared up front.
    use meso_render::scene::mesh::quad;
    let mut scene = meso_render::scene::test_scenes::edit_test_scene();
    let visible_full = |scene: &Scene| {
        let mode = SpmmMode::new(scene.clone(), 24, 24).expect("mode");
        mode.prepare_every_material();
        mode.diagnostics()
            .material_bytes()
            .expect("spmm reports")
            .full
    };
    let visible = visible_full(&scene);
    for (i, z) in [(2usize, 4.0), (3, 5.0)] {
        let pack = meso_materials::spmm::testing::sample_material(16, 16, 4, Some(4));
        scene.material_names.push(format!("behind{i}"));
        scene.materials.push(Material::Spmm {
            material: std::sync::Arc::new(pack),
            uv_scale: glam::DVec2::ONE,
            residual: true,
            npca: 4,
        });
        scene.meshes.push(quad(
            DVec3::new(-1.0, 0.0, z),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
            i,
        ));
    }
    let mut lazy = SpmmMode::new(scene.clone(), 24, 24).expect("mode");
    let mut eager = SpmmMode::new(scene.clone(), 24, 24).expect("mode");
    eager.prepare_every_material();
    for mode in [&mut lazy, &mut eager] {
        meso_render::run_frames(mode, 8, |_, _| {});
    }
    let (l, e) = (
        lazy.diagnostics().material_bytes().expect("bytes"),
        eager.diagnostics().material_bytes().expect("bytes"),
    );
    assert_eq!(l.full, e.full);
    assert_eq!(e.resident, e.full, "everything prepared");
    assert!(e.full > 3 * visible, "the hidden packs are the larger part");
    assert!(
        l.resident as f64 <= 1.2 * visible as f64,
        "resident {} against the visible pack's {visible}",
        l.resident
    );
    let (a, b) = (lazy.image(), eager.image());
    assert!(
        a.pixels()
            .iter()
            .zip(b.pixels())
            .all(|(p, q)| p.map(f32::to_bits) == q.map(f32::to_bits)),
        "bit-identical images"
    );
}

#[test]
fn only_the_residual_tables_of_clusters_rays_reach_are_held_and_the_image_is_the_same() {
    // The panel shows a tenth of a 16 x 16 pack in each direction: the texels its
    // rays reach belong to 2 of the pack's 4 clusters (clusters interleave as t * 7 % 4),
    // so half the residual tables are never laid out; the image equals the one
    // rendered with every table laid out up front, bit for bit.
    let mut scene = meso_render::scene::test_scenes::edit_test_scene();
    scene.materials[1] = Material::Spmm {
        material: std::sync::Arc::new(meso_materials::spmm::testing::sample_material(
            16,
            16,
            4,
            Some(4),
        )),
        uv_scale: glam::DVec2::splat(0.1),
        residual: true,
        npca: 4,
    };
    let mut lazy = SpmmMode::new(scene.clone(), 24, 24).expect("mode");
    let mut eager = SpmmMode::new(scene, 24, 24).expect("mode");
    eager.prepare_every_material();
    for mode in [&mut lazy, &mut eager] {
        meso_render::run_frames(mode, 8, |_, _| {});
    }
    let (l, e) = (
        lazy.diagnostics().material_bytes().expect("bytes"),
        eager.diagnostics().material_bytes().expect("bytes"),
    );
    assert_eq!((e.resident, l.full), (e.full, e.full));
    // One cluster's tables: 5 lights x 4 views cells of (1 + 4) RGB f32 values, each
    // cell padded from 15 floats to one 64-byte line.
    let table = (5 * 4 * 16 * 4) as u64;
    assert_eq!(
        e.resident - l.resident,
        2 * table,
        "two clusters' tables never laid out"
    );
    let (a, b) = (lazy.image(), eager.image());
    assert!(
        a.pixels()
            .iter()
            .zip(b.pixels())
            .all(|(p, q)| p.map(f32::to_bits) == q.map(f32::to_bits)),
        "bit-identical images"
    );
}
