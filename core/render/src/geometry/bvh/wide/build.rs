//! Building the wide tree from obvhs's binary BVH, in named stages: the visiting
//! order, the cost-optimal programme that decides where wide nodes and leaves go, and
//! the read-back that lays the nodes and leaves out depth-first. And the refit, which
//! keeps the tree's shape and recomputes its boxes.

use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

use super::triangle::write_leaf;
use super::{
    EMPTY, Kernel, LEAF, LEAF_PAD, LEAF_ROWS, LEAF_START_BITS, LEAF_START_MASK, MAX_LEAF,
    TRIANGLE_COST, WideBvh, lane_box, leaf_range, node_empty, set_lane_box,
};

/// The programme's decision for one binary node and slot budget: one leaf, one wide
/// node whose children are the binary children's (spread over the two budgets given),
/// or the binary children themselves spread over the two budgets given.
#[derive(Clone, Copy)]
enum Kind {
    Leaf,
    Internal(u8, u8),
    Split(u8, u8),
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
    pub(in crate::geometry::bvh) fn new(
        b: &Bvh2,
        triangles: &[Triangle],
        owners: &[(u32, u32)],
    ) -> Self {
        let n = b.nodes.len();
        assert!(
            triangles.len() < LEAF_START_MASK as usize && n < LEAF as usize,
            "{} triangles: more than the wide BVH addresses",
            triangles.len()
        );
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
        let kind = programme(b);
        out.lay_out(b, triangles, owners, &kind);
        out
    }

    /// Reads the wide tree back from the programme's decisions, from the root down:
    /// each wide node's children are laid out after it (what `refit` relies on), each
    /// leaf's triangles in the order a depth-first walk meets them. Sets how deep a
    /// traversal's stack can grow.
    fn lay_out(
        &mut self,
        b: &Bvh2,
        triangles: &[Triangle],
        owners: &[(u32, u32)],
        kind: &[[Kind; 8]],
    ) {
        self.nodes.push(node_empty());
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
                    let [l, r] = kids(b, x);
                    gather(l, a as usize, kind, b, &mut open);
                    gather(r, c as usize, kind, b, &mut open);
                }
                _ => open.push((x, true)),
            }
            let mut node = node_empty();
            for (lane, &(c, is_leaf)) in open.iter().enumerate() {
                set_lane_box(&mut node, lane, b.nodes[c].aabb());
                if is_leaf {
                    node.child[lane] = self.push_leaf(b, c, triangles, owners, &mut pending);
                } else {
                    let w = self.nodes.len();
                    self.nodes.push(node_empty());
                    node.child[lane] = w as u32;
                    todo.push((c, w, d + 1));
                }
            }
            self.nodes[slot] = node;
        }
        self.leaves.resize(self.leaves.len() + LEAF_PAD, 0.0);
        self.stack_need = 7 * depth + 1;
    }

    /// Appends the triangles under binary node `c` as one leaf (left subtree first)
    /// and returns the leaf's child reference. `pending` is scratch space, reused
    /// from leaf to leaf.
    fn push_leaf(
        &mut self,
        b: &Bvh2,
        c: usize,
        triangles: &[Triangle],
        owners: &[(u32, u32)],
        pending: &mut Vec<usize>,
    ) -> u32 {
        let start = self.sources.len();
        pending.clear();
        pending.push(c);
        while let Some(y) = pending.pop() {
            if b.nodes[y].is_leaf() {
                let f = b.nodes[y].first_index as usize;
                for p in f..f + b.nodes[y].prim_count as usize {
                    let source = b.primitive_indices[p];
                    self.owners.push(owners[source as usize]);
                    self.sources.push(source);
                }
            } else {
                let [l, r] = kids(b, y);
                pending.push(r);
                pending.push(l);
            }
        }
        let cnt = self.sources.len() - start;
        // Binary leaves hold one triangle (PLOC without collapsing), so a
        // leaf's count is the programme's, at most MAX_LEAF.
        assert!(cnt <= MAX_LEAF, "a leaf of {cnt} triangles");
        self.leaves.resize(LEAF_ROWS * self.sources.len(), 0.0);
        write_leaf(&mut self.leaves, start, &self.sources[start..], triangles);
        LEAF | ((cnt as u32) << LEAF_START_BITS) | start as u32
    }

    /// Follows triangles that moved: `triangles` is the list the tree was built from,
    /// same length and order, with new vertices. The tree keeps its shape; every box
    /// becomes the exact bound of what it holds again, bottom-up (a node's children
    /// come after it in `nodes`). Linear in the tree's size, without the programme.
    pub(in crate::geometry::bvh) fn refit(&mut self, triangles: &[Triangle]) {
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
}

/// Binary node `i`'s two children (obvhs keeps siblings side by side).
fn kids(b: &Bvh2, i: usize) -> [usize; 2] {
    let f = b.nodes[i].first_index as usize;
    [f, f + 1]
}

/// Every binary node, each before its children: the programme visits them in
/// reverse, children first.
fn top_down_order(b: &Bvh2) -> Vec<usize> {
    let mut order = Vec::with_capacity(b.nodes.len());
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        order.push(i);
        if !b.nodes[i].is_leaf() {
            stack.extend(kids(b, i));
        }
    }
    order
}

/// The cost-optimal programme (see `WideBvh::new`): per binary node x and slot budget
/// i + 1, the cheapest way to spread x's subtree over that many wide children.
fn programme(b: &Bvh2) -> Vec<[Kind; 8]> {
    let n = b.nodes.len();
    let order = top_down_order(b);
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
        let [l, r] = kids(b, x);
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
    kind
}

/// The wide children that binary node x makes when spread over at most i + 1
/// slots: (binary node, whether it is one leaf).
fn gather(x: usize, i: usize, kind: &[[Kind; 8]], b: &Bvh2, out: &mut Vec<(usize, bool)>) {
    match kind[x][i] {
        Kind::Leaf => out.push((x, true)),
        Kind::Internal(..) => out.push((x, false)),
        Kind::Split(a, c) => {
            let [l, r] = kids(b, x);
            gather(l, a as usize, kind, b, out);
            gather(r, c as usize, kind, b, out);
        }
    }
}
