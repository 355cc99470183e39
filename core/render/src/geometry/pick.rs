//! What lies under a point of the image: the viewport's click-to-pick. One ray through
//! the exact image position (not jittered), its first hit, the material there and, for
//! an SPMM material, the texel and cluster the renderer shades at that point.

use glam::{DVec2, DVec3};

use super::bvh::SceneBvh;
use super::camera::PinholeCamera;
use crate::scene::{Material, Scene};

/// The surface under a pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pick {
    pub position: DVec3,
    pub mesh: usize,
    pub material: usize,
    /// Interpolated texture coordinates (before the material's tiling).
    pub uv: DVec2,
    /// For SPMM materials: the texel (row-major) and its cluster.
    pub texel: Option<(usize, usize)>,
}

/// The first surface seen through image position (x, y) in pixels (x right, y down,
/// fractional) of a `width` x `height` image of `scene` from its camera.
pub fn pick(
    scene: &Scene,
    bvh: &SceneBvh,
    width: u32,
    height: u32,
    x: f64,
    y: f64,
) -> Option<Pick> {
    if !(x.is_finite() && y.is_finite()) || x < 0.0 || y < 0.0 {
        return None;
    }
    let camera = PinholeCamera::new(&scene.camera, width, height);
    let (px, py) = (x.floor(), y.floor());
    let ray = camera.ray(px as u32, py as u32, DVec2::new(x - px, y - py));
    let hit = bvh.closest_hit(ray.origin, ray.dir, 0.0, f64::INFINITY)?;
    let mesh = &scene.meshes[hit.mesh];
    let [i0, i1, i2] = mesh.indices[hit.triangle].map(|i| i as usize);
    let w0 = 1.0 - hit.b1 - hit.b2;
    let uv = mesh.uvs[i0] * w0 + mesh.uvs[i1] * hit.b1 + mesh.uvs[i2] * hit.b2;
    let texel = match &scene.materials[mesh.material] {
        Material::Spmm {
            material, uv_scale, ..
        } => {
            let t = material.texel_at(uv, *uv_scale);
            Some((t, material.texel_cluster()[t] as usize))
        }
        _ => None,
    };
    Some(Pick {
        position: ray.origin + ray.dir * hit.t,
        mesh: hit.mesh,
        material: mesh.material,
        uv,
        texel,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::test_scenes::edit_test_scene;

    #[test]
    fn picks_the_panel_its_texel_and_cluster_and_misses_the_sky() {
        let scene = edit_test_scene();
        let bvh = SceneBvh::build(&scene.meshes);
        // The camera looks at (0, 0.2, 0): the image centre sees the SPMM panel
        // (material 1, the quad x in [-0.4, 0.4], y in [0, 0.8] at z = 0).
        let p = pick(&scene, &bvh, 100, 100, 50.0, 50.0).expect("hits the panel");
        assert_eq!(p.material, 1);
        assert!(
            p.position.z.abs() < 1e-6 && (p.position.y - 0.2).abs() < 1e-6,
            "{p:?}"
        );
        let Material::Spmm {
            material, uv_scale, ..
        } = &scene.materials[1]
        else {
            panic!("material 1 is the SPMM panel");
        };
        let (t, c) = p.texel.expect("an SPMM texel");
        assert_eq!(t, material.texel_at(p.uv, *uv_scale));
        assert_eq!(c, material.texel_cluster()[t] as usize);
        // The bottom row sees the floor; the top-left corner sees the background.
        assert_eq!(
            pick(&scene, &bvh, 100, 100, 50.0, 99.0).map(|p| p.material),
            Some(0)
        );
        assert_eq!(pick(&scene, &bvh, 100, 100, 0.0, 0.0), None);
        assert_eq!(pick(&scene, &bvh, 100, 100, f64::NAN, 0.0), None);
    }
}
