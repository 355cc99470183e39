//! Scene files: the spec's example parses into the documented values, and every kind
//! of bad input is an error naming the file, the line and the key.

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};

use super::*;
use meso_materials::brdf::BrdfModel;

/// A unit right tetrahedron without normals or UVs.
const TETRA: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";

fn setup() -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::create_dir_all(dir.path().join("meshes")).expect("mkdir");
    std::fs::write(dir.path().join("meshes/tetra.obj"), TETRA).expect("write obj");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../materials/leather.spmm"),
        dir.path().join("leather.spmm"),
    )
    .expect("copy pack");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../materials/env/env_sky.exr"),
        dir.path().join("sky.exr"),
    )
    .expect("copy map");
    dir
}

/// The example with the tables the render modes added: `[render] mode/device`, an
/// `[environment]`, an inline-tabulated `merl` material, and no `[background]`.
fn with_mode_tables(example: &str) -> String {
    example
        .replace(
            "max_specular_depth = 2\n",
            "max_specular_depth = 2\nmode = \"biscale\"\ndevice = \"gpu\"\n",
        )
        .replace("[background]\ncolor = [0.1, 0.2, 0.3]\n", "")
        + r#"
[materials.paint]
kind = "merl"
tabulate = { model = "cook_torrance", params = { m = 0.3, f0 = 0.05 }, albedo = [0.8, 0.2, 0.1] }
tint = [1.0, 0.5, 1.0]

[environment]
path = "sky.exr"
strength = 2.5
rotate_y_deg = -40.0
"#
}

const EXAMPLE: &str = r#"version = 1

[render]
width = 64
height = 48
frames = 8
seed = 3
max_specular_depth = 2

[camera]
position = [0.0, 0.6, 2.5]
look_at = [0.0, 0.4, 0.0]
up = [0.0, 1.0, 0.0]
fov_y_deg = 35.0

[materials.floor]
kind = "brdf"
model = "ward"
params = { ax = 0.1, ay = 0.3 }
albedo = [0.7, 0.6, 0.5]

[materials.cloth]
kind = "spmm"
pack = "leather.spmm"
uv_scale = [4.0, 2.0]
residual = false

[materials.chrome]
kind = "mirror"
reflectance = [0.9, 0.9, 0.9]

[[mesh]]
path = "meshes/tetra.obj"
material = "cloth"
scale = 2.0
rotate_axis = [0.0, 1.0, 0.0]
rotate_deg = 90.0
translate = [1.0, 0.0, 0.0]

[[quad]]
corner = [-2.0, 0.0, 2.0]
edge_u = [4.0, 0.0, 0.0]
edge_v = [0.0, 0.0, -4.0]
material = "floor"

[[light]]
kind = "point"
position = [1.0, 2.0, 1.0]
intensity = [5.0, 5.0, 5.0]

[[light]]
kind = "area"
corner = [-0.5, 2.0, -0.5]
edge_u = [1.0, 0.0, 0.0]
edge_v = [0.0, 0.0, 1.0]
radiance = [8.0, 8.0, 8.0]

[ambient]
radiance = [0.3, 0.3, 0.3]
radius = inf

[background]
color = [0.1, 0.2, 0.3]
"#;

fn write(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("scene.toml");
    std::fs::write(&p, text).expect("write scene");
    p
}

#[test]
fn the_spec_example_loads_with_its_values() {
    let dir = setup();
    let s = load_scene(&write(dir.path(), EXAMPLE)).expect("valid scene");
    assert_eq!(
        s.render,
        RenderSettings {
            width: 64,
            height: 48,
            frames: 8,
            seed: 3,
            max_specular_depth: 2,
            mode: crate::ModeKind::Spmm,
            device: crate::Device::Cpu,
            sampler: meso_materials::rng::Sampler::Sobol,
            light_samples: 1,
        }
    );
    assert_eq!(s.camera.fov_y_deg, 35.0);
    assert_eq!(s.material_names, vec!["chrome", "cloth", "floor"]);
    match &s.materials[2] {
        Material::Brdf { brdf, albedo } => {
            assert_eq!(brdf.param_values(), vec![0.1, 0.3]);
            assert_eq!(*albedo, DVec3::new(0.7, 0.6, 0.5));
        }
        other => panic!("floor is a brdf material, got {other:?}"),
    }
    match &s.materials[1] {
        Material::Spmm {
            uv_scale,
            residual,
            npca,
            material,
        } => {
            assert_eq!(
                (*uv_scale, *residual, *npca),
                (DVec2::new(4.0, 2.0), false, 0)
            );
            assert_eq!(material.width(), 64);
        }
        other => panic!("cloth is an spmm material, got {other:?}"),
    }
    // Mesh: scale 2, then 90 degrees about +y (x -> -z), then +1 in x: vertex (1,0,0)
    // goes to (2,0,0), then (0,0,-2), then (1,0,-2).
    let tetra = &s.meshes[0];
    assert_eq!(tetra.material, 1);
    assert_eq!(tetra.positions.len(), 4);
    let moved = DVec3::new(1.0, 0.0, -2.0);
    assert!(
        tetra
            .positions
            .iter()
            .any(|p| (*p - moved).length() < 1e-12),
        "{:?}",
        tetra.positions
    );
    // Computed normals are unit; spherical UVs lie in [0, 1].
    assert!(
        tetra
            .normals
            .iter()
            .all(|n| (n.length() - 1.0).abs() < 1e-12)
    );
    assert!(
        tetra
            .uvs
            .iter()
            .all(|uv| (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y))
    );
    // Quad: geometric normal normalize(edge_u x edge_v) = +y; uv (s, t) over the edges.
    let floor = &s.meshes[1];
    assert_eq!(floor.normals[0], DVec3::Y);
    assert_eq!(floor.positions[2], DVec3::new(2.0, 0.0, -2.0));
    assert_eq!(floor.uvs[2], DVec2::new(1.0, 1.0));
    assert_eq!(s.lights.len(), 2);
    assert!(matches!(s.lights[1], Light::Area { radiance, .. } if radiance == DVec3::splat(8.0)));
    assert_eq!(
        s.ambient,
        Some(Ambient {
            radiance: DVec3::splat(0.3),
            radius: f64::INFINITY
        })
    );
    assert!(matches!(s.background, Background::Color(c) if c == DVec3::new(0.1, 0.2, 0.3)));
}

#[test]
fn mode_device_environment_and_merl_tables_load_with_their_values() {
    let dir = setup();
    let s = load_scene(&write(dir.path(), &with_mode_tables(EXAMPLE))).expect("valid scene");
    assert_eq!(
        (s.render.mode, s.render.device),
        (ModeKind::Biscale, Device::Gpu)
    );
    let env = s.environment.as_ref().expect("an environment");
    assert_eq!(
        (env.strength, env.rotate_y_deg, env.mis),
        (2.5, -40.0, true)
    );
    assert_eq!((env.map.width(), env.map.height()), (512, 256));
    assert!(matches!(s.background, Background::FromEnvironment));
    let paint = s
        .material_names
        .iter()
        .position(|n| n == "paint")
        .expect("paint");
    match &s.materials[paint] {
        Material::Merl { brdf, tint } => {
            assert_eq!(*tint, DVec3::new(1.0, 0.5, 1.0));
            // The table holds albedo x Cook-Torrance at its cells: red > green > blue.
            let v = brdf.eval(DVec3::new(0.3, 0.0, 0.95).normalize(), DVec3::Z);
            assert!(v.x > v.y && v.y > v.z && v.z > 0.0, "{v}");
        }
        other => panic!("paint is a merl material, got {other:?}"),
    }
    // Defaults: spmm on the CPU, no environment, black background from it.
    let plain = load_scene(&write(dir.path(), EXAMPLE)).expect("valid");
    assert_eq!(
        (plain.render.mode, plain.render.device),
        (ModeKind::Spmm, Device::Cpu)
    );
    assert!(plain.environment.is_none());
}

#[test]
fn obj_faults_name_the_file_line_and_its_own_vertex_numbers() {
    // Issue 22: a NaN in the third vertex was "vertex 4" and an overflow in the first
    // "vertex 0"; the file counts vertices from 1, and its line is named.
    let dir = setup();
    let at = |text: &str| {
        let p = dir.path().join("meshes/odd.obj");
        std::fs::write(&p, text).expect("write obj");
        let placement = mesh::Placement {
            scale: 1.0,
            rotation: glam::DMat3::IDENTITY,
            translate: DVec3::ZERO,
        };
        mesh::load_obj(&p, &placement, 0)
            .expect_err("refused")
            .to_string()
    };
    let e = at("# a comment\nv 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n");
    assert!(e.contains("line 4: vertex 3 is not finite"), "{e}");
    let e = at("v 1e39 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    assert!(e.contains("line 1: vertex 1 is not finite"), "{e}");
    let e = at("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//-9223372036854775808\n");
    assert!(
        e.contains("line 5: normal index -9223372036854775808 is out of range"),
        "{e}"
    );
    let e = at("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n");
    assert!(e.contains("line 4: vertex index 4 is out of range"), "{e}");
    let e = at("v 0 0 0\nv 1 0 0\nv 0 1 3e38\nf 1 2 3\n");
    assert!(
        e.contains("line 3: vertex 3") && e.contains("outside the scene extent"),
        "{e}"
    );
    // Relative indices within what came before are fine.
    let p = dir.path().join("meshes/relative.obj");
    std::fs::write(&p, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n").expect("write");
    let placement = mesh::Placement {
        scale: 1.0,
        rotation: glam::DMat3::IDENTITY,
        translate: DVec3::ZERO,
    };
    assert_eq!(
        mesh::load_obj(&p, &placement, 0)
            .expect("loads")
            .indices
            .len(),
        1
    );
}

#[test]
fn computed_normals_are_area_weighted() {
    // Two triangles sharing vertex 0: one of area 2 facing +z, one of area 0.5 facing +x.
    let positions = [
        DVec3::ZERO,
        DVec3::new(2.0, 0.0, 0.0),
        DVec3::new(0.0, 2.0, 0.0),
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
    ];
    let n = mesh::vertex_normals(&positions, &[[0, 1, 2], [0, 3, 4]]);
    let expected = DVec3::new(0.5, 0.0, 2.0).normalize();
    assert!((n[0] - expected).length() < 1e-12, "{}", n[0]);
}

/// (edit to the example, expected line, texts the message must contain)
fn bad_cases() -> Vec<(String, Option<usize>, Vec<&'static str>)> {
    let line_of = |needle: &str| {
        EXAMPLE
            .lines()
            .position(|l| l.contains(needle))
            .map(|i| i + 1)
    };
    vec![
        (
            EXAMPLE.replace("seed = 3", "sed = 3"),
            line_of("seed = 3"),
            vec!["sed"],
        ),
        (
            EXAMPLE.replace("version = 1", "version = 2"),
            Some(1),
            vec!["version"],
        ),
        (
            EXAMPLE.replace("fov_y_deg = 35.0\n", ""),
            None,
            vec!["fov_y_deg"],
        ),
        (
            EXAMPLE.replace("width = 64", "width = \"wide\""),
            line_of("width = 64"),
            vec!["width"],
        ),
        (
            EXAMPLE.replace("material = \"floor\"", "material = \"flor\""),
            line_of("material = \"floor\""),
            vec!["quad[0].material", "flor", "floor"],
        ),
        (
            EXAMPLE.replace("ax = 0.1", "ax = 7.0"),
            line_of("ax = 0.1"),
            vec!["materials.floor.params", "ax", "7"],
        ),
        (
            EXAMPLE.replace("edge_v = [0.0, 0.0, -4.0]", "edge_v = [8.0, 0.0, 0.0]"),
            line_of("edge_v = [0.0, 0.0, -4.0]"),
            vec!["quad[0].edge_v", "zero area"],
        ),
        (
            EXAMPLE.replace("edge_v = [0.0, 0.0, 1.0]", "edge_v = [0.0, 0.0, 0.0]"),
            None,
            vec!["light[1].edge_v", "zero area"],
        ),
        (
            EXAMPLE.replace("position = [1.0, 2.0, 1.0]", "position = [nan, 2.0, 1.0]"),
            line_of("position = [1.0, 2.0, 1.0]"),
            vec!["light[0].position", "not finite"],
        ),
        (
            EXAMPLE.replace(
                "intensity = [5.0, 5.0, 5.0]",
                "intensity = [5.0, -5.0, 5.0]",
            ),
            line_of("intensity = [5.0"),
            vec!["light[0].intensity", "negative"],
        ),
        (
            EXAMPLE.replace("meshes/tetra.obj", "meshes/missing.obj"),
            line_of("meshes/tetra.obj"),
            vec!["mesh[0].path", "missing.obj"],
        ),
        (
            EXAMPLE.replace("pack = \"leather.spmm\"", "pack = \"nope.spmm\""),
            line_of("leather.spmm"),
            vec!["materials.cloth.pack", "nope.spmm"],
        ),
        (
            EXAMPLE.replace(
                "residual = false",
                "residual = false\nalbedo = [1.0, 1.0, 1.0]",
            ),
            None,
            vec!["materials.cloth.albedo", "does not belong"],
        ),
        (
            EXAMPLE.replace("kind = \"mirror\"", "kind = \"glass\""),
            line_of("kind = \"mirror\""),
            vec!["materials.chrome.kind", "glass"],
        ),
        (
            EXAMPLE.replace("radius = inf", "radius = -1.0"),
            line_of("radius = inf"),
            vec!["ambient.radius"],
        ),
        (
            EXAMPLE.replace("scale = 2.0", "scale = 0.0"),
            line_of("scale = 2.0"),
            vec!["mesh[0].scale"],
        ),
        (
            EXAMPLE.replace("look_at = [0.0, 0.4, 0.0]", "look_at = [0.0, 0.6, 2.5]"),
            line_of("look_at"),
            vec!["camera.look_at"],
        ),
        // Issue 22: finite in f64, but the placed vertices overflow f32 (obvhs panicked).
        (
            EXAMPLE.replace(
                "translate = [1.0, 0.0, 0.0]",
                "translate = [1e308, 0.0, 0.0]",
            ),
            line_of("meshes/tetra.obj"),
            vec![
                "mesh[0] (scale, rotate, translate)",
                "tetra.obj",
                "line 1",
                "vertex 1",
                "outside the scene extent",
            ],
        ),
        (
            EXAMPLE.replace(
                "translate = [1.0, 0.0, 0.0]",
                "translate = [0.0, -1e308, 0.0]",
            ),
            line_of("meshes/tetra.obj"),
            vec!["mesh[0]", "outside the scene extent"],
        ),
        (
            EXAMPLE.replace("scale = 2.0", "scale = 1e300"),
            line_of("meshes/tetra.obj"),
            vec![
                "mesh[0]",
                "vertex 2",
                "-1.000e300]",
                "outside the scene extent",
            ],
        ),
        (
            EXAMPLE.replace("corner = [-2.0, 0.0, 2.0]", "corner = [-2.0, 0.0, 2e7]"),
            line_of("corner = [-2.0, 0.0, 2.0]"),
            vec!["quad[0].corner", "outside the scene extent"],
        ),
        (
            EXAMPLE.replace("position = [1.0, 2.0, 1.0]", "position = [1.0, 2.0, 1e8]"),
            line_of("position = [1.0, 2.0, 1.0]"),
            vec!["light[0].position", "outside the scene extent"],
        ),
        (
            EXAMPLE.replace("position = [0.0, 0.6, 2.5]", "position = [0.0, 0.6, -3e7]"),
            line_of("position = [0.0, 0.6, 2.5]"),
            vec!["camera.position", "outside the scene extent"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("mode = \"biscale\"", "mode = \"fast\""),
            line_of("max_specular_depth").map(|l| l + 1),
            vec!["render.mode", "fast", "spmm, biscale, adaptive"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("device = \"gpu\"", "device = \"tpu\""),
            line_of("max_specular_depth").map(|l| l + 2),
            vec!["render.device", "tpu"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("strength = 2.5", "strength = -1.0"),
            None,
            vec!["environment.strength", "non-negative"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("rotate_y_deg = -40.0", "rotate_y_deg = nan"),
            None,
            vec!["environment.rotate_y_deg", "not finite"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("path = \"sky.exr\"", "path = \"nosky.exr\""),
            None,
            vec!["environment.path", "nosky.exr"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("strength = 2.5", "strenght = 2.5"),
            None,
            vec!["strenght"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("tint = [1.0, 0.5, 1.0]", "path = \"x.binary\""),
            None,
            vec!["materials.paint.path", "exactly one"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("model = \"cook_torrance\"", "model = \"velvet\""),
            None,
            vec!["materials.paint.tabulate.model", "velvet"],
        ),
        (
            with_mode_tables(EXAMPLE).replace("tabulate = {", "bogus = 1\ntabulate = {"),
            None,
            vec!["bogus"],
        ),
    ]
}

#[test]
fn bad_input_names_file_line_and_key() {
    let dir = setup();
    for (i, (text, line, needles)) in bad_cases().into_iter().enumerate() {
        let err = load_scene(&write(dir.path(), &text))
            .expect_err("bad scene")
            .to_string();
        assert!(err.contains("scene.toml"), "case {i}: {err}");
        if let Some(line) = line {
            assert!(
                err.contains(&format!("line {line}")),
                "case {i}: expected line {line}: {err}"
            );
        }
        for n in needles {
            assert!(err.contains(n), "case {i}: `{n}` missing from: {err}");
        }
        assert!(!err.contains('\n'), "case {i}: one line: {err}");
    }
}

#[test]
fn the_sampler_is_read_and_a_wrong_one_is_named() {
    let dir = setup();
    let scene = |sampler: &str| {
        EXAMPLE.replacen(
            "[render]\n",
            &format!("[render]\nsampler = \"{sampler}\"\n"),
            1,
        )
    };
    let s = load_scene(&write(dir.path(), &scene("independent"))).expect("valid scene");
    assert_eq!(s.render.sampler, meso_materials::rng::Sampler::Independent);
    let e = load_scene(&write(dir.path(), &scene("halton")))
        .expect_err("unknown sampler")
        .to_string();
    assert!(
        e.contains("render.sampler") && e.contains("`halton`") && e.contains("sobol, independent"),
        "{e}"
    );
}

#[test]
fn light_samples_are_read_and_a_count_out_of_range_is_named() {
    let dir = setup();
    let scene =
        |n: &str| EXAMPLE.replacen("[render]\n", &format!("[render]\nlight_samples = {n}\n"), 1);
    assert_eq!(
        load_scene(&write(dir.path(), EXAMPLE))
            .expect("valid")
            .render
            .light_samples,
        1
    );
    let s = load_scene(&write(dir.path(), &scene("3"))).expect("valid scene");
    assert_eq!(s.render.light_samples, 3);
    for bad in ["0", "65"] {
        let e = load_scene(&write(dir.path(), &scene(bad)))
            .expect_err("out of range")
            .to_string();
        assert!(
            e.contains("render.light_samples") && e.contains(bad) && e.contains("1..=64"),
            "{e}"
        );
    }
}

/// `lambert.btf` in `dir`: a grey Lambertian tabulated on `side` x `side` texels and
/// the Bonn directions, stored as f32.
fn write_lambert_btf(dir: &Path, side: u32) {
    let dirs = meso_materials::btf::directions::bonn81();
    let lambert = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    let btf = meso_materials::btf::Btf::from_brdf(
        &lambert,
        DVec3::splat(0.5),
        side,
        side,
        dirs.clone(),
        dirs,
    )
    .expect("valid BTF");
    meso_materials::btf::file::write_btf(
        &dir.join("lambert.btf"),
        &btf,
        meso_materials::btf::file::BtfPrecision::F32,
    )
    .expect("write BTF");
}

#[test]
fn btf_materials_load_tiled_and_bad_ones_name_the_material() {
    let dir = setup();
    write_lambert_btf(dir.path(), 2);
    let with_btf = |table: &str| {
        EXAMPLE.replace(
            "[materials.chrome]",
            &format!("[materials.velvet]\nkind = \"btf\"\n{table}\n[materials.chrome]"),
        )
    };
    let s = load_scene(&write(
        dir.path(),
        &with_btf("path = \"lambert.btf\"\nuv_scale = [3.0, 2.0]\n"),
    ))
    .expect("valid scene");
    let velvet = s
        .material_names
        .iter()
        .position(|n| n == "velvet")
        .expect("velvet");
    match &s.materials[velvet] {
        Material::Btf { table, uv_scale } => {
            assert_eq!(*uv_scale, DVec2::new(3.0, 2.0));
            assert_eq!((table.width(), table.height()), (2, 2));
            let v = table.eval_texel(3, DVec3::Z, DVec3::Z);
            assert!((v.x - 0.5 / std::f64::consts::PI).abs() < 1e-6, "{v}");
        }
        other => panic!("velvet is a btf material, got {other:?}"),
    }
    // An edit may not give the table a tiling a scene file refuses.
    if let Material::Btf { table, .. } = &s.materials[velvet] {
        let mut edited = s.clone();
        let bad = crate::SceneEdit::Material {
            index: velvet,
            material: Material::Btf {
                table: Arc::clone(table),
                uv_scale: DVec2::new(0.0, 1.0),
            },
        };
        assert!(matches!(
            bad.apply_to(&mut edited),
            Err(crate::EditError::UvScale(_))
        ));
    }
    std::fs::write(dir.path().join("junk.btf"), b"not a btf").expect("write junk");
    for (table, needles) in [
        ("", vec!["materials.velvet.path", "needs `path`"]),
        (
            "path = \"missing.btf\"\n",
            vec!["materials.velvet.path", "missing.btf"],
        ),
        (
            "path = \"junk.btf\"\n",
            vec!["materials.velvet.path", "junk.btf", "safetensors"],
        ),
        (
            "path = \"lambert.btf\"\nuv_scale = [0.0, 1.0]\n",
            vec!["materials.velvet.uv_scale", "positive"],
        ),
        (
            "path = \"lambert.btf\"\ntint = [1.0, 1.0, 1.0]\n",
            vec![
                "materials.velvet.tint",
                "does not belong to a `btf` material",
            ],
        ),
    ] {
        let err = load_scene(&write(dir.path(), &with_btf(table)))
            .expect_err("bad btf material")
            .to_string();
        for n in needles {
            assert!(err.contains(n), "`{n}` missing from: {err}");
        }
    }
}

/// `load_scene_within`'s bound is the scene's: two `btf` materials share it, each
/// held whole only if its value bytes fit its half.
#[test]
fn btf_materials_share_the_scenes_memory_bound() {
    let dir = setup();
    write_lambert_btf(dir.path(), 4);
    std::fs::copy(dir.path().join("lambert.btf"), dir.path().join("copy.btf")).expect("copied");
    let velvet = "[materials.velvet]\nkind = \"btf\"\npath = \"lambert.btf\"\n";
    let one = EXAMPLE.replace("[materials.chrome]", &format!("{velvet}[materials.chrome]"));
    let suede = velvet.replace("velvet", "suede");
    let two = EXAMPLE.replace(
        "[materials.chrome]",
        &format!(
            "{velvet}{}[materials.chrome]",
            suede.replace("lambert.btf", "copy.btf")
        ),
    );
    // Two materials of one file (written two ways) share its table, held whole.
    let same = EXAMPLE.replace(
        "[materials.chrome]",
        &format!(
            "{velvet}{}[materials.chrome]",
            suede.replace("lambert.btf", "./lambert.btf")
        ),
    );
    let bytes = 16 * 81 * 81 * 3 * 4;
    let bound = meso_materials::btf::table::MemoryBound::new(bytes + bytes / 2);
    let held_whole = |text: &str| -> Vec<bool> {
        let s = load_scene_within(&write(dir.path(), text), bound).expect("valid scene");
        s.materials
            .iter()
            .filter_map(|m| match m {
                Material::Btf { table, .. } => {
                    assert_eq!(table.value_bytes(), bytes);
                    Some(table.cache().is_none())
                }
                _ => None,
            })
            .collect()
    };
    assert_eq!(held_whole(&one), [true]);
    assert_eq!(held_whole(&two), [false, false]);
    assert_eq!(held_whole(&same), [true, true]);
    let s = load_scene_within(&write(dir.path(), &same), bound).expect("valid scene");
    let tables: Vec<_> = (s.materials.iter())
        .filter_map(|m| match m {
            Material::Btf { table, .. } => Some(table),
            _ => None,
        })
        .collect();
    assert!(Arc::ptr_eq(tables[0], tables[1]), "one table for one file");
}
