//! The CPU traversal of the scene's BVH. obvhs's compressed wide BVH (CWBVH) is laid
//! out for GPUs: 8-bit child boxes relative to a per-node grid, decoded for every
//! ray, leaves of at most 3 triangles, and one scalar intersection callback per
//! primitive through an index table. Here obvhs's binary BVH (the one the CWBVH is
//! made from) is collapsed into 8-wide nodes by the same cost-optimal programme with
//! this traversal's costs and leaves of up to `MAX_LEAF` triangles, which halves the
//! nodes (docs/performance.md); the children's f32 boxes lie in structure-of-arrays
//! order, so one AVX2 instruction tests a slab of all 8 children, and each leaf's
//! triangles (edges precomputed) lie in structure-of-arrays order too, so one AVX2
//! instruction per term tests the whole leaf. A refit keeps the tree's shape and
//! recomputes its boxes. Traversal is ordered (nearest child first, farther ones
//! stacked with their entry distance and skipped once a closer hit is known);
//! occlusion stops at the first hit.
//!
//! The triangle test, scalar or 8-wide, performs obvhs's Moller-Trumbore arithmetic
//! operation for operation (same operands, same order, no fused multiply-add), so a
//! hit's distance is bit for bit the one obvhs finds, and the box test is conservative
//! (Ize 2013: far distances widened by 1 + 2 gamma_3), so no triangle obvhs would hit
//! is culled.
//!
//! Here: the layout (nodes, leaf references, the ray query) and the box helpers both
//! stages share; `build.rs` collapses the binary tree and refits it, `traverse.rs`
//! answers closest-hit and occlusion queries, `triangle.rs` holds the leaves' triangle
//! layout and intersection test.

mod build;
#[cfg(test)]
mod tests;
mod traverse;
mod triangle;

use glam::Vec3A;
use obvhs::aabb::Aabb;

pub(super) use triangle::barycentrics;

/// Most triangles in one leaf (a leaf's count has 4 bits). Leaves larger than the
/// CWBVH's 3 halve the node count; measured against Embree (docs/performance.md).
const MAX_LEAF: usize = 8;
/// A triangle test's cost relative to a node test in the collapse's cost model
/// (obvhs's CWBVH conversion uses 0.3 for a GPU). A leaf's triangles are tested 8 at
/// a time, so a triangle costs little; chosen by measuring 0.05-0.15
/// (docs/performance.md).
const TRIANGLE_COST: f32 = 0.07;

/// A child reference: a node index, or (`LEAF` set) a leaf's first triangle slot in
/// the low 27 bits and its triangle count (1 to 15) in bits 27-30.
const LEAF: u32 = 1 << 31;
const LEAF_START_BITS: u32 = 27;
const LEAF_START_MASK: u32 = (1 << LEAF_START_BITS) - 1;
/// An unused child slot: its box is empty, so it is never entered.
const EMPTY: u32 = u32::MAX;

/// Eight children: their boxes as rows lo x, hi x, lo y, hi y, lo z, hi z of 8 lanes.
/// 224 bytes, aligned to cache lines (padded to 256) so a node spans 4 lines, not 5.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Node {
    planes: [[f32; 8]; 6],
    child: [u32; 8],
}

// The traversal's prefetch asks for a node's four lines and for a leaf's lines up to
// 320 bytes: both hold only while a node is 256 bytes and a leaf at most 320.
const _: () = assert!(size_of::<Node>() == 256);
const _: () = assert!(MAX_LEAF * LEAF_ROWS * size_of::<f32>() <= 320);

/// Floats per triangle in a leaf: v0, e1, e2 (x, y, z each).
const LEAF_ROWS: usize = 9;
/// Floats after the last leaf: an 8-lane load of a leaf's last row reads up to 7
/// floats past it.
const LEAF_PAD: usize = 7;

/// What a closest-hit traversal found: the primitive slot, the distance and the hit
/// test's barycentric weights of vertices 1 and 2.
#[derive(Clone, Copy, Debug)]
pub(super) struct Found {
    pub slot: u32,
    pub t: f32,
    pub u: f32,
    pub v: f32,
}

/// A ray as the traversal reads it.
#[derive(Clone, Copy)]
pub(super) struct Query {
    o: [f32; 3],
    d: [f32; 3],
    /// 1 / d, with components under 1e-30 in magnitude replaced by +-1e-30 first so
    /// that no slab product is 0 x infinity.
    inv: [f32; 3],
    /// Per axis, 1 when the direction is negative: the near plane is then the box's
    /// high side (row 2 axis + 1), else its low side.
    neg: [usize; 3],
    tmin: f32,
    tmax: f32,
}

impl Query {
    pub(super) fn new(o: [f32; 3], d: [f32; 3], tmin: f32, tmax: f32) -> Self {
        let safe = |x: f32| {
            if x.abs() < 1e-30 {
                1.0 / 1e-30f32.copysign(x)
            } else {
                1.0 / x
            }
        };
        let inv = d.map(safe);
        Self {
            o,
            d,
            inv,
            neg: inv.map(|i| usize::from(i < 0.0)),
            tmin,
            tmax,
        }
    }
}

/// Which node test a traversal uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// AVX2: 8 children per slab instruction (x86-64 CPUs that have it).
    Avx2,
    /// Plain Rust over the 8 lanes (any CPU; what the compiler vectorises itself).
    Portable,
}

impl Kernel {
    /// The fastest this CPU runs.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self::Avx2;
        }
        Self::Portable
    }
}

/// The 8-wide tree the CPU traverses: nodes, the leaves' triangles, and per triangle
/// slot its owner in the scene and its source in the build's list.
pub(super) struct WideBvh {
    nodes: Vec<Node>,
    /// The leaves' triangles: a leaf of `count` triangles from slot `start` is the
    /// floats from `LEAF_ROWS * start`, in structure-of-arrays order (`LEAF_ROWS`
    /// rows of `count`: v0 x, y, z, e1 x, y, z, e2 x, y, z), so one 8-lane load reads
    /// a row of the whole leaf. `LEAF_PAD` floats follow the last leaf.
    leaves: Vec<f32>,
    /// Per slot, the scene's (mesh, triangle within the mesh): one lookup per hit
    /// instead of two.
    owners: Vec<(u32, u32)>,
    /// Per slot, the index of its triangle in the list the tree was built from: what
    /// a refit reads the moved triangles by.
    sources: Vec<u32>,
    /// Stack entries a traversal can need: 7 per level of the tree, plus one.
    stack_need: usize,
    kernel: Kernel,
}

impl WideBvh {
    /// The (mesh, triangle within the mesh) of primitive slot `slot`.
    #[inline]
    pub(super) fn owner(&self, slot: u32) -> (u32, u32) {
        self.owners[slot as usize]
    }
}

/// A node with no children: every slot empty, its box inverted so no ray enters it.
fn node_empty() -> Node {
    let mut planes = [[0.0; 8]; 6];
    for axis in 0..3 {
        planes[2 * axis] = [f32::INFINITY; 8];
        planes[2 * axis + 1] = [f32::NEG_INFINITY; 8];
    }
    Node {
        planes,
        child: [EMPTY; 8],
    }
}

/// Child `lane`'s box.
fn lane_box(node: &Node, lane: usize) -> Aabb {
    let side = |row: usize| Vec3A::from_array([0, 2, 4].map(|axis| node.planes[axis + row][lane]));
    Aabb::new(side(0), side(1))
}

/// Sets child `lane`'s box (what building and refitting write).
fn set_lane_box(node: &mut Node, lane: usize, bb: &Aabb) {
    for axis in 0..3 {
        node.planes[2 * axis][lane] = bb.min[axis];
        node.planes[2 * axis + 1][lane] = bb.max[axis];
    }
}

/// A leaf reference's (first triangle slot, triangle count).
fn leaf_range(child: u32) -> (usize, usize) {
    (
        (child & LEAF_START_MASK) as usize,
        ((child & !LEAF) >> LEAF_START_BITS) as usize,
    )
}
