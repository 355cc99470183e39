//! Environment lighting in the spmm mode against closed forms and invariants: a
//! constant environment equals unbounded ambient light (both estimators), the white
//! furnace, a small bright patch lights a plane like a directional light of the
//! patch's irradiance, a rotated map equals the scene rotated the other way, a
//! strength edit equals a fresh render bit for bit, a rotation restarts only its layer,
//! and rays that leave the scene read the map where it says.

use std::f64::consts::{PI, TAU};
use std::sync::Arc;

use glam::{DMat3, DVec3};

use super::SpmmMode;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::image::Image;
use meso_materials::metrics::compare;
use meso_render::RenderModeExt;
use meso_render::layers::ENVIRONMENT;
use meso_render::scene::mesh::quad;
use meso_render::scene::{
    Ambient, Background, Camera, Environment, Light, Material, Scene, TriangleMesh,
};
use meso_render::{Invalidation, RenderMode, SceneEdit};

fn constant_map(l: f32) -> Arc<Image> {
    let mut img = Image::new(16, 8);
    img.pixels_mut().iter_mut().for_each(|p| *p = [l; 3]);
    Arc::new(img)
}

fn environment(map: Arc<Image>, mis: bool) -> Environment {
    Environment {
        map,
        strength: 1.0,
        rotate_y_deg: 0.0,
        mis,
    }
}

fn lambertian(albedo: f64) -> Material {
    Material::Brdf {
        brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        albedo: DVec3::splat(albedo),
    }
}

/// The shared test floor at `size` x `size`, lit by nothing yet; rays that leave
/// it see the environment.
fn floor_scene(material: Material, wall: bool, size: u32) -> Scene {
    let mut s = meso_render::scene::test_scenes::floor_scene(material, wall);
    (s.render.width, s.render.height, s.render.seed) = (size, size, 4);
    s.background = Background::FromEnvironment;
    s
}

fn render(scene: &Scene, frames: u32) -> Image {
    let mut m =
        SpmmMode::new(scene.clone(), scene.render.width, scene.render.height).expect("valid scene");
    for _ in 0..frames {
        m.render_frame();
    }
    assert_eq!(m.progress().dropped, 0);
    m.image()
}

fn mean(img: &Image) -> DVec3 {
    img.pixels()
        .iter()
        .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .sum::<DVec3>()
        / img.pixels().len() as f64
}

#[test]
fn a_constant_environment_equals_unbounded_ambient_light() {
    // Same scenes, two estimators: ambient (radius inf, one cosine or defensive ray)
    // and the environment (map sampling + material sampling with MIS). A Lambertian
    // next to a wall (visible fraction 1/2 in closed form) and a tilted-basis SPMM.
    let l = 0.8;
    for (material, wall, expected) in [
        (lambertian(0.6), true, Some(0.6 * l * 0.5)),
        (lambertian(0.6), false, Some(0.6 * l)),
        (meso_render::scene::test_scenes::tilted_spmm(), false, None),
    ] {
        let mut with_ambient = floor_scene(material, wall, 16);
        with_ambient.ambient = Some(Ambient {
            radiance: DVec3::splat(l),
            radius: f64::INFINITY,
        });
        let mut with_env = with_ambient.clone();
        with_env.ambient = None;
        with_env.environment = Some(environment(constant_map(l as f32), true));
        // Rays that leave see black in both, so only lighting is compared.
        with_ambient.background = Background::Color(DVec3::ZERO);
        with_env.background = Background::Color(DVec3::ZERO);
        let a = mean(&render(&with_ambient, 128)).x;
        let e = mean(&render(&with_env, 128)).x;
        // 16^2 x 128 = 32768 samples each; the per-sample relative deviation of either
        // estimator is below 1 here, so each mean is within 0.6% (1 sigma); 3% is 5
        // sigma of their difference.
        assert!((a - e).abs() < 0.03 * a, "ambient {a} vs environment {e}");
        if let Some(x) = expected {
            assert!(
                (e - x).abs() < 0.03 * x,
                "environment {e} vs closed form {x}"
            );
        }
    }
}

#[test]
fn a_white_lambertian_in_a_white_furnace_is_white() {
    for mis in [true, false] {
        let mut scene = floor_scene(lambertian(1.0), false, 16);
        scene.environment = Some(environment(constant_map(1.0), mis));
        let m = mean(&render(&scene, 128));
        for c in m.to_array() {
            assert!((c - 1.0).abs() < 0.02, "mis {mis}: {m}");
        }
    }
}

/// A map that is black but for a `w` x `h` block of radiance `l` at (x0, y0).
fn patch_map(x0: u32, y0: u32, w: u32, h: u32, l: [f32; 3]) -> Image {
    let mut img = Image::new(64, 32);
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            img.set(x, y, l);
        }
    }
    img
}

#[test]
fn a_small_bright_patch_lights_a_plane_like_a_directional_light() {
    // Irradiance of a horizontal plane from the patch, exactly from the map's pixels:
    // each pixel is constant over theta in [t0, t1] (from +y) and a phi range of
    // 2 pi / 64, so its cosine-weighted solid angle is dphi (sin^2 t1 - sin^2 t0) / 2.
    let (x0, y0, w, h) = (40, 6, 2, 2);
    let l = [300.0f32, 200.0, 100.0];
    let dphi = TAU / 64.0;
    let projected: f64 = (y0..y0 + h)
        .map(|y| {
            let (t0, t1) = (PI * y as f64 / 32.0, PI * (y + 1) as f64 / 32.0);
            w as f64 * dphi * (t1.sin().powi(2) - t0.sin().powi(2)) / 2.0
        })
        .sum();
    let albedo = 0.7;
    for mis in [true, false] {
        let mut scene = floor_scene(lambertian(albedo), false, 16);
        let mut env = environment(Arc::new(patch_map(x0, y0, w, h, l)), mis);
        env.rotate_y_deg = 70.0; // a turn about the normal changes nothing here
        scene.environment = Some(env);
        let m = mean(&render(&scene, 64));
        for (c, li) in m.to_array().into_iter().zip(l) {
            let expected = albedo / PI * li as f64 * projected;
            // Map sampling draws only the patch, whose cosine varies by about 10%
            // over it: the estimate's relative deviation per sample is ~0.05, over
            // 16384 samples ~4e-4; MIS adds rare BRDF-sampled hits.
            assert!(
                (c - expected).abs() < 0.01 * expected,
                "mis {mis}: {c} vs {expected}"
            );
        }
    }
}

fn turn(p: DVec3, deg: f64) -> DVec3 {
    DMat3::from_rotation_y(deg.to_radians()) * p
}

fn turned_quad(corner: DVec3, u: DVec3, v: DVec3, material: usize, deg: f64) -> TriangleMesh {
    quad(turn(corner, deg), turn(u, deg), turn(v, deg), material)
}

/// A floor, a standing panel of anisotropic Ward (its tangent follows the geometry)
/// and a camera at an angle, everything turned by `deg` about +y, under a map with
/// a bright off-axis patch turned by `env_deg`.
fn rotation_scene(deg: f64, env_deg: f64) -> Scene {
    let mut s = floor_scene(lambertian(0.5), false, 32);
    s.materials.push(Material::Brdf {
        brdf: AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.08), ("ay", 0.3)]).expect("valid"),
        albedo: DVec3::new(0.9, 0.7, 0.4),
    });
    s.material_names.push("panel".into());
    s.meshes = vec![
        turned_quad(
            DVec3::new(-3.0, 0.0, 3.0),
            DVec3::new(6.0, 0.0, 0.0),
            DVec3::new(0.0, 0.0, -6.0),
            0,
            deg,
        ),
        turned_quad(
            DVec3::new(-0.6, 0.0, -0.3),
            DVec3::new(1.2, 0.0, 0.4),
            DVec3::new(0.0, 1.0, 0.0),
            1,
            deg,
        ),
    ];
    s.camera = Camera {
        position: turn(DVec3::new(1.5, 1.4, 2.2), deg),
        look_at: turn(DVec3::new(0.0, 0.4, 0.0), deg),
        up: DVec3::Y,
        fov_y_deg: 55.0,
    };
    let mut map = patch_map(10, 5, 4, 3, [40.0, 30.0, 20.0]);
    for p in map.pixels_mut() {
        p[0] += 0.05;
        p[1] += 0.1;
        p[2] += 0.2;
    }
    let mut env = environment(Arc::new(map), true);
    env.rotate_y_deg = env_deg;
    s.environment = Some(env);
    s
}

#[test]
fn turning_the_map_equals_turning_the_scene_the_other_way() {
    let a = render(&rotation_scene(0.0, 90.0), 16);
    let b = render(&rotation_scene(-90.0, 0.0), 16);
    let c = compare(&a, &b, 0.0).expect("same size");
    // The same samples in rotated coordinates: only f32 traversal rounding differs.
    let scale = mean(&a).max_element();
    assert!(c.rmse < 0.01 * scale && c.mssim > 0.995, "{c:?}");
    // A map turned the wrong way round gives a different image.
    let wrong = render(&rotation_scene(-90.0, 180.0), 16);
    let d = compare(&a, &wrong, 0.0).expect("same size");
    assert!(d.rmse > 10.0 * c.rmse.max(1e-6), "{d:?} vs {c:?}");
}

#[test]
fn a_strength_edit_keeps_every_sample_and_a_turn_restarts_only_its_layer() {
    let mut scene = rotation_scene(0.0, 30.0);
    scene.lights.push(Light::Point {
        position: DVec3::new(1.0, 2.0, 1.0),
        intensity: DVec3::splat(2.0),
    });
    let mut m = SpmmMode::new(scene.clone(), 32, 32).expect("valid");
    for _ in 0..3 {
        m.render_frame();
    }
    let mut stronger = scene.environment.clone().expect("has one");
    stronger.strength = 2.5;
    assert_eq!(
        m.apply(SceneEdit::Environment(Some(stronger.clone()))),
        Ok(Invalidation::Nothing)
    );
    let mut fresh_scene = scene.clone();
    fresh_scene.environment = Some(stronger.clone());
    assert_eq!(m.image(), render(&fresh_scene, 3), "bit for bit");
    // A turn restarts the environment layer only: the point light's samples stay.
    let mut turned = stronger;
    turned.rotate_y_deg = 75.0;
    assert_eq!(
        m.apply(SceneEdit::Environment(Some(turned.clone()))),
        Ok(Invalidation::Layer(ENVIRONMENT))
    );
    for _ in 0..2 {
        m.render_frame();
    }
    turned.strength = 0.0;
    m.apply(SceneEdit::Environment(Some(turned.clone())))
        .expect("valid");
    fresh_scene.environment = Some(turned);
    assert_eq!(
        m.image(),
        render(&fresh_scene, 5),
        "the light's 5 frames kept"
    );
    // Off and on again with the same map: nothing to redo.
    assert_eq!(
        m.apply(SceneEdit::Environment(None)),
        Ok(Invalidation::Nothing)
    );
}

#[test]
fn rays_that_leave_the_scene_read_the_map_where_the_convention_says() {
    // No geometry: a narrow camera looks along d, the map is turned by 90 degrees, so
    // it must read the unrotated map at R_y(-90) d, chosen at the centre of pixel
    // (20, 10) of a map whose pixels encode their own coordinates.
    let mut map = Image::new(64, 32);
    for y in 0..32 {
        for x in 0..64 {
            map.set(x, y, [x as f32, y as f32, 1.0]);
        }
    }
    let seen = meso_render::environment::direction_at(20.5 / 64.0, 10.5 / 32.0);
    let d = turn(seen, 90.0);
    let mut scene = floor_scene(lambertian(0.5), false, 3);
    scene.meshes.clear();
    scene.camera = Camera {
        position: DVec3::ZERO,
        look_at: d,
        up: DVec3::Y,
        fov_y_deg: 0.01,
    };
    let mut env = environment(Arc::new(map), true);
    env.rotate_y_deg = 90.0;
    env.strength = 2.0;
    scene.environment = Some(env);
    assert_eq!(render(&scene, 1).get(1, 1), [40.0, 20.0, 2.0]);
    // With a [background] colour, escaping rays see the colour instead.
    scene.background = Background::Color(DVec3::new(0.1, 0.2, 0.3));
    assert_eq!(render(&scene, 1).get(1, 1), [0.1, 0.2, 0.3]);
    // `[background] environment = ...`: the same convention, never turned and never
    // scaled by the [environment]'s turn and strength: looking along `seen` reads
    // pixel (20, 10) as it is.
    let map = scene.environment.as_ref().expect("set above").map.clone();
    scene.background = Background::Environment(map.clone());
    scene.camera.look_at = seen;
    assert_eq!(render(&scene, 1).get(1, 1), [20.0, 10.0, 1.0]);
    // ... and seen but not lighting: with no [environment] a floor under it is black.
    let mut floor = floor_scene(lambertian(0.5), false, 3);
    floor.background = Background::Environment(map);
    assert_eq!(render(&floor, 4).get(1, 1), [0.0, 0.0, 0.0]);
}

/// An analytic sky (brighter towards the zenith, bluish) with a small sun disc of
/// radius 2 degrees at elevation 35 degrees, each pixel the mean of 4 x 4 points.
fn sky_with_sun(width: u32, height: u32) -> Image {
    let sun = meso_render::environment::direction_at(0.62, (90.0 - 35.0) / 180.0);
    let cos_radius = 2f64.to_radians().cos();
    let mut img = Image::new(width, height);
    for y in 0..height {
        for x in 0..width {
            let mut sum = DVec3::ZERO;
            for (i, j) in (0..4).flat_map(|i| (0..4).map(move |j| (i, j))) {
                let d = meso_render::environment::direction_at(
                    (x as f64 + (i as f64 + 0.5) / 4.0) / width as f64,
                    (y as f64 + (j as f64 + 0.5) / 4.0) / height as f64,
                );
                let up = d.y.max(0.0);
                sum += DVec3::new(0.3, 0.45, 0.8) * (0.2 + up) + DVec3::splat(0.05);
                if d.dot(sun) > cos_radius {
                    sum += DVec3::new(900.0, 800.0, 650.0);
                }
            }
            let p = sum / 16.0;
            img.set(x, y, [p.x as f32, p.y as f32, p.z as f32]);
        }
    }
    img
}

#[test]
fn tilted_lambertian_planes_under_a_rotated_sky_with_a_sun_match_quadrature() {
    // The reference integrates the map (piecewise constant over its pixels) against
    // the clamped cosine of the plane's normal by a 16 x 16 midpoint rule in (phi,
    // cos theta) inside each pixel: independent of the renderer's samplers.
    let (w, h) = (128u32, 64u32);
    let map = Arc::new(sky_with_sun(w, h));
    for (tilt_deg, turn_deg) in [(0.0, 0.0), (40.0, 57.0), (75.0, -120.0), (30.0, 200.0)] {
        let normal = DMat3::from_rotation_z(f64::to_radians(tilt_deg)) * DVec3::Y;
        let mut irradiance = DVec3::ZERO;
        for y in 0..h {
            let (c0, c1) = (
                (PI * y as f64 / h as f64).cos(),
                (PI * (y + 1) as f64 / h as f64).cos(),
            );
            for x in 0..w {
                let p = map.get(x, y);
                let l = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                let mut projected = 0.0;
                for i in 0..16 {
                    let phi = TAU * ((x as f64 + (i as f64 + 0.5) / 16.0) / w as f64 - 0.5);
                    for j in 0..16 {
                        let c = c0 + (c1 - c0) * (j as f64 + 0.5) / 16.0;
                        let s = (1.0 - c * c).max(0.0).sqrt();
                        let d = meso_render::environment::rotate_y(
                            DVec3::new(s * phi.cos(), c, s * phi.sin()),
                            turn_deg,
                        );
                        projected += d.dot(normal).max(0.0);
                    }
                }
                // Each sub-cell's solid angle: dphi x dcos.
                irradiance += l * projected * (TAU / w as f64 / 16.0) * ((c0 - c1) / 16.0);
            }
        }
        let albedo = 0.8;
        let expected = irradiance * albedo / PI;
        // A large quad through the origin with that normal, seen along it.
        let (t, b) = meso_materials::brdf::warp::orthonormal_basis(normal);
        let mut scene = floor_scene(lambertian(albedo), false, 16);
        scene.meshes = vec![quad(-50.0 * (t + b), 100.0 * t, 100.0 * b, 0)];
        if scene.meshes[0].normals[0].dot(normal) < 0.0 {
            scene.meshes = vec![quad(-50.0 * (t + b), 100.0 * b, 100.0 * t, 0)];
        }
        scene.camera = Camera {
            position: normal,
            look_at: DVec3::ZERO,
            up: t,
            fov_y_deg: 0.01,
        };
        let mut env = environment(Arc::clone(&map), true);
        env.rotate_y_deg = turn_deg;
        scene.environment = Some(env);
        let got = mean(&render(&scene, 256));
        for (g, e) in got.to_array().into_iter().zip(expected.to_array()) {
            // 65536 samples; the sun carries most of the light and map sampling draws
            // it in proportion: the per-sample deviation is about 0.3 of the mean,
            // about 1.2e-3 for the mean: 1% is 8 standard errors.
            assert!(
                (g - e).abs() < 0.01 * e,
                "tilt {tilt_deg} turn {turn_deg}: {got} vs {expected}"
            );
        }
    }
}
