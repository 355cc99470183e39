//! The biscale mode against closed forms, its own rules and bad input: a Lambertian
//! plane under a constant environment, one bright cube pixel landing in the cell the
//! binning rule names, the SH baseline against the pixel basis, losslessness on a
//! real mesh, the cache's round trip and its refusals.

use std::f64::consts::PI;
use std::sync::Arc;

use glam::{DVec2, DVec3};

use super::cubemap::CubeLayout;
use super::hemisphere::{HemisphereGrid, square_to_hemisphere};
use super::sh::ShTransfer;
use super::{BiscaleMode, BiscaleSettings, TransferSource, cache};
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::image::Image;
use meso_render::scene::test_scenes::{edit_test_scene, floor_scene};
use meso_render::scene::{Environment, Light, Material, Scene};
use meso_render::{ModeError, Prepare, RenderMode, RenderModeExt, SceneEdit, run_frames};

const ALBEDO: f64 = 0.6;

fn lambertian() -> Material {
    Material::Brdf {
        brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        albedo: DVec3::splat(ALBEDO),
    }
}

fn map_of(w: u32, h: u32, f: impl Fn(u32, u32) -> [f32; 3]) -> Arc<Image> {
    let mut img = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            img.set(x, y, f(x, y));
        }
    }
    Arc::new(img)
}

/// The floor scene (plane y = 0, normal +y, tangent +x) under `map`.
fn plane_scene(map: Arc<Image>) -> Scene {
    let mut scene = floor_scene(lambertian(), false);
    scene.environment = Some(Environment {
        map,
        strength: 1.0,
        rotate_y_deg: 0.0,
        mis: true,
    });
    scene
}

/// The plane under a smooth coloured map twice: with a Lambertian of `albedo`, and
/// with `other` (a tabulation of the same Lambertian).
fn lambertian_plane_and(albedo: DVec3, other: Material) -> (Scene, Scene) {
    let map = map_of(32, 16, |x, y| {
        [0.2 + x as f32 / 32.0, 0.5, 0.2 + y as f32 / 16.0]
    });
    let mut analytic = plane_scene(map.clone());
    analytic.materials[0] = Material::Brdf {
        brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        albedo,
    };
    let mut tabulated = plane_scene(map);
    tabulated.materials[0] = other;
    (analytic, tabulated)
}

/// No cache, and transfer at the scene's own vertices: these tests are about the
/// transfer and its edits on a known tessellation (the refinement's test turns it on;
/// a centre pixel on a refined floor can sit on a T-junction, where the coarser
/// side's interpolation differs from the finer side's).
fn settings() -> BiscaleSettings {
    BiscaleSettings {
        cache_dir: None,
        refine_vertices: 0,
        ..BiscaleSettings::default()
    }
}

fn centre_pixel(mode: &mut BiscaleMode, frames: u32) -> DVec3 {
    run_frames(mode, frames, |_, _| {});
    let p = mode.image().get(1, 1);
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

#[test]
fn a_lambertian_plane_in_a_constant_environment_matches_the_closed_form() {
    // Exact: L_o = albedo x L for any unoccluded Lambertian plane. The mode's only
    // approximation here is the binning: whole cube pixels go to the cell holding
    // their centre, so a cell's collected solid angle differs from 2 pi / M by the
    // pixels straddling its border; that border is one pixel wide, so its share of a
    // cell falls as 1 / n. Measured: 0.21% at n = 32, 0.95% at n = 16 (the errors of
    // the 64 cells partly cancel); bound 0.3 / n (0.94%, 1.9%).
    let radiance = 0.7;
    for n in [32, 16] {
        let scene = plane_scene(map_of(16, 8, |_, _| [radiance; 3]));
        let s = BiscaleSettings {
            cube_n: n,
            ..settings()
        };
        let mut mode = BiscaleMode::prepare(scene, 3, 3, s, Prepare::quietly()).expect("mode");
        let got = centre_pixel(&mut mode, 4);
        let expected = ALBEDO * radiance as f64;
        let rel = (got.x / expected - 1.0).abs();
        eprintln!("n = {n}: {got} vs {expected}: {rel:e}");
        assert!(rel < 0.3 / n as f64, "n = {n}: {got} vs {expected}");
    }
}

#[test]
fn a_small_bright_source_is_traced_and_lights_a_lambertian_plane_exactly() {
    // A 2 x 2-pixel source of 400 (and a dim gradient) over a Lambertian plane: exact,
    // L_o = albedo / pi x sum over the map's upper pixels of L cos(theta) dOmega
    // (summed here over 8 x 8 points per pixel). The transfer alone puts the source's
    // power in one local cell of about 20 degrees and shades it with the cell's mean
    // cosine; traced (the default share), the source is exact and the cells carry the
    // gradient. Measured at 64 frames, worst channel: 0.97% traced, 5.6% by the
    // transfer alone. Bounds 2% and (that the source sits where cells err) 3%.
    let (w, h) = (64, 32);
    let map = map_of(w, h, |x, y| {
        if (40..42).contains(&x) && (9..11).contains(&y) {
            [400.0, 300.0, 200.0]
        } else {
            [0.2 + x as f32 / 128.0, 0.3, 0.2 + y as f32 / 64.0]
        }
    });
    let mut exact = DVec3::ZERO;
    let k = 8;
    for y in 0..h {
        for x in 0..w {
            let p = map.get(x, y);
            let radiance = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let d_omega = meso_render::environment::pixel_solid_angle(w, h, y) / (k * k) as f64;
            for s in 0..k * k {
                let d = meso_render::environment::direction_at(
                    (x as f64 + ((s % k) as f64 + 0.5) / k as f64) / w as f64,
                    (y as f64 + ((s / k) as f64 + 0.5) / k as f64) / h as f64,
                );
                exact += radiance * d.y.max(0.0) * d_omega;
            }
        }
    }
    exact *= ALBEDO / std::f64::consts::PI;
    let error = |share: f64| {
        let s = BiscaleSettings {
            traced_share: share,
            ..settings()
        };
        let scene = plane_scene(map.clone());
        let mut mode = BiscaleMode::prepare(scene, 3, 3, s, Prepare::quietly()).expect("mode");
        let got = centre_pixel(&mut mode, 64);
        ((got - exact) / exact).abs().max_element()
    };
    let (traced, cells) = (
        error(meso_render::environment::DEFAULT_TRACED_SHARE),
        error(0.0),
    );
    assert!(
        traced < 0.02 && cells > 0.03,
        "traced {traced}, cells {cells}"
    );
}

/// The cell of the 8 x 8 grid whose forward-mapped points come nearest to `d`: an
/// independent search (forward map only) for the cell that contains `d`.
fn nearest_cell_by_forward_map(grid: HemisphereGrid, d: DVec3) -> usize {
    let steps = 24;
    let mut best = (f64::INFINITY, 0);
    for m in 0..grid.len() {
        let (ix, iy) = (m as u32 % grid.res, m as u32 / grid.res);
        for i in 0..steps * steps {
            let f = DVec2::new(
                (ix as f64 + ((i % steps) as f64 + 0.5) / steps as f64) / grid.res as f64,
                (iy as f64 + ((i / steps) as f64 + 0.5) / steps as f64) / grid.res as f64,
            );
            let dist = (square_to_hemisphere(f) - d).length();
            if dist < best.0 {
                best = (dist, m);
            }
        }
    }
    best.1
}

#[test]
fn one_bright_cube_pixel_lands_in_the_cell_of_its_centre() {
    // Rule (docs/rendering.md): a cube pixel's visible fraction x its solid angle goes
    // to the local cell containing the pixel's centre direction. For a Lambertian
    // plane the image is then E x solid angle x albedo / pi x (the cell's mean cos).
    let scene = plane_scene(map_of(16, 8, |_, _| [0.0; 3]));
    let mut mode = BiscaleMode::prepare(scene, 3, 3, settings(), Prepare::quietly()).expect("mode");
    let cube = CubeLayout::new(32);
    let grid = HemisphereGrid::new(8);
    let e = 1000.0f32;
    for d in [
        DVec3::new(0.3, 0.8, 0.2),
        DVec3::new(-0.6, 0.5, -0.1),
        DVec3::new(0.1, 0.2, -0.9),
    ] {
        let k = cube.pixel_of(d.normalize());
        let centre = cube.centre(k);
        // The plane's frame: normal +y, tangent +x (along u), bitangent n x t = -z.
        let local = DVec3::new(centre.x, -centre.z, centre.y);
        let m = nearest_cell_by_forward_map(grid, local);
        let strata = 40;
        let mean_cos: f64 =
            grid.strata(m, strata).map(|w| w.z).sum::<f64>() / (strata * strata) as f64;
        let expected = e as f64 * cube.solid_angle(k) * ALBEDO / PI * mean_cos;
        let mut light = vec![[0.0f32; 3]; cube.len()];
        light[k] = [e; 3];
        mode.relight_with(light);
        let got = centre_pixel(&mut mode, 2).x;
        eprintln!("pixel {k} -> cell {m}: {got} vs {expected}");
        // The table's 3 x 3-strata cell mean of cos against a 40 x 40 one: measured
        // 0.07%, 0.10% and 0.25% (the last cell touches the horizon, where cos varies
        // most across it); a neighbouring cell's mean cos differs by 5% or more.
        assert!((got / expected - 1.0).abs() < 5e-3, "{got} vs {expected}");
    }
}

#[test]
fn the_sh_baseline_agrees_on_a_low_frequency_environment() {
    // Radiance 1 + 0.5 y + 0.3 x over the sphere (band 1): the SH transfer of order 5
    // reproduces the plane's shading closely; it differs from the pixel basis only by
    // the truncation of the horizon's step (measured 1.1%; bound 3%). The pixel basis
    // is within 0.5% of the closed form.
    let (w, h) = (64, 32);
    let map = map_of(w, h, |x, y| {
        let d = meso_render::environment::direction_at(
            (x as f64 + 0.5) / w as f64,
            (y as f64 + 0.5) / h as f64,
        );
        let v = (1.0 + 0.5 * d.y + 0.3 * d.x) as f32;
        [v, v, v]
    });
    let scene = plane_scene(map);
    let mut mode = BiscaleMode::prepare(scene, 3, 3, settings(), Prepare::quietly()).expect("mode");
    let pixel = centre_pixel(&mut mode, 2).x;
    let pre = mode.precomputed().clone();
    let sh = ShTransfer::build(
        &pre.transfer,
        &pre.frames,
        CubeLayout::new(32),
        HemisphereGrid::new(8),
        5,
    );
    mode.set_transfer_source(TransferSource::Sh(Arc::new(sh)));
    let sh_pixel = centre_pixel(&mut mode, 2).x;
    // Closed form for the plane: albedo x (1 + 0.5 x 2/3) (the cosine-weighted mean of
    // y over the upper hemisphere is 2/3; x averages to zero).
    let exact = ALBEDO * (1.0 + 0.5 * 2.0 / 3.0);
    eprintln!("pixel basis {pixel}, SH {sh_pixel}, exact {exact}");
    assert!((pixel / exact - 1.0).abs() < 0.01);
    assert!(
        (sh_pixel / pixel - 1.0).abs() < 0.03,
        "{sh_pixel} vs {pixel}"
    );
}

#[test]
fn a_turned_environment_is_a_light_change_and_strength_keeps_the_samples() {
    // The plane beside a wall (x = 0, facing +x): turning the map about the normal
    // changes what the wall hides.
    let map = map_of(32, 16, |x, _| [if x < 8 { 4.0 } else { 0.2 }; 3]);
    let mut scene = floor_scene(lambertian(), true);
    scene.environment = plane_scene(map).environment;
    let mut mode =
        BiscaleMode::prepare(scene.clone(), 3, 3, settings(), Prepare::quietly()).expect("mode");
    let key = mode.precomputed().key;
    let before = centre_pixel(&mut mode, 1);
    let mut env = scene.environment.clone().expect("env");
    env.strength = 2.0;
    assert_eq!(
        mode.apply(SceneEdit::Environment(Some(env.clone()))),
        Ok(meso_render::Invalidation::Nothing)
    );
    let doubled = DVec3::from(mode.image().get(1, 1).map(|c| c as f64));
    assert!((doubled / before - 2.0).abs().max_element() < 1e-5);
    env.rotate_y_deg = 90.0;
    mode.apply(SceneEdit::Environment(Some(env.clone())))
        .expect("turn");
    assert_eq!(mode.precomputed().key, key, "no recomputation of T");
    let turned = centre_pixel(&mut mode, 1);
    // The same as a mode prepared with the turned environment from the start.
    scene.environment = Some(env);
    let mut fresh =
        BiscaleMode::prepare(scene, 3, 3, settings(), Prepare::quietly()).expect("mode");
    let direct = centre_pixel(&mut fresh, 1);
    assert!(
        (turned - direct).abs().max_element() < 1e-6,
        "{turned} vs {direct}"
    );
    assert!(
        (turned - doubled).abs().max_element() > 1e-3,
        "the turn changed nothing"
    );
}

#[test]
fn a_btf_material_renders_like_the_brdf_it_tabulates() {
    // A `btf` material has no table: each local cell's BTF is read at a jittered
    // direction (an unbiased estimate of the cell average a table holds). A Lambertian
    // tabulated on Bonn's 81 directions, and on UBO2014's 151, against the analytic
    // Lambertian's table under the same map: they differ by the BTF's interpolation of
    // cos_i between its light directions and the jitter's noise. Measured at 64 frames:
    // 0.33% in the worst channel on the 81 directions; bound 1% on both layouts.
    use meso_materials::btf::directions::{bonn81, ubo151};
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    let lambert = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    for (layout, dirs) in [("bonn81", bonn81()), ("ubo151", ubo151())] {
        let (analytic, tabulated) = lambertian_plane_and(
            albedo,
            meso_render::scene::test_scenes::tabulated_btf_on(&lambert, albedo, DVec2::ONE, dirs),
        );
        BiscaleMode::supports(&tabulated).expect("btf materials are shaded");
        let a = centre_pixel(
            &mut BiscaleMode::prepare(analytic, 3, 3, settings(), Prepare::quietly())
                .expect("mode"),
            1,
        );
        let t = centre_pixel(
            &mut BiscaleMode::prepare(tabulated, 3, 3, settings(), Prepare::quietly())
                .expect("mode"),
            64,
        );
        assert!(a.min_element() > 0.05, "{layout}: {a}");
        eprintln!("{layout}: {t} against {a}");
        assert!(
            ((t - a) / a).abs().max_element() < 0.01,
            "{layout}: {t} against {a}"
        );
    }
}

#[test]
fn the_environment_turns_on_and_off_as_a_light_change() {
    // Without an environment the precomputed part is dark and the lights are the
    // image; turning a map on relights L* from the same transfer, and gives what a
    // mode prepared with the map from the start gives; turning it off again gives the
    // dark part back.
    let scene = plane_scene(map_of(16, 8, |x, _| [0.3 + x as f32 / 16.0, 0.4, 0.6]));
    let env = scene.environment.clone().expect("a map");
    let mut dark = scene.clone();
    dark.environment = None;
    BiscaleMode::supports(&dark).expect("a scene without an environment renders");
    let mut mode = BiscaleMode::prepare(dark, 3, 3, settings(), Prepare::quietly()).expect("mode");
    assert_eq!(centre_pixel(&mut mode, 1), DVec3::ZERO, "no lights: black");
    mode.apply(SceneEdit::Environment(Some(env)))
        .expect("turned on");
    let on = centre_pixel(&mut mode, 1);
    let fresh = centre_pixel(
        &mut BiscaleMode::prepare(scene, 3, 3, settings(), Prepare::quietly()).expect("mode"),
        1,
    );
    assert!(fresh.min_element() > 0.05, "{fresh}");
    assert!((on - fresh).abs().max_element() < 1e-6, "{on} vs {fresh}");
    mode.apply(SceneEdit::Environment(None))
        .expect("turned off");
    assert_eq!(centre_pixel(&mut mode, 1), DVec3::ZERO);
}

#[test]
fn the_cache_round_trips_and_refuses_stale_or_damaged_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = plane_scene(map_of(8, 4, |_, _| [1.0; 3]));
    let s = BiscaleSettings {
        cube_n: 8,
        cache_dir: Some(dir.path().to_path_buf()),
        ..BiscaleSettings::default()
    };
    let first =
        BiscaleMode::prepare(scene.clone(), 3, 3, s.clone(), Prepare::quietly()).expect("mode");
    assert!(!first.precomputed().stats.from_cache);
    let path = cache::path_in(dir.path(), first.precomputed().key);
    assert!(path.exists());
    let second =
        BiscaleMode::prepare(scene.clone(), 3, 3, s.clone(), Prepare::quietly()).expect("mode");
    assert!(second.precomputed().stats.from_cache);
    assert_eq!(second.precomputed().transfer, first.precomputed().transfer);
    assert_eq!(
        second.precomputed().biclusters,
        first.precomputed().biclusters
    );
    let vertices = first.precomputed().frames.len();
    let key = first.precomputed().key;
    // Stale: another key.
    let err = cache::read(&path, key ^ 1, &s, vertices).expect_err("stale");
    assert!(err.to_string().contains("stale"), "{err}");
    // Damaged: one byte of tensor data flipped, or the file cut short.
    let bytes = std::fs::read(&path).expect("read");
    let mut flipped = bytes.clone();
    let last = flipped.len() - 1;
    flipped[last] ^= 0x10;
    std::fs::write(&path, &flipped).expect("write");
    let err = cache::read(&path, key, &s, vertices).expect_err("damaged");
    assert!(err.to_string().contains("checksum"), "{err}");
    assert!(
        err.to_string().contains(&path.display().to_string()),
        "{err}"
    );
    // A damaged cache is rebuilt, never trusted, and rewritten whole.
    let third =
        BiscaleMode::prepare(scene.clone(), 3, 3, s.clone(), Prepare::quietly()).expect("mode");
    let stats = &third.precomputed().stats;
    assert!(
        !stats.from_cache && stats.cache_rejected.is_some(),
        "{stats:?}"
    );
    assert_eq!(std::fs::read(&path).expect("read"), bytes);
    std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("write");
    assert!(cache::read(&path, key, &s, vertices).is_err());
    // Structurally wrong contents with a correct checksum are refused too.
    let mut t = first.precomputed().transfer.clone();
    t.columns[0] = 1_000_000;
    let bad = cache::encode(key, &s, &t, &first.precomputed().biclusters);
    let err = cache::decode(&bad, key, &s, vertices).expect_err("out of range");
    assert!(err.contains("column 1000000 out of range"), "{err}");
}

#[test]
fn the_biclustered_product_equals_the_dense_one_on_a_mesh() {
    // The plane with a wall beside it (occlusion gives the matrix its structure).
    let mut scene = floor_scene(lambertian(), true);
    // Subdivide nothing: the two quads have 8 vertices; use a finer cube to get more
    // rows and columns.
    scene.environment = plane_scene(map_of(4, 2, |_, _| [1.0; 3])).environment;
    let s = BiscaleSettings {
        cube_n: 16,
        ..settings()
    };
    let mode = BiscaleMode::prepare(scene, 3, 3, s, Prepare::quietly()).expect("mode");
    let pre = mode.precomputed();
    let rng = meso_materials::rng::SampleStream::new(&[8]);
    for round in 0..3u64 {
        let light: Vec<[f32; 3]> = (0..pre.transfer.cols as u64)
            .map(|k| {
                [
                    rng.at(round * 100_000 + 3 * k) as f32,
                    rng.at(round * 100_000 + 3 * k + 1) as f32,
                    1.0,
                ]
            })
            .collect();
        let dense = pre.transfer.apply_f64(&light);
        let got = pre.biclusters.apply(&light);
        let err = super::bicluster::tests::relative_error(&dense, &got);
        assert!(err < 1e-6, "relative error {err}");
    }
    assert!(pre.flop_ratio() < 1.0, "{}", pre.flop_ratio());
}

/// A UV sphere of radius 0.5 at the origin: `rings` x `segments` quads, smooth normals,
/// u along the azimuth (so the tangent is well defined away from the poles).
fn uv_sphere(rings: u32, segments: u32) -> meso_render::scene::TriangleMesh {
    let (mut positions, mut normals, mut uvs, mut indices) = (vec![], vec![], vec![], vec![]);
    for i in 0..=rings {
        let v = i as f64 / rings as f64;
        let theta = PI * v;
        for j in 0..=segments {
            let u = j as f64 / segments as f64;
            let phi = 2.0 * PI * u;
            let n = DVec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                -theta.sin() * phi.sin(),
            );
            positions.push(n * 0.5);
            normals.push(n);
            uvs.push(DVec2::new(u, 1.0 - v));
        }
    }
    let w = segments + 1;
    for i in 0..rings {
        for j in 0..segments {
            let (a, b, c, d) = (
                i * w + j,
                i * w + j + 1,
                (i + 1) * w + j + 1,
                (i + 1) * w + j,
            );
            indices.push([a, d, c]);
            indices.push([a, c, b]);
        }
    }
    meso_render::scene::TriangleMesh {
        positions,
        normals,
        uvs,
        indices,
        material: 0,
    }
}

#[test]
fn a_lambertian_sphere_under_a_map_agrees_with_the_spmm_mode() {
    // No occlusion and a smooth frame field: what is left is the cube map's and the
    // cells' discretisation and the per-vertex interpolation of L*.
    let (w, h) = (64, 32);
    let map = map_of(w, h, |x, y| {
        let d = meso_render::environment::direction_at(
            (x as f64 + 0.5) / w as f64,
            (y as f64 + 0.5) / h as f64,
        );
        let bright = d.dot(DVec3::new(0.6, 0.7, 0.4).normalize()) > 0.9;
        [
            if bright { 20.0 } else { 0.3 },
            0.5,
            0.4 + 0.3 * d.y.max(0.0) as f32,
        ]
    });
    let mut scene = plane_scene(map);
    scene.meshes = vec![uv_sphere(24, 48)];
    scene.camera = meso_render::scene::Camera {
        position: DVec3::new(0.0, 0.3, 2.0),
        look_at: DVec3::ZERO,
        up: DVec3::Y,
        fov_y_deg: 35.0,
    };
    let (iw, ih) = (32, 32);
    let mut spmm = crate::trace::SpmmMode::new(scene.clone(), iw, ih).expect("spmm");
    run_frames(&mut spmm, 1024, |_, _| {});
    let reference = spmm.image();
    let mut mode =
        BiscaleMode::prepare(scene, iw, ih, settings(), Prepare::quietly()).expect("mode");
    run_frames(&mut mode, 64, |_, _| {});
    let image = mode.image();
    let mean = |img: &Image| {
        img.pixels()
            .iter()
            .map(|p| p[0] as f64 + p[1] as f64 + p[2] as f64)
            .sum::<f64>()
    };
    let ratio = mean(&image) / mean(&reference);
    let c = meso_materials::metrics::compare(&reference, &image, 0.0).expect("same size");
    eprintln!(
        "sphere: mean ratio {ratio}, rmse {}, mssim {}",
        c.rmse, c.mssim
    );
    assert!((ratio - 1.0).abs() < 0.02, "mean ratio {ratio}");
    assert!(c.mssim > 0.95, "{c:?}");
}

#[test]
fn moving_frames_take_the_nearest_view_and_still_frames_restart() {
    // A Lambertian table does not depend on the view: the fast frames equal the full
    // ones; the switch each way restarts the image (samples must not mix).
    let scene = plane_scene(map_of(16, 8, |x, _| [0.2 + x as f32 * 0.1; 3]));
    let mut mode = BiscaleMode::prepare(scene, 3, 3, settings(), Prepare::quietly()).expect("mode");
    let still = centre_pixel(&mut mode, 2);
    assert_eq!(
        mode.apply(SceneEdit::Moving(true)),
        Ok(meso_render::Invalidation::All)
    );
    assert_eq!(mode.progress().frames, 0);
    let moving = centre_pixel(&mut mode, 2);
    assert!(
        (moving - still).abs().max_element() < 1e-6,
        "{moving} vs {still}"
    );
    assert_eq!(
        mode.apply(SceneEdit::Moving(true)),
        Ok(meso_render::Invalidation::Nothing)
    );
    assert_eq!(
        mode.apply(SceneEdit::Moving(false)),
        Ok(meso_render::Invalidation::All)
    );
}

#[test]
fn meshes_without_uvs_and_cancelled_preparations_fail_cleanly() {
    // An OBJ without texture coordinates gets the documented spherical UVs and renders
    // an SPMM material; an edit bringing a mesh without UVs is refused naming it.
    let dir = tempfile::tempdir().expect("temp dir");
    let obj = dir.path().join("tetra.obj");
    std::fs::write(
        &obj,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .expect("write");
    let placement = meso_render::scene::mesh::Placement {
        scale: 1.0,
        rotation: glam::DMat3::IDENTITY,
        translate: DVec3::ZERO,
    };
    let mesh = meso_render::scene::mesh::load_obj(&obj, &placement, 0).expect("loads");
    assert_eq!(mesh.uvs.len(), mesh.positions.len(), "default UVs");
    let mut scene = plane_scene(map_of(8, 4, |_, _| [1.0; 3]));
    scene.materials[0] = meso_render::scene::test_scenes::tilted_spmm();
    scene.meshes = vec![mesh.clone()];
    scene.camera.position = DVec3::new(2.0, 2.0, 2.0);
    scene.camera.look_at = DVec3::splat(0.2);
    scene.camera.up = DVec3::Y;
    scene.camera.fov_y_deg = 40.0;
    let s = BiscaleSettings {
        cube_n: 8,
        ..settings()
    };
    let mut mode = BiscaleMode::prepare(scene.clone(), 8, 8, s.clone(), Prepare::quietly())
        .expect("renders with default UVs");
    run_frames(&mut mode, 1, |_, _| {});
    let mut bare = mesh;
    bare.uvs.clear();
    let err = mode
        .apply(SceneEdit::Meshes(vec![bare]))
        .expect_err("refused");
    assert!(
        err.to_string().contains("mesh 0") && err.to_string().contains("uvs"),
        "{err}"
    );
    // Cancelled before and during the precomputation.
    let cancel = std::sync::atomic::AtomicBool::new(true);
    let err = BiscaleMode::prepare(
        scene.clone(),
        8,
        8,
        s.clone(),
        Prepare::new(&|_, _| {}, &cancel),
    )
    .err()
    .expect("cancelled");
    assert_eq!(err, ModeError::Cancelled(meso_render::Cancelled));
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let stop_in_biclustering = |stage: &str, _: f32| {
        if stage == "biclustering" {
            cancel.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    };
    let err = BiscaleMode::prepare(scene, 8, 8, s, Prepare::new(&stop_in_biclustering, &cancel))
        .err()
        .expect("cancelled");
    assert_eq!(err, ModeError::Cancelled(meso_render::Cancelled));
}

#[test]
fn the_bias_against_the_spmm_mode_is_the_tessellation_and_vanishes_with_it() {
    // Per-vertex transfer samples visibility at the vertices, where a convex mesh
    // sees its whole hemisphere; the reference shades flat facets under smooth
    // normals, whose own plane hides part of the shading hemisphere. So biscale is
    // brighter on coarse meshes (the low-res bunny's 1.4-2.8%) and the gap closes as
    // the facets shrink (measured 1.6%, 0.4%, 0.2% at 6x12, 12x24, 24x48): with n and
    // M fixed, only the tessellation changes here.
    let (w, h) = (64, 32);
    let map = map_of(w, h, |x, y| {
        let d = meso_render::environment::direction_at(
            (x as f64 + 0.5) / w as f64,
            (y as f64 + 0.5) / h as f64,
        );
        [0.4 + 0.3 * d.y.max(0.0) as f32; 3]
    });
    let gap = |rings: u32, segments: u32| {
        let mut scene = plane_scene(map.clone());
        scene.meshes = vec![uv_sphere(rings, segments)];
        scene.camera = meso_render::scene::Camera {
            position: DVec3::new(0.0, 0.3, 2.0),
            look_at: DVec3::ZERO,
            up: DVec3::Y,
            fov_y_deg: 35.0,
        };
        let (iw, ih) = (32, 32);
        let mut spmm = crate::trace::SpmmMode::new(scene.clone(), iw, ih).expect("spmm");
        run_frames(&mut spmm, 512, |_, _| {});
        let mut mode =
            BiscaleMode::prepare(scene, iw, ih, settings(), Prepare::quietly()).expect("mode");
        run_frames(&mut mode, 64, |_, _| {});
        let sum = |img: &Image| img.pixels().iter().map(|p| p[0] as f64).sum::<f64>();
        sum(&mode.image()) / sum(&spmm.image()) - 1.0
    };
    let (coarse, fine) = (gap(6, 12), gap(24, 48));
    eprintln!("biscale / spmm - 1: 6x12 {coarse:.4}, 24x48 {fine:.4}");
    assert!(coarse > 0.008, "the coarse sphere is brighter: {coarse}");
    assert!(fine.abs() < 0.005, "the fine sphere agrees: {fine}");
    assert!(coarse > 3.0 * fine.abs(), "{coarse} vs {fine}");
}

/// The edit test scene (a Lambertian floor, an SPMM panel, an area and a point light,
/// ambient occlusion) under a black environment: everything the image shows is
/// traced on top of the precomputation.
/// The lights and the ambient term, no environment: the biscale mode's precomputed
/// part is dark, and its image is what it traces exactly.
fn lights_only_scene() -> Scene {
    let scene = edit_test_scene();
    assert!(scene.environment.is_none());
    scene
}

/// Renders `scene` at 24 x 24 for `frames` frames in the biscale and the spmm mode,
/// asserts their image means agree within 1% (the lights lighting the scene), and
/// returns the biscale mode and the relative RMSE between the two images.
fn agrees_with_spmm(scene: Scene, frames: u32) -> (BiscaleMode, f64) {
    let (w, h) = (24, 24);
    let mut biscale =
        BiscaleMode::prepare(scene.clone(), w, h, settings(), Prepare::quietly()).expect("mode");
    let mut spmm = crate::trace::SpmmMode::new(scene, w, h).expect("spmm");
    run_frames(&mut biscale, frames, |_, _| {});
    run_frames(&mut spmm, frames, |_, _| {});
    let (a, b) = (biscale.image(), spmm.image());
    let mean = |img: &Image| {
        img.pixels()
            .iter()
            .map(|p| f64::from(p[0] + p[1] + p[2]))
            .sum::<f64>()
            / img.pixels().len() as f64
    };
    let (ma, mb) = (mean(&a), mean(&b));
    assert!(mb > 0.05, "the lights light the scene: {mb}");
    assert!(
        (ma - mb).abs() <= 0.01 * mb,
        "mean {ma} against spmm's {mb}"
    );
    let rmse = (a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(p, q)| (0..3).map(|c| f64::from(p[c] - q[c]).powi(2)).sum::<f64>())
        .sum::<f64>()
        / (3 * a.pixels().len()) as f64)
        .sqrt();
    eprintln!("biscale against spmm: means {ma} {mb}, rmse {rmse}");
    (biscale, rmse / (mb / 3.0))
}

#[test]
fn lights_and_ambient_occlusion_converge_to_the_spmm_modes_image() {
    // Both modes estimate the same integral for the lights and the ambient term (the
    // shading core's response at the same frame, the same per-light estimator) with
    // different random numbers (the spmm mode's Sobol points, the biscale mode's
    // independent ones). Measured at 256 frames, 24 x 24: mean ratio 1.0010, relative
    // RMSE 0.0145 (the spmm mode against itself with another seed: 0.0089). Bounds:
    // 0.5% and 0.04; without the ambient term the image is 49% dimmer.
    let (mut biscale, relative) = agrees_with_spmm(lights_only_scene(), 256);
    assert!(relative < 0.04, "relative RMSE {relative}");
    // The lights were traced: shadow and ambient rays counted.
    let stats = biscale.render_frame();
    assert!(stats.counters.rays.shadow > 0 && stats.counters.rays.ambient > 0);
}

#[test]
fn forty_lights_converge_to_the_spmm_modes_image() {
    // The biscale mode samples every light; the spmm mode selects 16 of the 40 at
    // random each sample (trace/many_lights.rs): the same integral.
    let scene = meso_render::scene::test_scenes::many_lights_scene(40);
    let (_, relative) = agrees_with_spmm(scene, 256);
    assert!(relative < 0.06, "relative RMSE {relative}");
}

#[test]
fn light_and_ambient_edits_are_the_layers_edits() {
    let mut mode = BiscaleMode::prepare(lights_only_scene(), 8, 8, settings(), Prepare::quietly())
        .expect("mode");
    run_frames(&mut mode, 2, |_, _| {});
    let mut light = mode.scene().lights[1];
    if let Light::Point { intensity, .. } = &mut light {
        *intensity = DVec3::new(0.2, 0.4, 0.9);
    }
    // A colour re-weights the light's layer: every sample stands.
    let kept = mode.apply(SceneEdit::Light { index: 1, light });
    assert_eq!(kept, Ok(meso_render::Invalidation::Nothing));
    assert_eq!(mode.progress().min_samples, 2);
    // Adding a light and changing the ambient term are accepted, not refused.
    let added = mode.apply(SceneEdit::AddLight(Light::Point {
        position: DVec3::new(-1.0, 1.0, 0.5),
        intensity: DVec3::ONE,
    }));
    assert!(added.is_ok(), "{added:?}");
    let ambient = mode.apply(SceneEdit::Ambient(None));
    assert!(ambient.is_ok(), "{ambient:?}");
    run_frames(&mut mode, 1, |_, _| {});
    assert!(
        mode.image()
            .pixels()
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite()))
    );
}

/// The edit test scene's floor and upright panel under a sky with a small bright sun
/// behind the panel, no lights: the panel's shadow falls on the floor between its
/// four corners.
fn sun_behind_the_panel() -> Scene {
    let mut scene = edit_test_scene();
    scene.lights.clear();
    scene.ambient = None;
    // Lat-long: the sun about 35 degrees up, towards -z (behind the panel seen from
    // the camera at +z), so the shadow falls towards the camera.
    scene.environment = Some(Environment {
        map: map_of(64, 32, |x, y| {
            if (9..=10).contains(&y) && (15..=16).contains(&x) {
                [400.0; 3]
            } else {
                [0.2; 3]
            }
        }),
        strength: 1.0,
        rotate_y_deg: 0.0,
        mis: true,
    });
    scene
}

#[test]
fn refinement_puts_a_receivers_shadow_where_the_spmm_mode_sees_it() {
    // Without refinement the floor's transfer lives at its four corners, which all
    // see the sun: no shadow. With it, vertices are added where visibility varies and
    // the floor shows the panel's shadow. Both are compared with the spmm mode at 128
    // frames (whose own noise against a 1024-frame image is measured below). The sun
    // is left in the transfer (nothing traced): traced, its shadow is exact either way
    // (relative RMSE 0.037 unrefined, 0.033 refined), and the refinement is for what
    // the transfer carries.
    let (w, h) = (32, 32);
    let scene = sun_behind_the_panel();
    let mut spmm = crate::trace::SpmmMode::new(scene.clone(), w, h).expect("spmm");
    run_frames(&mut spmm, 128, |_, _| {});
    let reference = spmm.image();
    let error = |refine_vertices: usize| {
        let s = BiscaleSettings {
            cube_n: 16,
            rays_per_side: 1,
            refine_vertices,
            traced_share: 0.0,
            ..settings()
        };
        let mut mode =
            BiscaleMode::prepare(scene.clone(), w, h, s, Prepare::quietly()).expect("mode");
        run_frames(&mut mode, 128, |_, _| {});
        let added = mode.precomputed().stats.refined_vertices;
        (relative_rmse(&mode.image(), &reference), added)
    };
    let (flat, none_added) = error(0);
    let (refined, added) = error(4096);
    eprintln!(
        "relative RMSE against spmm: {flat} unrefined, {refined} with {added} vertices added"
    );
    assert_eq!(none_added, 0);
    assert!(added > 0 && added <= 4096 + 64, "{added} vertices added");
    assert!(
        refined < 0.5 * flat,
        "refined {refined} against unrefined {flat}"
    );
}

fn relative_rmse(a: &Image, b: &Image) -> f64 {
    let n = (3 * a.pixels().len()) as f64;
    let mean = b
        .pixels()
        .iter()
        .map(|p| f64::from(p[0] + p[1] + p[2]))
        .sum::<f64>()
        / n;
    let se = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(p, q)| (0..3).map(|c| f64::from(p[c] - q[c]).powi(2)).sum::<f64>())
        .sum::<f64>();
    (se / n).sqrt() / mean
}

#[test]
fn a_merl_table_of_a_lambertian_renders_like_the_lambertian() {
    // The table's cells hold albedo / pi (the reader's nearest cell, exact for a
    // constant), so both tabulations agree but for f32 rounding of the table.
    let albedo = DVec3::new(0.7, 0.5, 0.3);
    let lambert = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    let merl = Material::Merl {
        brdf: Arc::new(meso_materials::merl::tabulate(&lambert, albedo).expect("table")),
        tint: DVec3::ONE,
    };
    let (analytic, measured) = lambertian_plane_and(albedo, merl);
    BiscaleMode::supports(&measured).expect("MERL tables are tabulated");
    let a = centre_pixel(
        &mut BiscaleMode::prepare(analytic, 3, 3, settings(), Prepare::quietly()).expect("mode"),
        1,
    );
    let m = centre_pixel(
        &mut BiscaleMode::prepare(measured, 3, 3, settings(), Prepare::quietly()).expect("mode"),
        1,
    );
    assert!(a.min_element() > 0.05, "{a}");
    assert!(((m - a) / a).abs().max_element() < 1e-3, "{m} against {a}");
}

#[test]
fn a_mirror_shows_what_it_reflects_as_the_spmm_mode_does() {
    // The lights-only scene with an upright mirror beside the panel: the biscale mode
    // follows the reflected ray as the spmm mode does, so the two agree as without it.
    let (w, h) = (24, 24);
    let mut scene = lights_only_scene();
    scene.materials.push(Material::Mirror {
        reflectance: DVec3::new(0.9, 0.85, 0.8),
    });
    scene.material_names.push("chrome".into());
    scene.meshes.push(meso_render::scene::mesh::quad(
        DVec3::new(-1.4, 0.0, 0.8),
        DVec3::new(0.6, 0.0, -0.9),
        DVec3::new(0.0, 0.9, 0.0),
        2,
    ));
    let mut biscale =
        BiscaleMode::prepare(scene.clone(), w, h, settings(), Prepare::quietly()).expect("mode");
    let mut spmm = crate::trace::SpmmMode::new(scene, w, h).expect("spmm");
    let stats = run_frames(&mut biscale, 256, |_, _| {});
    run_frames(&mut spmm, 256, |_, _| {});
    assert!(stats.counters.rays.specular > 0, "the mirror is seen");
    let (a, b) = (biscale.image(), spmm.image());
    let mean = |img: &Image| {
        img.pixels()
            .iter()
            .map(|p| f64::from(p[0] + p[1] + p[2]))
            .sum::<f64>()
    };
    let (ma, mb) = (mean(&a), mean(&b));
    let relative = relative_rmse(&a, &b);
    eprintln!(
        "with a mirror: mean ratio {}, relative RMSE {relative}",
        ma / mb
    );
    assert!(
        (ma - mb).abs() <= 0.005 * mb,
        "mean {ma} against spmm's {mb}"
    );
    assert!(relative < 0.04, "relative RMSE {relative}");
}

/// Frames that stop between tiles, and a preview of one pixel per block after a
/// restart (a camera edit, a moved light), leave exactly the film of whole frames:
/// the preview and the stopped rows are the frame's own samples, which the call that
/// completes the frame skips.
#[test]
fn a_preview_and_stopped_frames_leave_the_image_of_whole_frames() {
    const W: u32 = 160;
    const STRIDE: u32 = 4;
    let scene = lights_only_scene();
    let mut modes = [(); 2].map(|_| {
        BiscaleMode::prepare(scene.clone(), W, W, settings(), Prepare::quietly()).expect("mode")
    });
    let mut camera = scene.camera;
    camera.position += DVec3::new(0.2, 0.1, 0.0);
    let mut moved = scene.lights[0];
    if let Light::Area { corner, .. } = &mut moved {
        corner.x += 0.3;
    }
    let grid = meso_render::preview::grid_pixels(W, W, STRIDE);
    let edits = [
        SceneEdit::Camera(camera),
        SceneEdit::Light {
            index: 0,
            light: moved,
        },
    ];
    for edit in edits {
        for m in &mut modes {
            m.render_frame();
            m.apply(edit.clone()).expect("an edit");
            assert_eq!(m.progress().min_samples, 0, "{edit:?} restarts every pixel");
        }
        let [whole, yielding] = &mut modes;
        let frames = yielding.progress().frames;
        let preview = yielding.render_preview(STRIDE).expect("a preview");
        assert_eq!(preview.counters.samples, grid.len() as u64);
        assert!(yielding.render_preview(STRIDE).is_none(), "previewed twice");
        // Stopped after its first tile, then after every other.
        let mut stops = 0;
        let first = yielding.render_frame_yielding(&mut || {
            stops += 1;
            true
        });
        assert!(first.counters.samples < u64::from(W * W) - grid.len() as u64);
        assert_eq!(
            yielding.progress().frames,
            frames,
            "the frame is unfinished"
        );
        // Each call that is stopped at once still renders one more tile.
        let tiles = (0..W).take_while(|_| {
            yielding.render_frame_yielding(&mut || true);
            yielding.progress().frames == frames
        });
        assert!(tiles.count() < W as usize, "the frame never completes");
        whole.render_frame();
        assert_eq!(stops, 1);
        assert!(whole.image().pixels() == yielding.image().pixels());
        assert!(yielding.progress().shows_every_pixel);
    }
}
