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
    assert!(matches!(
        s.materials[s.meshes[0].material],
        Material::Spmm { .. }
    ));
    // The area light faces the floor: edge_u x edge_v points down.
    let Light::Area { edge_u, edge_v, .. } = s.lights[0] else {
        panic!("an area light")
    };
    assert!(edge_u.cross(edge_v).y < 0.0);
    assert!(s.ambient.is_some());
    assert!(matches!(s.background, Background::Color(_)));
}
