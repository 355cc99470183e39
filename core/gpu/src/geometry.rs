//! The scene's geometry on the device: obvhs's CWBVH nodes uploaded as they are
//! (80-byte `Pod` records), the triangles in leaf order as f32 (what the CPU's
//! traversal tests, so hits agree bit for bit) with their material and scene
//! (mesh, triangle), and per triangle the vertex normals and UVs shading needs.

use meso_render::geometry::SceneBvh;
use meso_render::scene::TriangleMesh;

use super::GpuContext;
use super::kernel::storage;

/// Words per triangle in `tris` (v0, v1, v2, material, mesh, triangle).
pub(super) const TRI_WORDS: usize = 12;
/// Floats per triangle in `shade` (n0, n1, n2, uv0, uv1, uv2, pad).
pub(super) const SHADE_FLOATS: usize = 16;

/// The device buffers of one scene's geometry.
pub(super) struct GeometryBuffers {
    pub nodes: wgpu::Buffer,
    pub tris: wgpu::Buffer,
    pub shade: wgpu::Buffer,
    pub bvh_bytes: u64,
    pub triangle_bytes: u64,
}

/// The words of `tris` and the floats of `shade`, in the BVH's leaf order.
pub(super) fn triangle_arrays(bvh: &SceneBvh, meshes: &[TriangleMesh]) -> (Vec<u32>, Vec<f32>) {
    let mut tris = Vec::with_capacity(bvh.primitives().len() * TRI_WORDS);
    let mut shade = Vec::with_capacity(bvh.primitives().len() * SHADE_FLOATS);
    for (tri, (m, t)) in bvh.primitives() {
        let mesh = &meshes[m as usize];
        for v in [tri.v0, tri.v1, tri.v2] {
            tris.extend([v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]);
        }
        tris.extend([mesh.material as u32, m, t]);
        let idx = mesh.indices[t as usize];
        for i in idx {
            let n = mesh.normals[i as usize];
            shade.extend([n.x as f32, n.y as f32, n.z as f32]);
        }
        for i in idx {
            let uv = mesh.uvs[i as usize];
            shade.extend([uv.x as f32, uv.y as f32]);
        }
        shade.push(0.0);
    }
    (tris, shade)
}

impl GeometryBuffers {
    pub fn upload(ctx: &GpuContext, bvh: &SceneBvh, meshes: &[TriangleMesh]) -> Self {
        let nodes: &[u8] = bytemuck::cast_slice(bvh.nodes());
        let (tris, shade) = triangle_arrays(bvh, meshes);
        Self {
            nodes: storage(ctx, "bvh nodes", nodes),
            tris: storage(ctx, "triangles", bytemuck::cast_slice(&tris)),
            shade: storage(ctx, "shading", bytemuck::cast_slice(&shade)),
            bvh_bytes: nodes.len() as u64,
            triangle_bytes: (tris.len() * 4 + shade.len() * 4) as u64,
        }
    }
}
