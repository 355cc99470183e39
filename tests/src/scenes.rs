//! The shipped scenes load (the default scene is what the README, the app and the
//! renderer tests use).

use std::path::PathBuf;

use meso_core::scene::{Background, Light, Material, load_scene};

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
