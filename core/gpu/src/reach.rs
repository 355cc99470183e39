//! Which clusters of each SPMM pack a scene can reach, so the device holds only their
//! data (bases and residual tables). The GPU cannot prepare on demand as the CPU
//! does, so the set is conservative: every texel under the UV box of every triangle
//! that carries the material, mapped through its tiling, with a margin for f32
//! rounding and bilinear neighbours. A pack no mesh carries reaches nothing.

use meso_render::reach::wrapped;
use meso_render::scene::{Material, Scene};

/// Per material: `Some(used clusters)` for an SPMM pack, `Some([carried])` for a
/// `btf` table (uploaded whole, or not at all if no mesh carries it), `None` for
/// other kinds.
pub type Reach = Vec<Option<Vec<bool>>>;

/// The clusters each SPMM pack of `scene` can be shaded at.
pub fn reachable_clusters(scene: &Scene) -> Reach {
    scene
        .materials
        .iter()
        .enumerate()
        .map(|(i, m)| match m {
            Material::Spmm {
                material, uv_scale, ..
            } => {
                let covered =
                    covered_texels(scene, i, material.width(), material.height(), *uv_scale);
                Some(match covered {
                    Some(texels) => material.clusters_of_texels(texels),
                    None => vec![true; material.clusters().len()],
                })
            }
            Material::Btf { .. } => Some(vec![scene.meshes.iter().any(|m| m.material == i)]),
            _ => None,
        })
        .collect()
}

/// The texels under the UV boxes of material `index`'s triangles on a `width` x
/// `height` grid tiled by `scale`; `None` when that is every texel (or a UV is not
/// finite: then nothing is assumed).
fn covered_texels(
    scene: &Scene,
    index: usize,
    width: u32,
    height: u32,
    scale: glam::DVec2,
) -> Option<Vec<usize>> {
    let (w, h) = (i64::from(width), i64::from(height));
    let stride = (w + 1) as usize;
    // A difference table of the boxes: one add per corner, then prefix sums.
    let mut diff = vec![0i32; stride * (h + 1) as usize];
    for mesh in scene.meshes.iter().filter(|m| m.material == index) {
        for tri in &mesh.indices {
            let uv = tri.map(|v| mesh.uvs[v as usize] * scale);
            if !uv.iter().all(|p| p.is_finite()) {
                return None;
            }
            let lo = uv[0].min(uv[1]).min(uv[2]);
            let hi = uv[0].max(uv[1]).max(uv[2]);
            // One texel of margin, plus what the device's f32 coordinates may be off
            // by (about 16 ulps of the largest coordinate, in texels).
            let slack = |c: f64, n: i64| 1 + (c * n as f64 * 1e-6).ceil() as i64;
            let mx = slack(lo.x.abs().max(hi.x.abs()), w);
            let my = slack(lo.y.abs().max(hi.y.abs()), h);
            // Columns grow with u; rows grow as v falls (row 0 is the top).
            let (x0, x1) = (
                (lo.x * w as f64).floor() as i64 - mx,
                (hi.x * w as f64).floor() as i64 + mx,
            );
            let (y0, y1) = (
                (-hi.y * h as f64).floor() as i64 - my,
                (-lo.y * h as f64).floor() as i64 + my,
            );
            let (xs, ys) = (wrapped(x0, x1, w), wrapped(y0, y1, h));
            if xs[0] == Some((0, w)) && ys[0] == Some((0, h)) {
                return None;
            }
            for &(ya, yb) in ys.iter().flatten() {
                for &(xa, xb) in xs.iter().flatten() {
                    let at = |x: i64, y: i64| y as usize * stride + x as usize;
                    diff[at(xa, ya)] += 1;
                    diff[at(xb, ya)] -= 1;
                    diff[at(xa, yb)] -= 1;
                    diff[at(xb, yb)] += 1;
                }
            }
        }
    }
    // Prefix sums in place: entry (x, y) becomes the number of boxes covering it.
    for y in 0..=h as usize {
        for x in 0..=w as usize {
            let mut v = diff[y * stride + x];
            if x > 0 {
                v += diff[y * stride + x - 1];
            }
            if y > 0 {
                v += diff[(y - 1) * stride + x];
            }
            if x > 0 && y > 0 {
                v -= diff[(y - 1) * stride + x - 1];
            }
            diff[y * stride + x] = v;
        }
    }
    Some(
        (0..h as usize)
            .flat_map(|y| (0..w as usize).map(move |x| (x, y)))
            .filter(|&(x, y)| diff[y * stride + x] > 0)
            .map(|(x, y)| y * w as usize + x)
            .collect(),
    )
}

#[cfg(test)]
pub(super) mod tests {
    use glam::DVec2;

    use super::*;
    use meso_materials::rng::SampleStream;

    /// Every point of every triangle carrying a pack lands, by the CPU's own texel
    /// look-up (nearest and its bilinear neighbours), in a cluster marked reachable;
    /// on the test scenes and on a panel whose UVs cover a corner of its texture
    /// (where some clusters are unreachable, so the test can tell).
    #[test]
    fn every_shaded_texel_is_in_a_reachable_cluster() {
        let mut scenes: Vec<Scene> = ["default.toml", "cornell.toml", "cloth.toml", "env.toml"]
            .iter()
            .map(|f| super::super::tests::test_scene(f))
            .collect();
        scenes.push(partial_panel_scene());
        let mut unreached = 0;
        for scene in &scenes {
            let reach = reachable_clusters(scene);
            for (i, m) in scene.materials.iter().enumerate() {
                let Material::Spmm {
                    material, uv_scale, ..
                } = m
                else {
                    continue;
                };
                let used = reach[i].as_ref().expect("a pack's clusters");
                unreached += used.iter().filter(|u| !**u).count();
                eprintln!(
                    "material {i}: {} of {} clusters reachable",
                    used.iter().filter(|u| **u).count(),
                    used.len()
                );
                let grid = meso_materials::spmm::TexelGrid::of(material);
                for mesh in scene.meshes.iter().filter(|m| m.material == i) {
                    for (k, tri) in mesh.indices.iter().enumerate() {
                        let mut s = SampleStream::new(&[41, i as u64, k as u64]);
                        for _ in 0..4 {
                            let (a, b) = (s.next(), s.next());
                            let (a, b) = if a + b > 1.0 {
                                (1.0 - a, 1.0 - b)
                            } else {
                                (a, b)
                            };
                            let uv = mesh.uvs[tri[0] as usize] * (1.0 - a - b)
                                + mesh.uvs[tri[1] as usize] * a
                                + mesh.uvs[tri[2] as usize] * b;
                            let t = grid.nearest(uv, *uv_scale);
                            let c = material.texel_cluster()[t] as usize;
                            assert!(used[c], "material {i}, triangle {k}, uv {uv}: cluster {c}");
                        }
                    }
                }
            }
        }
        assert!(unreached > 0, "the partial panel leaves clusters unreached");
    }

    /// A pack no mesh carries reaches nothing.
    #[test]
    fn a_pack_no_mesh_carries_reaches_no_cluster() {
        let mut scene = partial_panel_scene();
        scene.meshes.retain(|m| m.material != 1);
        let reach = reachable_clusters(&scene);
        assert!(reach[0].is_none());
        assert!(reach[1].as_ref().expect("a pack").iter().all(|u| !u));
    }

    /// The edit test scene with a 16 x 16 panel pack whose right half is cluster 1
    /// alone, and the panel's UVs inside that half (columns 10 to 12 after the 2 x
    /// tiling): cluster 0 is unreachable.
    pub(crate) fn partial_panel_scene() -> Scene {
        let mut scene = meso_render::scene::test_scenes::edit_test_scene();
        let pack = meso_materials::spmm::testing::sample_material(16, 16, 2, Some(3));
        // Cluster 1 has the larger dictionary, so every texel's basis indices fit it.
        let clusters: Vec<u32> = pack
            .texel_cluster()
            .iter()
            .enumerate()
            .map(|(t, &c)| if t % 16 >= 8 { 1 } else { c })
            .collect();
        let pack = meso_materials::spmm::SpmmMaterial::new(
            pack.name().into(),
            pack.provenance().into(),
            16,
            16,
            pack.clusters().to_vec(),
            clusters,
            pack.weights().clone(),
            pack.residual().cloned(),
        )
        .expect("valid pack");
        let Material::Spmm { material, .. } = &mut scene.materials[1] else {
            panic!("the panel is a pack");
        };
        *material = std::sync::Arc::new(pack);
        for mesh in scene.meshes.iter_mut().filter(|m| m.material == 1) {
            for uv in &mut mesh.uvs {
                *uv = DVec2::new(0.33 + 0.06 * uv.x, 0.15 + 0.1 * uv.y);
            }
        }
        scene
    }
}
