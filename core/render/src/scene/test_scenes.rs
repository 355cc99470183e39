//! Small scenes built in code for tests of modes, edits, picking and reports.

use std::sync::Arc;

use glam::{DVec2, DVec3};

use super::mesh::quad;
use super::{Ambient, Background, Camera, Light, Material, RenderSettings, Scene};
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};

const SIZE: u32 = 24;

/// A Lambertian floor (material 0) and an SPMM panel with a residual of 6 components,
/// more than a moving camera keeps (material 1), under an area light and a point
/// light, with AO.
pub fn edit_test_scene() -> Scene {
    let panel = meso_materials::spmm::testing::sample_material(4, 4, 2, Some(6));
    Scene {
        render: RenderSettings {
            width: SIZE,
            height: SIZE,
            frames: 1,
            seed: 9,
            max_specular_depth: 2,
            mode: crate::ModeKind::Spmm,
            device: crate::Device::Cpu,
            sampler: meso_materials::rng::Sampler::Sobol,
            light_samples: 1,
        },
        camera: Camera {
            position: DVec3::new(0.0, 1.2, 2.0),
            look_at: DVec3::new(0.0, 0.2, 0.0),
            up: DVec3::Y,
            fov_y_deg: 50.0,
        },
        material_names: vec!["floor".into(), "panel".into()],
        material_files: Vec::new(),
        materials: vec![
            Material::Brdf {
                brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
                albedo: DVec3::splat(0.6),
            },
            Material::Spmm {
                material: Arc::new(panel),
                uv_scale: DVec2::splat(2.0),
                residual: true,
                npca: 6,
            },
        ],
        meshes: vec![
            quad(
                DVec3::new(-2.0, 0.0, 2.0),
                DVec3::new(4.0, 0.0, 0.0),
                DVec3::new(0.0, 0.0, -4.0),
                0,
            ),
            quad(
                DVec3::new(-0.4, 0.0, 0.0),
                DVec3::new(0.8, 0.0, 0.0),
                DVec3::new(0.0, 0.8, 0.0),
                1,
            ),
        ],
        lights: vec![
            Light::Area {
                corner: DVec3::new(-0.3, 1.5, 0.2),
                edge_u: DVec3::new(0.6, 0.0, 0.0),
                edge_v: DVec3::new(0.0, 0.0, 0.6),
                radiance: DVec3::splat(6.0),
            },
            Light::Point {
                position: DVec3::new(1.0, 1.0, 1.0),
                intensity: DVec3::new(1.0, 0.5, 0.2),
            },
        ],
        ambient: Some(Ambient {
            radiance: DVec3::splat(0.3),
            radius: 0.5,
        }),
        environment: None,
        background: Background::Color(DVec3::new(0.1, 0.1, 0.2)),
    }
}

/// A large floor (material 0, normal +y) seen straight down through a 0.01-degree
/// field at 3x3 pixels, so every pixel looks at (almost exactly) one point; with
/// `wall`, an infinite wall through x = 0 facing +x beside that point. No lights,
/// no ambient term, no environment, a black background.
pub fn floor_scene(material: Material, wall: bool) -> Scene {
    let mut meshes = vec![quad(
        DVec3::new(-50.0, 0.0, 50.0),
        DVec3::new(100.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, -100.0),
        0,
    )];
    if wall {
        meshes.push(quad(
            DVec3::new(0.0, 0.0, 50.0),
            DVec3::new(0.0, 0.0, -100.0),
            DVec3::new(0.0, 100.0, 0.0),
            0,
        ));
    }
    let look = if wall {
        DVec3::new(1e-3, 0.0, 0.0)
    } else {
        DVec3::ZERO
    };
    Scene {
        render: RenderSettings {
            width: 3,
            height: 3,
            frames: 1,
            seed: 1,
            max_specular_depth: 2,
            mode: crate::ModeKind::Spmm,
            device: crate::Device::Cpu,
            sampler: meso_materials::rng::Sampler::Sobol,
            light_samples: 1,
        },
        camera: Camera {
            position: look + DVec3::new(0.0, 1.0, 0.0),
            look_at: look,
            up: DVec3::NEG_Z,
            fov_y_deg: 0.01,
        },
        material_names: vec!["floor".into()],
        material_files: Vec::new(),
        materials: vec![material],
        meshes,
        lights: Vec::new(),
        ambient: None,
        environment: None,
        background: Background::Color(DVec3::ZERO),
    }
}

/// `edit_test_scene`'s floor and SPMM panel under `n` lights: every tenth a small
/// one-sided area light (alternately facing down and up, so orientation matters), the
/// rest point lights of random colour, some black; no ambient term.
pub fn many_lights_scene(n: usize) -> Scene {
    let mut scene = edit_test_scene();
    scene.ambient = None;
    let rng = meso_materials::rng::SampleStream::new(&[77]);
    let u = |k: usize, d: u64| rng.at(k as u64 * 8 + d);
    scene.lights = (0..n)
        .map(|k| {
            let p = DVec3::new(
                -2.0 + 4.0 * u(k, 0),
                0.3 + 2.0 * u(k, 1),
                -2.0 + 4.0 * u(k, 2),
            );
            let colour = DVec3::new(u(k, 3), u(k, 4), u(k, 5));
            if k % 10 == 9 {
                let (a, b) = (DVec3::new(0.15, 0.0, 0.0), DVec3::new(0.0, 0.0, 0.15));
                let (edge_u, edge_v) = if k % 20 == 9 { (a, b) } else { (b, a) };
                Light::Area {
                    corner: p,
                    edge_u,
                    edge_v,
                    radiance: colour * (20.0 / n as f64),
                }
            } else {
                let black = k % 37 == 5;
                Light::Point {
                    position: p,
                    intensity: if black {
                        DVec3::ZERO
                    } else {
                        colour * (4.0 / n as f64)
                    },
                }
            }
        })
        .collect();
    scene
}

/// One texel with one Ward basis tilted 35 degrees: a BTF that does not vanish with
/// the shading cosine, the case the defensive mixture exists for.
pub fn tilted_spmm() -> Material {
    let normal = DVec3::new(35f64.to_radians().sin(), 0.0, 35f64.to_radians().cos());
    let basis = meso_materials::brdf::BasisFunction::new(
        AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.3), ("ay", 0.15)]).expect("valid"),
        normal,
    )
    .expect("unit normal");
    let pack = meso_materials::spmm::SpmmMaterial::new(
        "tilted".into(),
        "test".into(),
        1,
        1,
        vec![meso_materials::spmm::Cluster { bases: vec![basis] }],
        vec![0],
        meso_materials::spmm::SparseWeights {
            offsets: vec![0, 1],
            basis: vec![0],
            rgb: vec![[0.5, 0.5, 0.5]],
        },
        None,
    )
    .expect("valid material");
    Material::Spmm {
        material: Arc::new(pack),
        uv_scale: DVec2::ONE,
        residual: true,
        npca: 0,
    }
}

/// A `btf` material tabulating `albedo * brdf` on the Bonn 81 x 81 directions, 1 x 1
/// texel, tiled by `uv_scale`.
pub fn tabulated_btf(brdf: &AnalyticBrdf, albedo: DVec3, uv_scale: DVec2) -> Material {
    tabulated_btf_on(
        brdf,
        albedo,
        uv_scale,
        meso_materials::btf::directions::bonn81(),
    )
}

/// `tabulated_btf` on the direction layout `dirs` (light and view alike), e.g.
/// UBO2014's 151 directions.
pub fn tabulated_btf_on(
    brdf: &AnalyticBrdf,
    albedo: DVec3,
    uv_scale: DVec2,
    dirs: Vec<DVec3>,
) -> Material {
    let btf = meso_materials::btf::Btf::from_brdf(brdf, albedo, 1, 1, dirs.clone(), dirs)
        .expect("valid BTF");
    Material::Btf {
        table: Arc::new(meso_materials::btf::table::BtfTable::new(&btf).expect("shadeable")),
        uv_scale,
    }
}
