//! The shipped scenes load (the default scene is what the README, the app and the
//! renderer tests use).

use std::path::PathBuf;

use meso_render::scene::{Background, Light, Material, load_scene};

#[test]
fn the_default_scene_loads() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/default.toml");
    let s = load_scene(&path).expect("the default scene is valid");
    assert_eq!(s.meshes.len(), 2, "bunny and floor");
    // The low-resolution bunny: 3,674 triangles (tests/scenes/meshes/LICENSES.md).
    assert_eq!(s.meshes[0].indices.len(), 3674);
    let cloth = s.meshes[0].material;
    assert!(matches!(s.materials[cloth], Material::Spmm { .. }));
    // The editor saves the pack back to the file it came from.
    let pack = s.material_files[cloth].as_ref().expect("the pack's file");
    assert!(
        pack.ends_with("materials/leather.spmm"),
        "{}",
        pack.display()
    );
    assert!(s.material_files.iter().filter(|f| f.is_some()).count() == 1);
    // The area light faces the floor: edge_u x edge_v points down.
    let Light::Area { edge_u, edge_v, .. } = s.lights[0] else {
        panic!("an area light")
    };
    assert!(edge_u.cross(edge_v).y < 0.0);
    assert!(s.ambient.is_some());
    assert!(matches!(s.background, Background::Color(_)));
}

#[test]
fn the_cornell_box_and_cloth_scenes_load() {
    for (name, meshes, lights) in [
        ("cornell.toml", 16, 1),
        ("cloth.toml", 2, 2),
        ("fitted.toml", 2, 1),
    ] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("scenes")
            .join(name);
        let s = load_scene(&path).expect("the scene is valid");
        assert_eq!((s.meshes.len(), s.lights.len()), (meshes, lights), "{name}");
        assert!(
            s.materials
                .iter()
                .any(|m| matches!(m, Material::Spmm { .. })),
            "{name} shows an SPMM pack"
        );
    }
}

#[test]
fn the_merl_scenes_load_with_their_tables_and_lights() {
    // (scene, triangles of its object, MERL materials, environment strength)
    for (name, triangles, merl, strength) in [
        ("merl_bunny.toml", 3674, 2, 1.0),
        ("merl_dragon.toml", 46_540, 1, 0.8),
        ("merl_teapot.toml", 992, 2, 0.35),
    ] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("scenes")
            .join(name);
        let s = load_scene(&path).expect("the scene is valid");
        assert_eq!(s.meshes[0].indices.len(), triangles, "{name}");
        let tables: Vec<_> = s
            .materials
            .iter()
            .filter_map(|m| match m {
                Material::Merl { brdf, .. } => Some(brdf),
                _ => None,
            })
            .collect();
        assert_eq!(tables.len(), merl, "{name}");
        // Tabulated at load: every table holds data and reflects less than it receives.
        for t in tables {
            let albedo = t.albedo_at_normal();
            assert!(
                albedo.min_element() > 0.0 && albedo.max_element() < 1.0,
                "{name}: albedo {albedo}"
            );
        }
        assert!(matches!(s.lights[0], Light::Area { .. }), "{name}");
        let env = s.environment.as_ref().expect("an environment");
        assert_eq!(env.strength, strength, "{name}");
        assert!(
            matches!(s.background, Background::FromEnvironment),
            "{name}"
        );
    }
}
