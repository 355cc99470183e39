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

use std::mem::MaybeUninit;

use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

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

/// Most stack entries a traversal of any tree here can hold on the call stack; deeper
/// trees (never seen in practice: depth 36 would be needed) use a heap stack.
const INLINE_STACK: usize = 256;

/// 1 + 2 gamma_3 (gamma_n = n u / (1 - n u), u = 2^-24), rounded up: the factor that
/// makes the slab test's far distance an upper bound despite the rounding of the
/// subtraction, the product and the reciprocal (Ize, "Robust BVH ray traversal", 2013).
const ROBUST_FAR: f32 = 1.0 + 4.0 * f32::EPSILON;

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

/// A triangle as the intersection test reads it: obvhs's v0, e1 = v0 - v1 and
/// e2 = v2 - v0, computed once instead of per ray. Its normal e1 x e2 is not stored:
/// 36 bytes instead of 48 miss the caches less often than 6 products cost.
#[derive(Clone, Copy)]
struct LeafTriangle {
    v0: [f32; 3],
    e1: [f32; 3],
    e2: [f32; 3],
}

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

#[derive(Clone, Copy)]
struct Entry {
    child: u32,
    tnear: f32,
}

impl WideBvh {
    /// Collapses obvhs's binary BVH `b` (one triangle a leaf, indices into
    /// `triangles` and `owners`) into 8-wide nodes by the cost-optimal programme of
    /// Ylitie et al. 2017 (as obvhs's CWBVH conversion, with this traversal's costs):
    /// a node costs its half area, a leaf its half area x triangles x `TRIANGLE_COST`,
    /// and a leaf holds up to `MAX_LEAF` triangles. Per binary node and slot budget i
    /// (1 to 8) the programme keeps the cheapest of: one leaf, one wide node whose
    /// children are the binary children spread over 8 slots, or the binary children
    /// spread over i slots; the wide tree is read back from those decisions.
    pub(super) fn new(b: &Bvh2, triangles: &[Triangle], owners: &[(u32, u32)]) -> Self {
        #[derive(Clone, Copy)]
        enum Kind {
            Leaf,
            Internal(u8, u8),
            Split(u8, u8),
        }
        let n = b.nodes.len();
        assert!(
            triangles.len() < LEAF_START_MASK as usize && n < LEAF as usize,
            "{} triangles: more than the wide BVH addresses",
            triangles.len()
        );
        let kids = |i: usize| {
            let f = b.nodes[i].first_index as usize;
            [f, f + 1]
        };
        let mut out = Self {
            nodes: Vec::new(),
            leaves: Vec::new(),
            owners: Vec::new(),
            sources: Vec::new(),
            stack_need: 1,
            kernel: Kernel::detect(),
        };
        if n == 0 {
            return out;
        }
        let mut order = Vec::with_capacity(n);
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            order.push(i);
            if !b.nodes[i].is_leaf() {
                stack.extend(kids(i));
            }
        }
        let mut count = vec![0usize; n];
        let mut cost = vec![[0f32; 8]; n];
        let mut kind = vec![[Kind::Leaf; 8]; n];
        for &x in order.iter().rev() {
            let area = b.nodes[x].aabb().half_area();
            if b.nodes[x].is_leaf() {
                count[x] = b.nodes[x].prim_count as usize;
                cost[x] = [area * count[x] as f32 * TRIANGLE_COST; 8];
                continue;
            }
            let [l, r] = kids(x);
            count[x] = count[l] + count[r];
            let leaf = if count[x] <= MAX_LEAF {
                area * count[x] as f32 * TRIANGLE_COST
            } else {
                f32::INFINITY
            };
            let (mut best, mut split) = (f32::INFINITY, (0u8, 0u8));
            for k in 0..7 {
                let c = cost[l][k] + cost[r][6 - k];
                if c < best {
                    best = c;
                    split = (k as u8, (6 - k) as u8);
                }
            }
            let internal = area + best;
            (cost[x][0], kind[x][0]) = if leaf <= internal {
                (leaf, Kind::Leaf)
            } else {
                (internal, Kind::Internal(split.0, split.1))
            };
            for i in 1..8 {
                (cost[x][i], kind[x][i]) = (cost[x][i - 1], kind[x][i - 1]);
                for k in 0..i {
                    let c = cost[l][k] + cost[r][i - 1 - k];
                    if c < cost[x][i] {
                        cost[x][i] = c;
                        kind[x][i] = Kind::Split(k as u8, (i - 1 - k) as u8);
                    }
                }
            }
        }
        // The wide children that binary node x makes when spread over at most i + 1
        // slots: (binary node, whether it is one leaf).
        fn gather(
            x: usize,
            i: usize,
            kind: &[[Kind; 8]],
            kids: &dyn Fn(usize) -> [usize; 2],
            out: &mut Vec<(usize, bool)>,
        ) {
            match kind[x][i] {
                Kind::Leaf => out.push((x, true)),
                Kind::Internal(..) => out.push((x, false)),
                Kind::Split(a, c) => {
                    let [l, r] = kids(x);
                    gather(l, a as usize, kind, kids, out);
                    gather(r, c as usize, kind, kids, out);
                }
            }
        }
        out.nodes.push(node_empty());
        let mut todo = vec![(0usize, 0usize, 1usize)];
        let mut depth = 1;
        // Reused for every node and leaf: a refit runs this whole construction again.
        let mut open = Vec::with_capacity(8);
        let mut pending = Vec::new();
        while let Some((x, slot, d)) = todo.pop() {
            depth = depth.max(d);
            open.clear();
            match kind[x][0] {
                Kind::Internal(a, c) => {
                    let [l, r] = kids(x);
                    gather(l, a as usize, &kind, &kids, &mut open);
                    gather(r, c as usize, &kind, &kids, &mut open);
                }
                _ => open.push((x, true)),
            }
            let mut node = node_empty();
            for (lane, &(c, is_leaf)) in open.iter().enumerate() {
                set_lane_box(&mut node, lane, b.nodes[c].aabb());
                if is_leaf {
                    let start = out.sources.len();
                    pending.clear();
                    pending.push(c);
                    while let Some(y) = pending.pop() {
                        if b.nodes[y].is_leaf() {
                            let f = b.nodes[y].first_index as usize;
                            for p in f..f + b.nodes[y].prim_count as usize {
                                let source = b.primitive_indices[p];
                                out.owners.push(owners[source as usize]);
                                out.sources.push(source);
                            }
                        } else {
                            let [l, r] = kids(y);
                            pending.push(r);
                            pending.push(l);
                        }
                    }
                    let cnt = out.sources.len() - start;
                    // Binary leaves hold one triangle (PLOC without collapsing), so a
                    // leaf's count is the programme's, at most MAX_LEAF.
                    assert!(cnt <= MAX_LEAF, "a leaf of {cnt} triangles");
                    out.leaves.resize(LEAF_ROWS * out.sources.len(), 0.0);
                    write_leaf(&mut out.leaves, start, &out.sources[start..], triangles);
                    node.child[lane] = LEAF | ((cnt as u32) << LEAF_START_BITS) | start as u32;
                } else {
                    let w = out.nodes.len();
                    out.nodes.push(node_empty());
                    node.child[lane] = w as u32;
                    todo.push((c, w, d + 1));
                }
            }
            out.nodes[slot] = node;
        }
        out.leaves.resize(out.leaves.len() + LEAF_PAD, 0.0);
        out.stack_need = 7 * depth + 1;
        out
    }

    /// Follows triangles that moved: `triangles` is the list the tree was built from,
    /// same length and order, with new vertices. The tree keeps its shape; every box
    /// becomes the exact bound of what it holds again, bottom-up (a node's children
    /// come after it in `nodes`). Linear in the tree's size, without the programme.
    pub(super) fn refit(&mut self, triangles: &[Triangle]) {
        for n in (0..self.nodes.len()).rev() {
            for lane in 0..8 {
                let child = self.nodes[n].child[lane];
                if child == EMPTY {
                    continue;
                }
                let bb = if child & LEAF != 0 {
                    let (start, count) = leaf_range(child);
                    let sources = &self.sources[start..start + count];
                    write_leaf(&mut self.leaves, start, sources, triangles);
                    sources.iter().fold(Aabb::empty(), |bb, &source| {
                        bb.union(&triangles[source as usize].aabb())
                    })
                } else {
                    // Empty lanes hold an empty box, which leaves the union as it is.
                    debug_assert!(child as usize > n, "a child laid out before its node");
                    let node = &self.nodes[child as usize];
                    (0..8).fold(Aabb::empty(), |bb, l| bb.union(&lane_box(node, l)))
                };
                set_lane_box(&mut self.nodes[n], lane, &bb);
            }
        }
    }

    /// The (mesh, triangle within the mesh) of primitive slot `slot`.
    #[inline]
    pub(super) fn owner(&self, slot: u32) -> (u32, u32) {
        self.owners[slot as usize]
    }

    /// The closest hit within the query's (tmin, tmax): (primitive slot, distance).
    #[inline]
    pub(super) fn closest(&self, q: &Query) -> Option<Found> {
        self.closest_with(self.kernel, q)
    }

    /// Whether any triangle lies within the query's (tmin, tmax).
    #[inline]
    pub(super) fn occluded(&self, q: &Query) -> bool {
        self.occluded_with(self.kernel, q)
    }

    pub(super) fn closest_with(&self, kernel: Kernel, q: &Query) -> Option<Found> {
        if self.nodes.is_empty() {
            return None;
        }
        self.with_stack(|stack| match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernel::Avx2` is only chosen where the CPU reports AVX2
            // (`Kernel::detect`, or a test that checks the same first).
            Kernel::Avx2 => unsafe { self.closest_avx2(q, stack) },
            _ => self.traverse::<false, false>(q, stack),
        })
    }

    pub(super) fn occluded_with(&self, kernel: Kernel, q: &Query) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        self.with_stack(|stack| match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `closest_with`.
            Kernel::Avx2 => unsafe { self.occluded_avx2(q, stack) },
            _ => self.traverse::<false, true>(q, stack),
        })
        .is_some()
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn closest_avx2(&self, q: &Query, stack: &mut [MaybeUninit<Entry>]) -> Option<Found> {
        self.traverse::<true, false>(q, stack)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn occluded_avx2(&self, q: &Query, stack: &mut [MaybeUninit<Entry>]) -> Option<Found> {
        self.traverse::<true, true>(q, stack)
    }

    fn with_stack<R>(&self, f: impl FnOnce(&mut [MaybeUninit<Entry>]) -> R) -> R {
        if self.stack_need <= INLINE_STACK {
            // Left uninitialised: clearing 2 KiB per ray would cost as much as a
            // few node tests, and only entries written are read back.
            let mut stack = [const { MaybeUninit::uninit() }; INLINE_STACK];
            f(&mut stack)
        } else {
            f(&mut vec![MaybeUninit::uninit(); self.stack_need])
        }
    }

    /// Asks for a child's node or triangles ahead of use: several children's cache
    /// misses then overlap instead of each waiting in turn when its entry is popped.
    #[inline(always)]
    fn prefetch(&self, child: u32) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            // SAFETY (all prefetches): a prefetch never faults and changes nothing but
            // the caches, whatever the address.
            if child & LEAF != 0 {
                // At most 8 x 36 bytes: the lines of the first byte, of every 64th
                // after it within the leaf, and of the last.
                let (start, count) = leaf_range(child);
                let first = self.leaves[LEAF_ROWS * start..].as_ptr().cast::<i8>();
                let bytes = count * LEAF_ROWS * size_of::<f32>();
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(first);
                    _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(64));
                    if bytes > 128 {
                        _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(128));
                        _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(192));
                    }
                    if bytes > 256 {
                        _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(256));
                    }
                    _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(bytes - 1));
                }
            } else {
                // A node is four whole lines (`Node` is 64-byte aligned).
                let n = std::ptr::from_ref(&self.nodes[child as usize]).cast::<i8>();
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(n);
                    _mm_prefetch::<_MM_HINT_T0>(n.wrapping_add(64));
                    _mm_prefetch::<_MM_HINT_T0>(n.wrapping_add(128));
                    _mm_prefetch::<_MM_HINT_T0>(n.wrapping_add(192));
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = child;
    }

    /// The traversal both queries share. `ANY`: stop at the first hit (occlusion),
    /// unordered; else the closest hit, nearest child first. `AVX2` only from a
    /// function compiled with AVX2 enabled.
    #[inline(always)]
    fn traverse<const AVX2: bool, const ANY: bool>(
        &self,
        q: &Query,
        stack: &mut [MaybeUninit<Entry>],
    ) -> Option<Found> {
        let mut best: Option<Found> = None;
        let mut tmax = q.tmax;
        let mut len = 0;
        let mut current = 0u32;
        let mut tnear = [0.0f32; 8];
        loop {
            if current & LEAF == 0 {
                let node = &self.nodes[current as usize];
                let mask = if AVX2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 is only set by the AVX2-enabled entry points.
                    unsafe {
                        node_hits_avx2(node, q, tmax, &mut tnear)
                    }
                    #[cfg(not(target_arch = "x86_64"))]
                    unreachable!()
                } else {
                    node_hits_portable(node, q, tmax, &mut tnear)
                };
                if mask != 0 {
                    if mask & (mask - 1) == 0 {
                        current = node.child[mask.trailing_zeros() as usize];
                        continue;
                    }
                    // Several children: the nearest is visited now, the others stacked
                    // farthest first so the next nearest is popped next.
                    let mut refs = [0u32; 8];
                    let mut dist = [0f32; 8];
                    let mut k = 0;
                    let mut m = mask;
                    while m != 0 {
                        let i = m.trailing_zeros() as usize;
                        m &= m - 1;
                        let (r, d) = (node.child[i], tnear[i]);
                        self.prefetch(r);
                        let mut j = k;
                        if !ANY {
                            while j > 0 && dist[j - 1] < d {
                                refs[j] = refs[j - 1];
                                dist[j] = dist[j - 1];
                                j -= 1;
                            }
                        }
                        refs[j] = r;
                        dist[j] = d;
                        k += 1;
                    }
                    for j in 0..k - 1 {
                        stack[len] = MaybeUninit::new(Entry {
                            child: refs[j],
                            tnear: dist[j],
                        });
                        len += 1;
                    }
                    current = refs[k - 1];
                    continue;
                }
            } else {
                let (start, count) = leaf_range(current);
                let rows = &self.leaves[LEAF_ROWS * start..];
                // What the 8-lane loads of the last row read (`LEAF_PAD`).
                debug_assert!(rows.len() >= (LEAF_ROWS - 1) * count + 8);
                if AVX2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 is only set by the AVX2-enabled entry points; the
                    // leaf's rows and `LEAF_PAD` after the last leaf cover every load.
                    unsafe {
                        let (mask, t, u, v) = leaf_hits_avx2(rows.as_ptr(), count, q, tmax);
                        if mask != 0 {
                            // The nearest (for occlusion, the first that hits); the
                            // first of equals, as the scalar loop.
                            let mut m = if ANY {
                                mask & mask.wrapping_neg()
                            } else {
                                mask
                            };
                            while m != 0 {
                                let i = m.trailing_zeros() as usize;
                                m &= m - 1;
                                if t[i] < tmax {
                                    tmax = t[i];
                                    best = Some(Found {
                                        slot: (start + i) as u32,
                                        t: t[i],
                                        u: u[i],
                                        v: v[i],
                                    });
                                }
                            }
                            if ANY {
                                return best;
                            }
                        }
                    }
                } else {
                    for lane in 0..count {
                        let (t, u, v) = intersect(&leaf_lane(rows, count, lane), q, tmax);
                        if t < tmax {
                            best = Some(Found {
                                slot: (start + lane) as u32,
                                t,
                                u,
                                v,
                            });
                            if ANY {
                                return best;
                            }
                            tmax = t;
                        }
                    }
                }
            }
            // Next: the nearest stacked child not beyond the closest hit so far.
            loop {
                if len == 0 {
                    return best;
                }
                len -= 1;
                // SAFETY: entries below `len` were all written by the push above.
                let e = unsafe { stack[len].assume_init() };
                if e.tnear <= tmax * ROBUST_FAR {
                    current = e.child;
                    break;
                }
            }
        }
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

/// The barycentric weights of `t`'s vertices 1 and 2 where the query's ray meets its
/// plane, by the traversal's own arithmetic.
pub(super) fn barycentrics(t: &Triangle, q: &Query) -> (f32, f32) {
    let (u, v, ..) = solve(&leaf_triangle(t), q);
    (u, v)
}

/// Writes the triangles `sources` of `triangles` as the leaf from slot `start`.
fn write_leaf(leaves: &mut [f32], start: usize, sources: &[u32], triangles: &[Triangle]) {
    let count = sources.len();
    let leaf = &mut leaves[LEAF_ROWS * start..LEAF_ROWS * (start + count)];
    for (lane, &source) in sources.iter().enumerate() {
        let t = leaf_triangle(&triangles[source as usize]);
        for (row, value) in t.v0.into_iter().chain(t.e1).chain(t.e2).enumerate() {
            leaf[row * count + lane] = value;
        }
    }
}

/// Triangle `lane` of the leaf of `count` triangles whose rows start `rows`.
#[inline(always)]
fn leaf_lane(rows: &[f32], count: usize, lane: usize) -> LeafTriangle {
    let at = |row: usize| rows[row * count + lane];
    LeafTriangle {
        v0: [at(0), at(1), at(2)],
        e1: [at(3), at(4), at(5)],
        e2: [at(6), at(7), at(8)],
    }
}

fn leaf_triangle(t: &Triangle) -> LeafTriangle {
    LeafTriangle {
        v0: t.v0.to_array(),
        e1: (t.v0 - t.v1).to_array(),
        e2: (t.v2 - t.v0).to_array(),
    }
}

/// Child `lane`'s box.
fn lane_box(node: &Node, lane: usize) -> Aabb {
    let side = |row: usize| Vec3A::from_array([0, 2, 4].map(|axis| node.planes[axis + row][lane]));
    Aabb::new(side(0), side(1))
}

fn set_lane_box(node: &mut Node, lane: usize, bb: &Aabb) {
    for axis in 0..3 {
        node.planes[2 * axis][lane] = bb.min[axis];
        node.planes[2 * axis + 1][lane] = bb.max[axis];
    }
}

fn leaf_range(child: u32) -> (usize, usize) {
    (
        (child & LEAF_START_MASK) as usize,
        ((child & !LEAF) >> LEAF_START_BITS) as usize,
    )
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The Moller-Trumbore terms of obvhs's `Triangle::intersect` on precomputed edges:
/// the barycentric weights u (of v1) and v (of v2), 1 / det, and the normal and
/// origin offset whose dot product is the distance's numerator (left to the caller,
/// so a miss does not pay for it).
#[inline(always)]
fn solve(tri: &LeafTriangle, q: &Query) -> (f32, f32, f32, [f32; 3], [f32; 3]) {
    let (e1, e2) = (tri.e1, tri.e2);
    // Component by component as glam's cross product rounds it.
    let n = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let c = [tri.v0[0] - q.o[0], tri.v0[1] - q.o[1], tri.v0[2] - q.o[2]];
    let d = q.d;
    let r = [
        d[1] * c[2] - d[2] * c[1],
        d[2] * c[0] - d[0] * c[2],
        d[0] * c[1] - d[1] * c[0],
    ];
    let inv_det = 1.0 / dot(n, d);
    let u = dot(r, tri.e2) * inv_det;
    let v = dot(r, tri.e1) * inv_det;
    (u, v, inv_det, n, c)
}

/// obvhs's `Triangle::intersect` on precomputed edges: the distance (infinity when
/// the ray misses or the distance is outside [tmin, tmax]) and the weights u, v.
#[inline(always)]
fn intersect(tri: &LeafTriangle, q: &Query, tmax: f32) -> (f32, f32, f32) {
    let (u, v, inv_det, n, c) = solve(tri, q);
    let w = 1.0 - u - v;
    // A negative barycentric (including -0.0) misses, as in obvhs.
    let signs = u.to_bits() | v.to_bits() | w.to_bits();
    if inv_det != 0.0 && signs & 0x8000_0000 == 0 {
        let t = dot(n, c) * inv_det;
        if t >= q.tmin && t <= tmax {
            return (t, u, v);
        }
    }
    (f32::INFINITY, u, v)
}

/// `intersect` on every triangle of a leaf at once, operation for operation in the
/// same order (so every lane's distance is the scalar test's, bit for bit): the lanes
/// that hit within [tmin, tmax) as a bit mask (below `count`), and per lane the
/// distance and u, v. `rows` is the leaf's first float; each row is read with one
/// unaligned 8-lane load, lanes at and past `count` reading whatever follows.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn leaf_hits_avx2(
    rows: *const f32,
    count: usize,
    q: &Query,
    tmax: f32,
) -> (u32, [f32; 8], [f32; 8], [f32; 8]) {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees AVX2 and that 8 floats from every row start are
    // readable (the leaf's rows, then the next leaf's or the padding).
    unsafe {
        let row = |r: usize| _mm256_loadu_ps(rows.add(r * count));
        let (mul, sub, add) = (_mm256_mul_ps, _mm256_sub_ps, _mm256_add_ps);
        let (e1x, e1y, e1z) = (row(3), row(4), row(5));
        let (e2x, e2y, e2z) = (row(6), row(7), row(8));
        let nx = sub(mul(e1y, e2z), mul(e1z, e2y));
        let ny = sub(mul(e1z, e2x), mul(e1x, e2z));
        let nz = sub(mul(e1x, e2y), mul(e1y, e2x));
        let cx = sub(row(0), _mm256_set1_ps(q.o[0]));
        let cy = sub(row(1), _mm256_set1_ps(q.o[1]));
        let cz = sub(row(2), _mm256_set1_ps(q.o[2]));
        let [dx, dy, dz] = q.d.map(|x| _mm256_set1_ps(x));
        let rx = sub(mul(dy, cz), mul(dz, cy));
        let ry = sub(mul(dz, cx), mul(dx, cz));
        let rz = sub(mul(dx, cy), mul(dy, cx));
        let dot3 = |ax, ay, az, bx, by, bz| add(add(mul(ax, bx), mul(ay, by)), mul(az, bz));
        let one = _mm256_set1_ps(1.0);
        let inv_det = _mm256_div_ps(one, dot3(nx, ny, nz, dx, dy, dz));
        let u = mul(dot3(rx, ry, rz, e2x, e2y, e2z), inv_det);
        let v = mul(dot3(rx, ry, rz, e1x, e1y, e1z), inv_det);
        let w = sub(sub(one, u), v);
        let t = mul(dot3(nx, ny, nz, cx, cy, cz), inv_det);
        // Sign bits of u, v, w (a negative one, -0.0 included, misses); inv_det != 0
        // (true for NaN, as the scalar `!=`); tmin <= t < tmax.
        let negative = _mm256_movemask_ps(_mm256_or_ps(_mm256_or_ps(u, v), w)) as u32;
        let nonzero = _mm256_cmp_ps::<_CMP_NEQ_UQ>(inv_det, _mm256_setzero_ps());
        let within = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(t, _mm256_set1_ps(q.tmin)),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, _mm256_set1_ps(tmax)),
        );
        let mask = _mm256_movemask_ps(_mm256_and_ps(nonzero, within)) as u32
            & !negative
            & ((1u32 << count) - 1);
        let (mut ts, mut us, mut vs) = ([0f32; 8], [0f32; 8], [0f32; 8]);
        if mask != 0 {
            _mm256_storeu_ps(ts.as_mut_ptr(), t);
            _mm256_storeu_ps(us.as_mut_ptr(), u);
            _mm256_storeu_ps(vs.as_mut_ptr(), v);
        }
        (mask, ts, us, vs)
    }
}

/// Which of the node's children the ray enters within [tmin, tmax] (bit per child),
/// and each child's entry distance in `tnear`.
#[inline(always)]
fn node_hits_portable(node: &Node, q: &Query, tmax: f32, tnear: &mut [f32; 8]) -> u32 {
    let mut mask = 0;
    for (lane, entry) in tnear.iter_mut().enumerate() {
        let (mut near, mut far) = (q.tmin, tmax);
        for axis in 0..3 {
            let lo = node.planes[2 * axis + q.neg[axis]][lane];
            let hi = node.planes[2 * axis + 1 - q.neg[axis]][lane];
            near = near.max((lo - q.o[axis]) * q.inv[axis]);
            far = far.min((hi - q.o[axis]) * q.inv[axis]);
        }
        *entry = near;
        mask |= u32::from(near <= far * ROBUST_FAR) << lane;
    }
    mask
}

/// `node_hits_portable` with one AVX2 instruction per slab and lane-wise operation.
/// Only called from functions compiled with AVX2 enabled, into which it is inlined
/// (a `target_feature` function of its own would not be, and a call per node costs).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn node_hits_avx2(node: &Node, q: &Query, tmax: f32, tnear: &mut [f32; 8]) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: rows are 32-byte aligned (`Node` is align(64) and each row 32 bytes);
    // `neg` is 0 or 1, so every row index is below 6.
    unsafe {
        let row = |r: usize| _mm256_load_ps(node.planes[r].as_ptr());
        let slab = |axis: usize, r: usize| {
            _mm256_mul_ps(
                _mm256_sub_ps(row(r), _mm256_set1_ps(q.o[axis])),
                _mm256_set1_ps(q.inv[axis]),
            )
        };
        let near_x = slab(0, q.neg[0]);
        let near_y = slab(1, 2 + q.neg[1]);
        let near_z = slab(2, 4 + q.neg[2]);
        let far_x = slab(0, 1 - q.neg[0]);
        let far_y = slab(1, 3 - q.neg[1]);
        let far_z = slab(2, 5 - q.neg[2]);
        // The slab first: where it were NaN (finite rays give none) maxps/minps return
        // the second operand, the running bound, as f32::max/min do in the portable test.
        let near = _mm256_max_ps(
            near_z,
            _mm256_max_ps(near_y, _mm256_max_ps(near_x, _mm256_set1_ps(q.tmin))),
        );
        let far = _mm256_min_ps(
            far_z,
            _mm256_min_ps(far_y, _mm256_min_ps(far_x, _mm256_set1_ps(tmax))),
        );
        let far = _mm256_mul_ps(far, _mm256_set1_ps(ROBUST_FAR));
        _mm256_storeu_ps(tnear.as_mut_ptr(), near);
        _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far)) as u32
    }
}

#[cfg(test)]
mod tests {
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
}
