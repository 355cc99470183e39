//! Hard cases for the spmm mode: degenerate triangles, normals facing away, huge UVs,
//! grazing lights, mirror pairs and a camera inside a closed box: only finite samples,
//! no panic.

use glam::{DVec2, DVec3};

use super::SpmmMode;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_render::RenderModeExt;
use meso_render::scene::mesh::quad;
use meso_render::scene::{Ambient, Camera, RenderSettings, TriangleMesh};
use meso_render::scene::{Background, Light, Material, Scene};
use meso_render::{RenderMode, SceneEdit};

/// Degenerate triangles, normals facing away from the geometry, UVs far outside
/// [0, 1], a grazing light, a mirror pair, and a camera inside a closed box: the
/// film must receive only finite samples and nothing may panic.
#[test]
fn no_nan_and_no_panic_on_hard_geometry() {
    let pack = meso_materials::spmm::pack::read_pack(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../materials/woven_wool.spmm"
    )))
    .expect("shipped pack");
    let mut odd = quad(
        DVec3::new(-1.0, 0.0, 1.0),
        DVec3::new(2.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, -2.0),
        1,
    );
    odd.normals = vec![DVec3::NEG_Y; 4]; // facing away from the geometric normal
    odd.uvs = odd
        .uvs
        .iter()
        .map(|uv| *uv * 1e6 - DVec2::splat(3e5))
        .collect();
    odd.positions.push(DVec3::new(0.3, 0.2, 0.1));
    odd.indices.push([4, 4, 4]); // zero-area triangle
    odd.indices.push([0, 1, 4]);
    odd.normals.push(DVec3::ZERO); // a zero normal at that vertex
    odd.uvs.push(DVec2::new(f64::MAX / 4.0, 0.5));
    // A closed box around the camera: every primary ray hits the inside of a wall.
    let s = 3.0;
    let walls: Vec<TriangleMesh> = [
        (
            DVec3::new(-s, -s, -s),
            DVec3::new(2.0 * s, 0.0, 0.0),
            DVec3::new(0.0, 2.0 * s, 0.0),
        ),
        (
            DVec3::new(-s, -s, s),
            DVec3::new(0.0, 2.0 * s, 0.0),
            DVec3::new(2.0 * s, 0.0, 0.0),
        ),
        (
            DVec3::new(-s, -s, -s),
            DVec3::new(0.0, 2.0 * s, 0.0),
            DVec3::new(0.0, 0.0, 2.0 * s),
        ),
        (
            DVec3::new(s, -s, -s),
            DVec3::new(0.0, 0.0, 2.0 * s),
            DVec3::new(0.0, 2.0 * s, 0.0),
        ),
        (
            DVec3::new(-s, s, -s),
            DVec3::new(2.0 * s, 0.0, 0.0),
            DVec3::new(0.0, 0.0, 2.0 * s),
        ),
    ]
    .into_iter()
    .map(|(c, u, v)| quad(c, u, v, 2))
    .collect();
    let mut meshes = vec![odd];
    meshes.extend(walls);
    meshes.push(quad(
        DVec3::new(-0.5, 0.5, -0.5),
        DVec3::new(0.0, 0.0, 1.0),
        DVec3::new(0.0, 1.0, 0.0),
        0,
    ));
    let scene = Scene {
        render: RenderSettings {
            width: 24,
            height: 24,
            frames: 1,
            seed: 5,
            max_specular_depth: 3,
            mode: meso_render::ModeKind::Spmm,
            device: meso_render::Device::Cpu,
            sampler: meso_materials::rng::Sampler::Sobol,
            light_samples: 1,
        },
        camera: Camera {
            position: DVec3::new(0.0, 0.5, 2.0),
            look_at: DVec3::ZERO,
            up: DVec3::Y,
            fov_y_deg: 150.0,
        },
        material_names: vec!["mirror".into(), "cloth".into(), "wall".into()],
        material_files: Vec::new(),
        materials: vec![
            Material::Mirror {
                reflectance: DVec3::splat(0.9),
            },
            Material::Spmm {
                material: std::sync::Arc::new(pack),
                uv_scale: DVec2::splat(3.0),
                residual: true,
                npca: 0,
            },
            Material::Brdf {
                brdf: AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 1e-4), ("ay", 1e-4)])
                    .expect("valid"),
                albedo: DVec3::ONE,
            },
        ],
        meshes,
        lights: vec![
            // Grazing: just above the floor's plane.
            Light::Point {
                position: DVec3::new(2.5, 1e-7, 0.0),
                intensity: DVec3::splat(10.0),
            },
            Light::Area {
                corner: DVec3::new(-0.5, 2.9, -0.5),
                edge_u: DVec3::X,
                edge_v: DVec3::Z,
                radiance: DVec3::splat(3.0),
            },
        ],
        ambient: Some(Ambient {
            radiance: DVec3::splat(0.2),
            radius: 0.3,
        }),
        environment: None,
        background: Background::Color(DVec3::ZERO),
    };
    let mut r = SpmmMode::new(scene, 24, 24).expect("size");
    for f in 0..8u64 {
        let stats = r.render_frame();
        assert_eq!(stats.dropped, 0, "frame {f}");
        for y in 0..24 {
            for x in 0..24 {
                let (layers, _, _) = r.sample(x, y, f);
                assert!(
                    layers
                        .iter()
                        .all(|l| l.is_finite() && l.min_element() >= 0.0),
                    "pixel {x},{y} frame {f}: {layers:?}"
                );
            }
        }
    }
    // A light shrunk to nothing and a camera inside the floor's plane.
    r.apply(SceneEdit::AddLight(Light::Area {
        corner: DVec3::new(0.0, 1.0, 0.0),
        edge_u: DVec3::new(1e-300, 0.0, 0.0),
        edge_v: DVec3::new(0.0, 0.0, 1e-300),
        radiance: DVec3::ONE,
    }))
    .expect_err("a zero-area light is refused");
    let mut cam = r.scene().camera;
    cam.position = DVec3::new(0.0, 0.0, 0.3);
    r.apply(SceneEdit::Camera(cam)).expect("valid camera");
    for _ in 0..2 {
        assert_eq!(r.render_frame().dropped, 0);
    }
    let img = r.image();
    assert!(img.pixels().iter().flatten().all(|c| c.is_finite()));
    assert!(
        img.pixels().iter().any(|p| p[0] > 0.0),
        "some light arrives"
    );
}
