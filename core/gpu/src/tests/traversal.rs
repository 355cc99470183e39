//! The device's BVH traversal against the CPU's: every pixel centre's primary hit.

use glam::DVec3;

use crate::kernel::{Kernel, encoder, storage, submit_and_read, zeroed};

use super::kernel_cases::{TEST_SLOTS, f32s, test_module};
use super::{context, test_scene};

/// Every pixel centre's primary ray on the device and on the CPU: the same hit or
/// miss, the same distance, the same triangle (or one at the same distance: a tie),
/// and no traversal past the stack or step bounds. A hardware GPU need not round as
/// the CPU does (its compiler may fuse multiply-adds; Vulkan allows a division 2.5 ulp
/// off), so a ray through a triangle's edge may fall on either side of it: a
/// disagreement passes only where the nearer of the two hits is within `EDGE` of an
/// edge of its triangle (barycentrics in f64), and on at most half of the rays whose
/// hit on either device lies that near an edge (a device whose edge rule left a crack
/// along every edge would disagree on nearly all of them). Lavapipe rounds as the CPU does and has none; the
/// H200 had 12 in the Cornell box, whose camera on the symmetry plane sends 106 pixel
/// centres exactly through the walls' diagonals.
fn primary_hits_match(scene_file: &str, size: u32) {
    const EDGE: f64 = 1e-5;
    let scene = test_scene(scene_file);
    let bvh = meso_render::geometry::SceneBvh::build(&scene.meshes);
    let camera = meso_render::geometry::PinholeCamera::new(&scene.camera, size, size);
    let rays: Vec<_> = (0..size * size)
        .map(|p| camera.ray(p % size, p / size, glam::DVec2::splat(0.5)))
        .collect();
    let mut words = Vec::with_capacity(rays.len() * 8);
    for r in &rays {
        words.extend(f32s(r.origin));
        words.extend(f32s(r.dir));
        // The shader clamps its rays at 3e38 ("infinity"; WGSL may assume no inf).
        words.extend([0f32.to_bits(), 3.0e38f32.to_bits()]);
    }
    let ctx = context();
    let kernel = Kernel::new(ctx, &test_module(), "trace_rays", &TEST_SLOTS);
    let geometry = crate::geometry::GeometryBuffers::upload(ctx, &bvh, &scene.meshes);
    let cases = storage(ctx, "rays", bytemuck::cast_slice(&words));
    let out_size = (rays.len() * 8) as u64;
    let out = zeroed(ctx, "results", out_size);
    let data = zeroed(ctx, "data", 16);
    let counters = zeroed(ctx, "counters", 16);
    let bind = kernel.bind(
        ctx,
        &[
            &data,
            &cases,
            &out,
            &geometry.nodes,
            &geometry.tris,
            &counters,
            &data,
        ],
    );
    let mut enc = encoder(ctx);
    kernel.record(&mut enc, &bind, rays.len() as u32);
    let bytes =
        submit_and_read(ctx, enc, &[(&out, out_size), (&counters, 16)]).expect("the device works");
    let results: &[[f32; 2]] = bytemuck::cast_slice(&bytes[0]);
    let overflows: &[u32] = bytemuck::cast_slice(&bytes[1]);
    assert_eq!(
        &overflows[..2],
        &[0, 0],
        "{scene_file}: stack and step overflows"
    );
    let prims: Vec<(&obvhs::triangle::Triangle, (u32, u32))> = bvh.primitives().collect();
    let by_index: std::collections::HashMap<(usize, usize), &obvhs::triangle::Triangle> = prims
        .iter()
        .map(|&(t, (m, i))| ((m as usize, i as usize), t))
        .collect();
    let (mut hits, mut ties, mut edges, mut edge_rays) = (0, 0, 0, 0);
    for (i, (r, g)) in rays.iter().zip(results).enumerate() {
        let cpu = bvh.closest_hit(r.origin, r.dir, 0.0, f64::INFINITY);
        let gpu = (g[1] >= 0.0).then(|| (g[0] as f64, g[1] as usize));
        hits += usize::from(cpu.is_some());
        // A ray through an edge: either device's hit lies at one.
        let cpu_triangle = cpu.as_ref().map(|h| by_index[&(h.mesh, h.triangle)]);
        let gpu_triangle = gpu.map(|(_, prim)| prims[prim].0);
        edge_rays += usize::from(
            [cpu_triangle, gpu_triangle]
                .into_iter()
                .flatten()
                .any(|t| barycentric_margin(t, r.origin, r.dir) <= EDGE),
        );
        let agree = match (&cpu, gpu) {
            (None, None) => true,
            (Some(h), Some((t, prim))) => {
                let (m, tri) = prims[prim].1;
                let same = (m as usize, tri as usize) == (h.mesh, h.triangle);
                // A tie: another triangle at the same distance (a shared edge).
                ties += usize::from(!same && t as f32 == h.t as f32);
                (t - h.t).abs() <= 1e-6 * h.t && (same || t as f32 == h.t as f32)
            }
            _ => false,
        };
        if agree {
            continue;
        }
        let gpu_t = gpu.map_or(f64::INFINITY, |(t, _)| t);
        let (edge_distance, nearer) = match &cpu {
            Some(h) if h.t <= gpu_t => ((1.0 - h.b1 - h.b2).min(h.b1).min(h.b2), "CPU"),
            _ => {
                let (_, prim) = gpu.expect("the GPU hit is the nearer");
                (barycentric_margin(prims[prim].0, r.origin, r.dir), "GPU")
            }
        };
        assert!(
            edge_distance <= EDGE,
            "{scene_file} pixel {i}: the CPU finds {cpu:?}, the GPU {gpu:?}, and the {nearer}'s \
             hit is {edge_distance:e} inside its triangle, not at an edge"
        );
        edges += 1;
    }
    eprintln!(
        "{scene_file}: {hits} of {} rays hit, {edge_rays} within {EDGE:e} of an edge, \
         {ties} ties, {edges} on an edge disagree",
        rays.len()
    );
    assert!(
        hits > rays.len() / 3,
        "{scene_file}: the camera sees the scene"
    );
    assert!(ties * 100 <= hits, "{scene_file}: {ties} ties of {hits}");
    assert!(
        edges <= edge_rays.div_ceil(2),
        "{scene_file}: {edges} disagreements of {edge_rays} rays through an edge"
    );
}

/// The smallest barycentric weight of the ray's intersection with the triangle's
/// plane, in f64: negative outside, near zero at an edge.
fn barycentric_margin(tri: &obvhs::triangle::Triangle, o: DVec3, d: DVec3) -> f64 {
    let [v0, v1, v2] = [tri.v0, tri.v1, tri.v2].map(|v| v.as_dvec3());
    let (e1, e2) = (v1 - v0, v2 - v0);
    let p = d.cross(e2);
    let inv_det = 1.0 / e1.dot(p);
    let s = o - v0;
    let b1 = s.dot(p) * inv_det;
    let b2 = d.dot(s.cross(e1)) * inv_det;
    (1.0 - b1 - b2).min(b1).min(b2)
}

#[test]
fn primary_hits_equal_the_cpus_on_the_bunny() {
    primary_hits_match("default.toml", 96);
}

#[test]
fn primary_hits_equal_the_cpus_in_the_cornell_box() {
    primary_hits_match("cornell.toml", 96);
}
