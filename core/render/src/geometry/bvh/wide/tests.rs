//! The wide tree's own tests (the queries are tested through `SceneBvh` in
//! `bvh/mod.rs`).

use glam::DVec3;

use super::super::SceneBvh;
use super::super::tests::load_test_mesh;

/// A refit to moved vertices and back gives the tree built for the original
/// vertices bit for bit: every box is rebuilt from what it holds (none left stale
/// or only grown) and every leaf's rows are rewritten.
#[test]
fn a_refit_there_and_back_restores_every_box_and_leaf() {
    let mut meshes = load_test_mesh("bunny_lowres.obj");
    let original = meshes[0].positions.clone();
    let mut bvh = SceneBvh::build(&meshes);
    let planes = |bvh: &SceneBvh| -> Vec<[[u32; 8]; 6]> {
        let bits = |row: &[f32; 8]| row.map(f32::to_bits);
        bvh.wide
            .nodes
            .iter()
            .map(|n| n.planes.each_ref().map(bits))
            .collect()
    };
    let leaves =
        |bvh: &SceneBvh| -> Vec<u32> { bvh.wide.leaves.iter().map(|x| x.to_bits()).collect() };
    let (built_planes, built_leaves) = (planes(&bvh), leaves(&bvh));
    for p in &mut meshes[0].positions {
        *p = DVec3::new(p.x + 0.3 * p.y, 0.7 * p.y + 0.5, p.z - 0.2);
    }
    assert!(bvh.update(&meshes), "same triangles refit");
    let moved = planes(&bvh);
    let changed = moved
        .iter()
        .zip(&built_planes)
        .filter(|(a, b)| a != b)
        .count();
    assert_eq!(
        changed,
        moved.len(),
        "every node's boxes move with the vertices"
    );
    assert_ne!(leaves(&bvh), built_leaves);
    meshes[0].positions = original;
    assert!(bvh.update(&meshes));
    assert!(
        planes(&bvh) == built_planes,
        "boxes differ after the round trip"
    );
    assert!(
        leaves(&bvh) == built_leaves,
        "leaves differ after the round trip"
    );
}
