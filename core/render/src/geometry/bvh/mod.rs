//! Ray queries against a scene's triangles: closest-hit and occlusion (any-hit)
//! queries. obvhs builds a binary BVH on scene load (PLOC, one triangle a leaf); the
//! CPU traverses it collapsed into 8-wide nodes (`wide.rs`: SIMD box tests, ordered
//! traversal, in f32); a hit's barycentrics are the hit test's own (f32), which shading
//! combines with the mesh's f64 vertices. obvhs's compressed wide BVH (CWBVH, Ylitie
//! et al. 2017) is made from the same binary tree on first use: the GPU traverses it,
//! and obvhs's own traversal of it is the reference the CPU one is tested and
//! benchmarked against. Degenerate (zero-area) triangles are left out. Moved geometry
//! with the same triangles is refitted (every box updated bottom-up, the trees keep
//! their shape) instead of rebuilt; docs/performance.md has both costs.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use glam::{DVec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::ploc::PlocBuilder;
use obvhs::ray::{Ray as BvhRay, RayHit};
use obvhs::triangle::Triangle;

use crate::scene::TriangleMesh;

mod wide;

pub use wide::Kernel;
use wide::{Found, Query, WideBvh};

/// The closest intersection of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub mesh: usize,
    pub triangle: usize,
    /// Barycentric weights of the triangle's vertices 1 and 2 (vertex 0 gets 1 - b1 - b2).
    pub b1: f64,
    pub b2: f64,
}

pub struct SceneBvh {
    /// obvhs's compressed wide BVH of `bvh2`, made on first use: only the GPU
    /// traversal and the reference queries read it, so CPU renders never pay for it.
    bvh: OnceLock<CwBvh>,
    /// The tree the CPU traverses, collapsed from `bvh2` and refitted in place.
    wide: WideBvh,
    /// The binary BVH both wide trees are made from, refitted with them.
    bvh2: Bvh2,
    triangles: Vec<Triangle>,
    /// (mesh, triangle within the mesh) of each BVH primitive.
    refs: Vec<(u32, u32)>,
    build_time: Duration,
    refitted: bool,
    degenerate: usize,
}

/// Build settings: obvhs' medium preset (PLOC, no pre-splitting, so every leaf of the
/// binary BVH is one triangle and can be refitted).
const PARAMS: BvhBuildParams = BvhBuildParams::medium_build();

fn v3a(p: DVec3) -> Vec3A {
    Vec3A::new(p.x as f32, p.y as f32, p.z as f32)
}

/// A ray for the CPU traversal, in f32 as the BVH stores the triangles.
fn query(origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> Query {
    Query::new(
        v3a(origin).to_array(),
        v3a(dir).to_array(),
        tmin as f32,
        tmax as f32,
    )
}

impl SceneBvh {
    pub fn build(meshes: &[TriangleMesh]) -> Self {
        let (triangles, refs, degenerate) = collect_triangles(meshes);
        let start = Instant::now();
        let mut bvh2 = PlocBuilder::with_capacity(triangles.len()).build(
            PARAMS.ploc_search_distance,
            &triangles,
            (0..triangles.len() as u32).collect(),
            PARAMS.sort_precision,
            PARAMS.search_depth_threshold,
        );
        ReinsertionOptimizer::default().run(&mut bvh2, PARAMS.reinsertion_batch_ratio, None);
        let wide = WideBvh::new(&bvh2, &triangles, &refs);
        Self {
            bvh: OnceLock::new(),
            wide,
            bvh2,
            triangles,
            refs,
            build_time: start.elapsed(),
            refitted: false,
            degenerate,
        }
    }

    /// Follows moved geometry: refits when `meshes` has the same triangles (and the same
    /// zero-area ones) as the last build, rebuilds otherwise. Returns true if it refitted.
    pub fn update(&mut self, meshes: &[TriangleMesh]) -> bool {
        let (triangles, refs, degenerate) = collect_triangles(meshes);
        if refs != self.refs || triangles.is_empty() {
            *self = Self::build(meshes);
            return false;
        }
        let start = Instant::now();
        self.bvh2.init_primitives_to_nodes_if_uninit();
        for (prim, tri) in triangles.iter().enumerate() {
            let node = self.bvh2.primitives_to_nodes[prim] as usize;
            self.bvh2.nodes[node].set_aabb(tri.aabb());
        }
        self.bvh2.refit_all();
        self.bvh = OnceLock::new();
        self.wide.refit(&triangles);
        self.triangles = triangles;
        self.degenerate = degenerate;
        self.build_time = start.elapsed();
        self.refitted = true;
        true
    }

    /// obvhs's compressed wide BVH, compressed now if this is its first use since the
    /// last build or refit.
    fn cwbvh(&self) -> &CwBvh {
        self.bvh.get_or_init(|| compress(&self.bvh2))
    }

    /// Wall time of the last build or refit.
    pub fn build_time(&self) -> Duration {
        self.build_time
    }

    /// Whether the last update was a refit (else a full build).
    pub fn refitted(&self) -> bool {
        self.refitted
    }

    /// obvhs's CWBVH nodes (80-byte `Pod` records), what a device traversal reads; the
    /// first call after a build or refit makes the CWBVH.
    pub fn nodes(&self) -> &[obvhs::cwbvh::node::CwBvhNode] {
        &self.cwbvh().nodes
    }

    /// Per BVH primitive (leaf slot), the f32 triangle it tests and the scene's
    /// (mesh, triangle within the mesh): what a device traversal reads, in leaf order.
    pub fn primitives(&self) -> impl ExactSizeIterator<Item = (&Triangle, (u32, u32))> + '_ {
        self.cwbvh().primitive_indices.iter().map(|&i| {
            let i = i as usize;
            (&self.triangles[i], self.refs[i])
        })
    }

    /// Triangles in the BVH and zero-area triangles left out.
    pub fn triangle_counts(&self) -> (usize, usize) {
        (self.triangles.len(), self.degenerate)
    }

    /// The closest hit with `t` in [tmin, tmax].
    pub fn closest_hit(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> Option<Hit> {
        Some(self.hit(self.wide.closest(&query(origin, dir, tmin, tmax))?))
    }

    /// `closest_hit` with a chosen node test (`Kernel::Avx2` only where the CPU has it:
    /// `Kernel::detect`); every kernel finds the same hits.
    pub fn closest_hit_with(
        &self,
        kernel: Kernel,
        origin: DVec3,
        dir: DVec3,
        tmin: f64,
        tmax: f64,
    ) -> Option<Hit> {
        if kernel == Kernel::Avx2 {
            assert_eq!(Kernel::detect(), Kernel::Avx2, "this CPU has no AVX2");
        }
        let q = query(origin, dir, tmin, tmax);
        Some(self.hit(self.wide.closest_with(kernel, &q)?))
    }

    /// The closest hit by obvhs's own CWBVH traversal: the reference the CPU traversal
    /// is tested against and `meso bench rays --baseline` measures.
    pub fn closest_hit_reference(
        &self,
        origin: DVec3,
        dir: DVec3,
        tmin: f64,
        tmax: f64,
    ) -> Option<Hit> {
        if self.triangles.is_empty() {
            return None;
        }
        let ray = BvhRay::new(v3a(origin), v3a(dir), tmin as f32, tmax as f32);
        let mut hit = RayHit::none();
        let bvh = self.cwbvh();
        let source = |slot: u32| bvh.primitive_indices[slot as usize] as usize;
        let found = bvh.ray_traverse(ray, &mut hit, |r, slot| {
            self.triangles[source(slot as u32)].intersect(r)
        });
        found.then(|| {
            // The CWBVH's slots are its own (not the CPU tree's): map through its table.
            let i = source(hit.primitive_id);
            let (u, v) = wide::barycentrics(&self.triangles[i], &query(origin, dir, tmin, tmax));
            hit_record(self.refs[i], hit.t, u, v)
        })
    }

    /// The hit record of what the CPU traversal found.
    fn hit(&self, found: Found) -> Hit {
        hit_record(self.wide.owner(found.slot), found.t, found.u, found.v)
    }

    /// True if anything blocks the segment from `origin` along `dir` within [tmin, tmax].
    pub fn occluded(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> bool {
        self.wide.occluded(&query(origin, dir, tmin, tmax))
    }

    /// `occluded` with a chosen node test (as `closest_hit_with`).
    pub fn occluded_with(
        &self,
        kernel: Kernel,
        origin: DVec3,
        dir: DVec3,
        tmin: f64,
        tmax: f64,
    ) -> bool {
        if kernel == Kernel::Avx2 {
            assert_eq!(Kernel::detect(), Kernel::Avx2, "this CPU has no AVX2");
        }
        self.wide
            .occluded_with(kernel, &query(origin, dir, tmin, tmax))
    }

    /// `occluded` by obvhs's own traversal (the reference, as `closest_hit_reference`).
    pub fn occluded_reference(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> bool {
        if self.triangles.is_empty() {
            return false;
        }
        let ray = BvhRay::new(v3a(origin), v3a(dir), tmin as f32, tmax as f32);
        let bvh = self.cwbvh();
        !bvh.ray_traverse_miss(ray, |r, slot| {
            self.triangles[bvh.primitive_indices[slot] as usize].intersect(r)
        })
    }
}

/// A hit on triangle `tri` of mesh `m` at distance `t` with the hit test's f32
/// barycentrics `u`, `v` of vertices 1 and 2 (inside the triangle: the test refuses any
/// negative weight). Shading combines the f64 vertices with them, so the point stays on
/// the triangle's plane; reading those vertices here instead cost a cache miss per
/// incoherent ray (docs/performance.md).
fn hit_record((m, tri): (u32, u32), t: f32, u: f32, v: f32) -> Hit {
    Hit {
        t: t as f64,
        mesh: m as usize,
        triangle: tri as usize,
        b1: u as f64,
        b2: v as f64,
    }
}

/// The scene's non-degenerate triangles in f32, their (mesh, triangle) and how many
/// zero-area triangles were left out.
fn collect_triangles(meshes: &[TriangleMesh]) -> (Vec<Triangle>, Vec<(u32, u32)>, usize) {
    let mut triangles = Vec::new();
    let mut refs = Vec::new();
    let mut degenerate = 0;
    for (m, mesh) in meshes.iter().enumerate() {
        for (t, idx) in mesh.indices.iter().enumerate() {
            let [a, b, c] = idx.map(|i| mesh.positions[i as usize]);
            let (v0, v1, v2) = (v3a(a), v3a(b), v3a(c));
            // Zero area in f64, or not a proper triangle once in f32 (collapsed, or
            // non-finite: scenes refuse such input, this keeps obvhs safe regardless).
            let area2_f32 = (v1 - v0).cross(v2 - v0).length_squared();
            if (b - a).cross(c - a).length_squared() <= 0.0
                || !(area2_f32 > 0.0 && area2_f32.is_finite())
            {
                degenerate += 1;
                continue;
            }
            triangles.push(Triangle { v0, v1, v2 });
            refs.push((m as u32, t as u32));
        }
    }
    (triangles, refs, degenerate)
}

/// The wide BVH traversed at render time (up to 3 triangles per leaf).
fn compress(bvh2: &Bvh2) -> CwBvh {
    bvh2_to_cwbvh(bvh2, PARAMS.max_prims_per_leaf.clamp(1, 3), true, false)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::mesh::quad;

    fn floor_and_wall() -> Vec<TriangleMesh> {
        vec![
            quad(
                DVec3::new(-1.0, 0.0, 1.0),
                DVec3::new(2.0, 0.0, 0.0),
                DVec3::new(0.0, 0.0, -2.0),
                0,
            ),
            quad(
                DVec3::new(-1.0, 0.0, -1.0),
                DVec3::new(2.0, 0.0, 0.0),
                DVec3::new(0.0, 2.0, 0.0),
                1,
            ),
        ]
    }

    #[test]
    fn closest_hit_and_barycentrics() {
        let meshes = floor_and_wall();
        let bvh = SceneBvh::build(&meshes);
        assert_eq!(bvh.triangle_counts(), (4, 0));
        // Straight down onto the floor at (0.5, 0, 0.25).
        let h = bvh
            .closest_hit(
                DVec3::new(0.5, 1.0, 0.25),
                DVec3::NEG_Y,
                1e-4,
                f64::INFINITY,
            )
            .expect("hits the floor");
        assert_eq!(h.mesh, 0);
        assert!((h.t - 1.0).abs() < 1e-6);
        let idx = meshes[0].indices[h.triangle];
        let [a, b, c] = idx.map(|i| meshes[0].positions[i as usize]);
        let p = a * (1.0 - h.b1 - h.b2) + b * h.b1 + c * h.b2;
        assert!((p - DVec3::new(0.5, 0.0, 0.25)).length() < 1e-6, "{p}");
        // Towards the wall, the floor behind is farther: the wall wins.
        let h = bvh
            .closest_hit(DVec3::new(0.0, 0.5, 0.5), DVec3::NEG_Z, 1e-4, f64::INFINITY)
            .expect("hits the wall");
        assert_eq!(h.mesh, 1);
        assert!((h.t - 1.5).abs() < 1e-6);
        // Away from everything: no hit; tmax shorter than the distance: no hit.
        assert!(
            bvh.closest_hit(DVec3::new(0.0, 0.5, 0.5), DVec3::Y, 1e-4, f64::INFINITY)
                .is_none()
        );
        assert!(
            bvh.closest_hit(DVec3::new(0.5, 1.0, 0.25), DVec3::NEG_Y, 1e-4, 0.5)
                .is_none()
        );
    }

    #[test]
    fn occlusion_respects_the_segment() {
        let meshes = floor_and_wall();
        let bvh = SceneBvh::build(&meshes);
        let from = DVec3::new(0.0, 0.5, 0.5);
        assert!(bvh.occluded(from, DVec3::NEG_Z, 1e-4, 10.0));
        assert!(
            !bvh.occluded(from, DVec3::NEG_Z, 1e-4, 1.0),
            "the wall is 1.5 away"
        );
        assert!(!bvh.occluded(from, DVec3::Y, 1e-4, f64::INFINITY));
    }

    #[test]
    fn moved_geometry_is_refitted_and_new_geometry_rebuilt() {
        let mut meshes = floor_and_wall();
        let mut bvh = SceneBvh::build(&meshes);
        // Lift the floor by 0.25: same triangles, so a refit; rays see the new place.
        for p in &mut meshes[0].positions {
            p.y += 0.25;
        }
        assert!(bvh.update(&meshes), "same topology refits");
        let down = |bvh: &SceneBvh| {
            bvh.closest_hit(DVec3::new(0.5, 1.0, 0.25), DVec3::NEG_Y, 1e-4, 9.0)
                .map(|h| h.t)
        };
        assert!((down(&bvh).expect("floor") - 0.75).abs() < 1e-6);
        // Moving it far beyond the old box: a refit must grow the boxes.
        for p in &mut meshes[0].positions {
            p.y -= 5.0;
        }
        assert!(bvh.update(&meshes));
        assert!((down(&bvh).expect("floor") - 5.75).abs() < 1e-5);
        assert!(bvh.occluded(DVec3::new(0.0, 0.5, 0.5), DVec3::NEG_Z, 1e-4, 10.0));
        // A mesh fewer: rebuilt.
        meshes.pop();
        assert!(!bvh.update(&meshes));
        assert!(!bvh.refitted());
        assert_eq!(bvh.triangle_counts(), (2, 0));
        assert!(!bvh.occluded(DVec3::new(0.0, 0.5, 0.5), DVec3::NEG_Z, 1e-4, 10.0));
    }

    #[test]
    fn degenerate_triangles_are_left_out_and_empty_scenes_answer() {
        let mut meshes = floor_and_wall();
        meshes[0].positions.push(DVec3::ONE);
        let n = meshes[0].positions.len() as u32 - 1;
        meshes[0].indices.push([n, n, n]);
        let bvh = SceneBvh::build(&meshes);
        assert_eq!(bvh.triangle_counts(), (4, 1));
        let empty = SceneBvh::build(&[]);
        assert!(empty.closest_hit(DVec3::ZERO, DVec3::Y, 0.0, 1.0).is_none());
        assert!(!empty.occluded(DVec3::ZERO, DVec3::Y, 0.0, 1.0));
    }

    /// Closest hit by testing every triangle (Moller-Trumbore in f64): (t, mesh, triangle).
    fn brute_force(
        meshes: &[TriangleMesh],
        o: DVec3,
        d: DVec3,
        tmax: f64,
    ) -> Option<(f64, usize, usize)> {
        let mut best: Option<(f64, usize, usize)> = None;
        for (m, mesh) in meshes.iter().enumerate() {
            for (t, idx) in mesh.indices.iter().enumerate() {
                let [a, b, c] = idx.map(|i| mesh.positions[i as usize]);
                let (e1, e2) = (b - a, c - a);
                let p = d.cross(e2);
                let det = e1.dot(p);
                if det == 0.0 || e1.cross(e2).length_squared() <= 0.0 {
                    continue;
                }
                let s = o - a;
                let u = s.dot(p) / det;
                let q = s.cross(e1);
                let v = d.dot(q) / det;
                let dist = e2.dot(q) / det;
                if u >= 0.0
                    && v >= 0.0
                    && u + v <= 1.0
                    && dist > 0.0
                    && dist < tmax
                    && best.is_none_or(|(bt, _, _)| dist < bt)
                {
                    best = Some((dist, m, t));
                }
            }
        }
        best
    }

    /// Every ray's BVH answer against the brute force; returns (rays, hits).
    fn check_against_brute_force(
        meshes: &[TriangleMesh],
        bvh: &SceneBvh,
        seed: u64,
    ) -> (usize, usize) {
        let (lo, hi) = meshes[0].positions.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let (centre, radius) = ((lo + hi) * 0.5, (hi - lo).length());
        let mut rng = meso_materials::rng::SampleStream::new(&[seed]);
        let (rays, mut hits, mut ties) = (4000, 0, 0);
        for _ in 0..rays {
            // From a sphere around the mesh towards a point in its box: most rays hit,
            // some graze silhouettes, some miss.
            let z = 2.0 * rng.next() - 1.0;
            let phi = std::f64::consts::TAU * rng.next();
            let r = (1.0 - z * z).sqrt();
            let o = centre + radius * DVec3::new(r * phi.cos(), r * phi.sin(), z);
            let target = lo + (hi - lo) * DVec3::new(rng.next(), rng.next(), rng.next());
            let d = (target - o).normalize();
            let bvh_hit = bvh.closest_hit(o, d, 0.0, 1e3);
            let brute = brute_force(meshes, o, d, 1e3);
            match (bvh_hit, brute) {
                (None, None) => {}
                (Some(h), Some((t, m, tri))) => {
                    hits += 1;
                    // f32 traversal: the distance agrees to a relative 1e-5.
                    assert!(
                        (h.t - t).abs() <= 1e-5 * t,
                        "ray {o} {d}: bvh t {} brute {t}",
                        h.t
                    );
                    // The hit test's f32 barycentrics put the point where the ray
                    // meets the triangle (weights of vertices 1 and 2, inside it).
                    let [a, b, c] = meshes[h.mesh].indices[h.triangle]
                        .map(|i| meshes[h.mesh].positions[i as usize]);
                    let p = a * (1.0 - h.b1 - h.b2) + b * h.b1 + c * h.b2;
                    assert!(h.b1 >= 0.0 && h.b2 >= 0.0 && h.b1 + h.b2 <= 1.0 + 1e-6);
                    assert!(
                        p.distance(o + d * t) <= 1e-5 * radius,
                        "ray {o} {d}: barycentric point {p} against {}",
                        o + d * t
                    );
                    if (h.mesh, h.triangle) != (m, tri) {
                        // A tie: two triangles (an edge or vertex) at the same distance.
                        let [a, b, c] = meshes[h.mesh].indices[h.triangle]
                            .map(|i| meshes[h.mesh].positions[i as usize]);
                        let n = (b - a).cross(c - a);
                        let t_plane = n.dot(a - o) / n.dot(d);
                        assert!(
                            (t_plane - t).abs() <= 1e-5 * t,
                            "ray {o} {d}: other triangle"
                        );
                        ties += 1;
                    }
                }
                (a, b) => {
                    // A miss on one side only can only be a ray grazing an edge.
                    let edge = a.map(|h| h.t).or(b.map(|b| b.0)).expect("one hit");
                    panic!("ray {o} {d}: bvh {a:?}, brute force {b:?} (t {edge})");
                }
            }
        }
        eprintln!("{hits} of {rays} rays hit, {ties} ties");
        assert!(ties < rays / 100, "{ties} ties");
        (rays, hits)
    }

    #[test]
    fn closest_hits_on_the_bunny_match_brute_force_before_and_after_a_refit() {
        let mut meshes = load_test_mesh("bunny_lowres.obj");
        let mut bvh = SceneBvh::build(&meshes);
        let (rays, hits) = check_against_brute_force(&meshes, &bvh, 1);
        assert!(hits > rays / 2, "{hits} of {rays} rays hit");
        // Move it: squash, shear and shift every vertex; same triangles, so a refit.
        for p in &mut meshes[0].positions {
            *p = DVec3::new(p.x + 0.3 * p.y, 0.7 * p.y + 0.5, p.z - 0.2);
        }
        assert!(bvh.update(&meshes), "same triangles refit");
        let (rays, hits) = check_against_brute_force(&meshes, &bvh, 2);
        assert!(hits > rays / 2, "{hits} of {rays} rays hit after the refit");
    }

    /// The CPU traversal (every kernel this CPU has) against obvhs's own on one ray:
    /// the same distance bit for bit and the same triangle, or another triangle at
    /// exactly that distance (an edge both share); the same occlusion answer.
    /// obvhs's traversal can miss a hit that its own triangle test finds: it culls
    /// boxes that end nearer than 1e-4 whatever tmin is, and a ray lying exactly in a
    /// box's face plane along a zero direction component is culled by a tight box
    /// (a leaf's) and not by a larger one. A nearer hit than obvhs's is accepted only
    /// where obvhs's triangle test gives that triangle the same distance, bit for bit;
    /// returns true for such a ray.
    fn same_as_reference(bvh: &SceneBvh, o: DVec3, d: DVec3, tmax: f64) -> bool {
        let reference = bvh.closest_hit_reference(o, d, 0.0, tmax);
        let occluded = bvh.occluded_reference(o, d, 0.0, tmax);
        let mut kernels = vec![Kernel::Portable];
        if Kernel::detect() == Kernel::Avx2 {
            kernels.push(Kernel::Avx2);
        }
        // obvhs's own triangle test on the triangle of a hit of ours.
        let obvhs_distance = |h: &Hit| {
            let tri = bvh
                .primitives()
                .find(|(_, at)| *at == (h.mesh as u32, h.triangle as u32))
                .expect("hit triangle is in the BVH")
                .0;
            tri.intersect(&BvhRay::new(v3a(o), v3a(d), 0.0, tmax as f32))
        };
        if let Some(r) = reference {
            assert_eq!(
                obvhs_distance(&r).to_bits(),
                (r.t as f32).to_bits(),
                "{r:?}"
            );
        }
        let mut near_extra = false;
        for kernel in kernels {
            let hit = bvh.closest_hit_with(kernel, o, d, 0.0, tmax);
            match (hit, reference) {
                (None, None) => {}
                (Some(h), Some(r)) if h.t.to_bits() == r.t.to_bits() => {
                    if (h.mesh, h.triangle) != (r.mesh, r.triangle) {
                        assert_eq!(obvhs_distance(&h).to_bits(), (r.t as f32).to_bits());
                    }
                }
                (Some(h), r) if r.is_none_or(|r| r.t > h.t) => {
                    assert_eq!(
                        obvhs_distance(&h).to_bits(),
                        (h.t as f32).to_bits(),
                        "{kernel:?} ray {o} {d} tmax {tmax}: {h:?} is not a hit, obvhs {r:?}"
                    );
                    near_extra = true;
                }
                (h, r) => panic!("{kernel:?} ray {o} {d} tmax {tmax}: {h:?}, obvhs {r:?}"),
            }
            let blocked = bvh.occluded_with(kernel, o, d, 0.0, tmax);
            assert!(
                blocked == occluded || (near_extra && blocked),
                "{kernel:?} ray {o} {d} tmax {tmax}: occluded {blocked}, obvhs {occluded}"
            );
        }
        near_extra
    }

    /// Rays from around the mesh at its box and, like the renderer's secondary rays,
    /// from its surface over the face's hemisphere, some of them as short segments.
    fn check_against_obvhs(meshes: &[TriangleMesh], bvh: &SceneBvh, seed: u64, rays: usize) {
        let mesh = &meshes[0];
        let (lo, hi) = mesh.positions.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let (centre, radius) = ((lo + hi) * 0.5, (hi - lo).length());
        let mut rng = meso_materials::rng::SampleStream::new(&[seed]);
        let (mut hits, mut near_extra) = (0, 0);
        for i in 0..rays {
            let (o, d, tmax) = if i % 2 == 0 {
                let z = 2.0 * rng.next() - 1.0;
                let phi = std::f64::consts::TAU * rng.next();
                let r = (1.0 - z * z).sqrt();
                let o = centre + radius * DVec3::new(r * phi.cos(), r * phi.sin(), z);
                let target = lo + (hi - lo) * DVec3::new(rng.next(), rng.next(), rng.next());
                (o, (target - o).normalize(), f64::INFINITY)
            } else {
                let tri =
                    ((rng.next() * mesh.indices.len() as f64) as usize).min(mesh.indices.len() - 1);
                let [a, b, c] = mesh.indices[tri].map(|i| mesh.positions[i as usize]);
                let n = (b - a).cross(c - a);
                if n.length_squared() == 0.0 {
                    continue;
                }
                let n = n.normalize();
                let (u, v) = (rng.next(), rng.next());
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                let p = a + (b - a) * u + (c - a) * v + n * (1e-4 * radius);
                let w = DVec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5);
                let w = (w - n * w.dot(n) + n * rng.next()).normalize_or(n);
                let tmax = if i % 4 == 1 {
                    radius * rng.next()
                } else {
                    f64::INFINITY
                };
                (p, w, tmax)
            };
            near_extra += usize::from(same_as_reference(bvh, o, d, tmax));
            hits += usize::from(bvh.closest_hit(o, d, 0.0, tmax).is_some());
        }
        eprintln!("{hits} of {rays} rays hit; {near_extra} hits nearer than 1e-4 obvhs culls");
        assert!(hits > rays / 5 && hits < rays, "{hits} of {rays}");
        assert!(near_extra < rays / 1000 + 1, "{near_extra}");
    }

    /// A mesh of tests/scenes/meshes as its file has it.
    pub(super) fn load_test_mesh(name: &str) -> Vec<TriangleMesh> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/scenes/meshes")
            .join(name);
        let identity = crate::scene::mesh::Placement {
            scale: 1.0,
            rotation: glam::DMat3::IDENTITY,
            translate: DVec3::ZERO,
        };
        vec![crate::scene::mesh::load_obj(&path, &identity, 0).expect("mesh")]
    }

    #[test]
    fn cpu_traversal_finds_obvhs_hits_on_the_bunny_the_dragon_and_after_a_refit() {
        let mut bunny = load_test_mesh("bunny_lowres.obj");
        let mut bvh = SceneBvh::build(&bunny);
        check_against_obvhs(&bunny, &bvh, 3, 20_000);
        for p in &mut bunny[0].positions {
            *p = DVec3::new(p.x + 0.3 * p.y, 0.7 * p.y + 0.5, p.z - 0.2);
        }
        assert!(bvh.update(&bunny));
        check_against_obvhs(&bunny, &bvh, 4, 20_000);
        let dragon = load_test_mesh("dragon.obj");
        check_against_obvhs(&dragon, &SceneBvh::build(&dragon), 5, 20_000);
    }

    #[test]
    fn axis_parallel_rays_and_rays_through_shared_edges_match_obvhs() {
        // Directions with zero components (the slab test's 1 / 0) and rays aimed
        // exactly at the quads' shared diagonal and at their corners.
        let meshes = floor_and_wall();
        let bvh = SceneBvh::build(&meshes);
        for o in [
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(-1.0, 1.0, 1.0),
            DVec3::new(1.0, 0.5, 0.5),
            DVec3::new(0.25, 1.0, -0.25),
        ] {
            for d in [
                DVec3::NEG_Y,
                DVec3::NEG_Z,
                DVec3::X,
                DVec3::NEG_X,
                DVec3::new(0.0, -1.0, -1.0).normalize(),
            ] {
                same_as_reference(&bvh, o, d, f64::INFINITY);
                same_as_reference(&bvh, o, d, 0.5);
            }
        }
        // Straight down onto a point of the floor's diagonal (a tie between its halves).
        let h = bvh
            .closest_hit(DVec3::new(0.0, 1.0, 0.0), DVec3::NEG_Y, 0.0, 9.0)
            .expect("the floor");
        assert_eq!((h.mesh, h.t), (0, 1.0));
    }
}
