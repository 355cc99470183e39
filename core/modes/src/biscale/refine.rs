//! Where transfer is sampled: the scene's triangles subdivided adaptively where
//! visibility varies, so a receiver's shadow has vertices to live on (a floor's four
//! corners see the whole sky; the shadow under an object lies between them).
//!
//! Each triangle is split at its edge midpoints into four, recursively, while the
//! visibility of its corners and of the midpoints it would add differs (looking one
//! level ahead finds a shadow that lies wholly inside a large triangle) or while it is
//! larger than a fraction of the scene, down to a smallest edge and within a budget
//! of added vertices spent on the largest triangles first. Visibility at a point is a probe: 64 fixed directions, each
//! occluded or not (rays below the point's horizon are not compared). The transfer is
//! then precomputed at the refined vertices (the original ones among them), and a hit
//! finds its leaf triangle by descending the triangle's quadtree with its barycentric
//! coordinates. Neighbouring leaves of different depth meet at T-junctions, where L*
//! is interpolated along the coarser edge: a seam of the size of one leaf, at most.

use std::collections::HashMap;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use meso_render::geometry::SceneBvh;
use meso_render::scene::TriangleMesh;

/// Probe directions per point.
const PROBES: usize = 64;
/// Corners differ where this many probe directions seen above both horizons are
/// occluded at one and not at the other (2 of 64: about 3% of the sky).
const DIFFERENT: u32 = 2;
/// Triangles longer than the scene's diagonal over this are split whatever their
/// visibility (so a shadow wholly inside a huge triangle is still looked for).
const LARGEST_EDGE_DIVISOR: f64 = 8.0;
/// No edge is split below the scene's diagonal over this.
const SMALLEST_EDGE_DIVISOR: f64 = 256.0;
/// Deepest split of one original triangle.
const MAX_DEPTH: u32 = 12;
/// Offset of probe rays along the normal, relative to the point's magnitude (the
/// visibility pass's).
const EPSILON_REL: f64 = 1e-5;

/// A node of one triangle's quadtree: a leaf triangle of the refined mesh, or four
/// children at consecutive indices (corner 0, corner 1, corner 2, middle).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Node {
    Leaf(u32),
    Split(u32),
}

/// The refined meshes (in scene order) and, per original triangle, its quadtree.
#[derive(Clone, Debug, Default)]
pub struct Refinement {
    pub meshes: Vec<TriangleMesh>,
    /// Per mesh, every node; per original triangle, its root's index.
    nodes: Vec<Vec<Node>>,
    roots: Vec<Vec<u32>>,
    /// Vertices added to the original meshes.
    pub added_vertices: usize,
}

impl Refinement {
    /// The meshes as they are: every triangle a leaf of its own.
    pub fn none(meshes: &[TriangleMesh]) -> Self {
        Self {
            meshes: meshes.to_vec(),
            nodes: meshes
                .iter()
                .map(|m| (0..m.indices.len() as u32).map(Node::Leaf).collect())
                .collect(),
            roots: meshes
                .iter()
                .map(|m| (0..m.indices.len() as u32).collect())
                .collect(),
            added_vertices: 0,
        }
    }

    /// The refined vertices (of the refined mesh `mesh`) around the point of
    /// barycentric coordinates (b1, b2) of original triangle `triangle`, with their
    /// interpolation weights.
    pub fn locate(&self, mesh: usize, triangle: usize, b1: f64, b2: f64) -> ([usize; 3], [f64; 3]) {
        let nodes = &self.nodes[mesh];
        let (mut u, mut v) = (b1, b2);
        let mut node = nodes[self.roots[mesh][triangle] as usize];
        // Bounded by the tree's depth; the bound keeps a damaged tree from looping.
        for _ in 0..=MAX_DEPTH {
            match node {
                Node::Leaf(t) => {
                    let tri = self.meshes[mesh].indices[t as usize].map(|i| i as usize);
                    let w0 = (1.0 - u - v).max(0.0);
                    return (tri, [w0, u, v]);
                }
                Node::Split(first) => {
                    let (child, cu, cv) = child_of(u, v);
                    node = nodes[first as usize + child];
                    (u, v) = (cu, cv);
                }
            }
        }
        unreachable!("a quadtree deeper than MAX_DEPTH")
    }
}

/// Every quadtree as flat arrays, the layout the GPU mode's `locate` descends
/// (`meso_gpu::BiscaleInputs`): per mesh its first triangle, per scene triangle its
/// root, the nodes of every mesh (`meso_gpu::LEAF_BIT | leaf`, or the first of four
/// children) and per leaf its three vertices, offset by `mesh_offsets` into the
/// refined vertices of all meshes.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FlatQuadtrees {
    pub mesh_first: Vec<u32>,
    pub roots: Vec<u32>,
    pub nodes: Vec<u32>,
    pub leaves: Vec<[u32; 3]>,
}

impl Refinement {
    /// The quadtrees flattened, `leaf_bit` marking leaves (see `FlatQuadtrees`).
    pub fn flat(&self, mesh_offsets: &[usize], leaf_bit: u32) -> FlatQuadtrees {
        let mut f = FlatQuadtrees::default();
        for (mesh, nodes) in self.nodes.iter().enumerate() {
            let (node_base, leaf_base) = (f.nodes.len() as u32, f.leaves.len() as u32);
            f.mesh_first.push(f.roots.len() as u32);
            f.roots
                .extend(self.roots[mesh].iter().map(|r| r + node_base));
            f.nodes.extend(nodes.iter().map(|n| match n {
                Node::Leaf(t) => leaf_bit | (leaf_base + t),
                Node::Split(first) => node_base + first,
            }));
            let offset = mesh_offsets[mesh] as u32;
            f.leaves.extend(
                self.meshes[mesh]
                    .indices
                    .iter()
                    .map(|tri| tri.map(|v| offset + v)),
            );
        }
        f
    }
}

/// Which child of a midpoint split holds (u, v), and the point's coordinates in it.
/// Children: 0 at corner 0 (u, v small), 1 at corner 1 (u >= 1/2), 2 at corner 2
/// (v >= 1/2), 3 the middle, whose corners are the midpoints of edges 12, 20, 01.
fn child_of(u: f64, v: f64) -> (usize, f64, f64) {
    if u >= 0.5 {
        (1, 2.0 * u - 1.0, 2.0 * v)
    } else if v >= 0.5 {
        (2, 2.0 * u, 2.0 * v - 1.0)
    } else if u + v < 0.5 {
        (0, 2.0 * u, 2.0 * v)
    } else {
        (3, 1.0 - 2.0 * u, 1.0 - 2.0 * v)
    }
}

/// The four children of triangle (a, b, c) with midpoints ab, bc, ca, in the order
/// `child_of` names them. The middle child's corners are (bc, ca, ab): its point
/// (s, t) is bc + s (ca - bc) + t (ab - bc), which `child_of` inverts.
fn children(a: u32, b: u32, c: u32, ab: u32, bc: u32, ca: u32) -> [[u32; 3]; 4] {
    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [bc, ca, ab]]
}

/// Fixed probe directions: a Fibonacci sphere.
fn probe_directions() -> Vec<DVec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..PROBES)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / PROBES as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// A point's probe: which directions lie above its horizon, and which of those are
/// occluded.
#[derive(Clone, Copy, Debug, Default)]
struct Probe {
    above: u64,
    occluded: u64,
}

impl Probe {
    fn at(bvh: &SceneBvh, dirs: &[DVec3], p: DVec3, n: DVec3) -> Self {
        let origin = p + n * (EPSILON_REL * p.abs().max_element().max(1.0));
        let mut probe = Probe::default();
        for (i, d) in dirs.iter().enumerate() {
            if d.dot(n) > 0.0 {
                probe.above |= 1 << i;
                if bvh.occluded(origin, *d, 0.0, f64::INFINITY) {
                    probe.occluded |= 1 << i;
                }
            }
        }
        probe
    }

    fn differs(&self, other: &Probe) -> bool {
        let both = self.above & other.above;
        ((self.occluded ^ other.occluded) & both).count_ones() >= DIFFERENT
    }
}

/// One mesh being refined: its vertices (the originals first) with their probes,
/// its quadtree nodes, its original triangles (until they are queued), and its leaves.
struct MeshBuilder {
    mesh: TriangleMesh,
    originals: usize,
    probes: Vec<Probe>,
    midpoints: HashMap<(u32, u32), u32>,
    nodes: Vec<Node>,
    roots: Vec<u32>,
    level: Vec<(u32, [u32; 3])>,
    leaves: Vec<(u32, [u32; 3])>,
}

impl MeshBuilder {
    fn new(mesh: &TriangleMesh) -> Self {
        let mut b = MeshBuilder {
            mesh: TriangleMesh {
                indices: Vec::new(),
                ..mesh.clone()
            },
            originals: mesh.positions.len(),
            probes: vec![Probe::default(); mesh.positions.len()],
            midpoints: HashMap::new(),
            nodes: Vec::new(),
            roots: Vec::with_capacity(mesh.indices.len()),
            level: Vec::new(),
            leaves: Vec::new(),
        };
        for tri in &mesh.indices {
            let node = b.nodes.len() as u32;
            b.roots.push(node);
            b.level.push((node, *tri));
            // Marked unfinished (u32::MAX) until the triangle is a leaf or split.
            b.nodes.push(Node::Leaf(u32::MAX));
        }
        b
    }

    /// The vertex halfway along edge (a, b), made the first time (its probe is
    /// taken with the level's others, `pending`).
    fn midpoint(&mut self, a: u32, b: u32, pending: &mut Vec<u32>) -> u32 {
        let key = (a.min(b), a.max(b));
        if let Some(&m) = self.midpoints.get(&key) {
            return m;
        }
        let (i, j) = (key.0 as usize, key.1 as usize);
        let m = &mut self.mesh;
        m.positions.push((m.positions[i] + m.positions[j]) * 0.5);
        m.normals
            .push((m.normals[i] + m.normals[j]).normalize_or(m.normals[i]));
        if !m.uvs.is_empty() {
            let uv: DVec2 = (m.uvs[i] + m.uvs[j]) * 0.5;
            m.uvs.push(uv);
        }
        self.probes.push(Probe::default());
        let index = (m.positions.len() - 1) as u32;
        self.midpoints.insert(key, index);
        pending.push(index);
        index
    }

    fn midpoints_of(&mut self, [a, b, c]: [u32; 3], pending: &mut Vec<u32>) -> [u32; 3] {
        [
            self.midpoint(a, b, pending),
            self.midpoint(b, c, pending),
            self.midpoint(c, a, pending),
        ]
    }

    fn longest_edge(&self, [a, b, c]: [u32; 3]) -> f64 {
        let p = |i: u32| self.mesh.positions[i as usize];
        let (pa, pb, pc) = (p(a), p(b), p(c));
        (pa - pb)
            .length()
            .max((pb - pc).length())
            .max((pc - pa).length())
    }

    /// Whether any two of `points` see the sky differently.
    fn varies(&self, points: &[u32]) -> bool {
        points.iter().enumerate().any(|(k, &i)| {
            points[k + 1..]
                .iter()
                .any(|&j| self.probes[i as usize].differs(&self.probes[j as usize]))
        })
    }

    /// Takes the probes of `vertices` in parallel.
    fn probe(&mut self, vertices: &[u32], bvh: &SceneBvh, dirs: &[DVec3]) {
        let m = &self.mesh;
        let taken: Vec<Probe> = vertices
            .par_iter()
            .map(|&i| {
                let i = i as usize;
                Probe::at(
                    bvh,
                    dirs,
                    m.positions[i],
                    m.normals[i].normalize_or(DVec3::Y),
                )
            })
            .collect();
        for (&i, p) in vertices.iter().zip(taken) {
            self.probes[i as usize] = p;
        }
    }

    /// The refined mesh: its leaves as triangles, the added vertices no leaf uses
    /// dropped (originals keep their indices, so an unrefined mesh's transfer rows are
    /// unchanged), the nodes pointing at the leaves.
    fn finish(mut self) -> (TriangleMesh, Vec<Node>, Vec<u32>, usize) {
        let leaves = std::mem::take(&mut self.leaves);
        let mut used = vec![false; self.mesh.positions.len()];
        for (_, tri) in &leaves {
            for &i in tri {
                used[i as usize] = true;
            }
        }
        let mut remap = vec![u32::MAX; used.len()];
        let mut kept = 0u32;
        for (i, r) in remap.iter_mut().enumerate() {
            if i < self.originals || used[i] {
                *r = kept;
                kept += 1;
            }
        }
        fn keep<T: Copy>(v: &[T], remap: &[u32]) -> Vec<T> {
            v.iter()
                .zip(remap)
                .filter(|(_, r)| **r != u32::MAX)
                .map(|(x, _)| *x)
                .collect()
        }
        let m = &self.mesh;
        let mut out = TriangleMesh {
            positions: keep(&m.positions, &remap),
            normals: keep(&m.normals, &remap),
            uvs: keep(&m.uvs, &remap),
            indices: Vec::with_capacity(leaves.len()),
            material: m.material,
        };
        for (node, tri) in leaves {
            self.nodes[node as usize] = Node::Leaf(out.indices.len() as u32);
            out.indices.push(tri.map(|i| remap[i as usize]));
        }
        let added = out.positions.len() - self.originals;
        (out, self.nodes, self.roots, added)
    }
}

/// Edge lengths that bound the refinement, from the scene's extent.
#[derive(Clone, Copy, Debug)]
struct Scale {
    largest: f64,
    smallest: f64,
}

impl Scale {
    fn of(meshes: &[TriangleMesh]) -> Self {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in meshes.iter().flat_map(|m| &m.positions) {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let diagonal = if lo.x.is_finite() {
            (hi - lo).length()
        } else {
            0.0
        };
        Self {
            largest: diagonal / LARGEST_EDGE_DIVISOR,
            smallest: diagonal / SMALLEST_EDGE_DIVISOR,
        }
    }
}

/// A triangle waiting to be looked at, largest first.
#[derive(PartialEq, Eq, PartialOrd, Ord)]
struct Candidate {
    /// The longest edge's bits (a non-negative f64's bits order as the number).
    edge: u64,
    mesh: usize,
    node: u32,
    depth: u32,
    tri: [u32; 3],
}

/// Triangles looked at together, their new midpoints probed in parallel.
const BATCH: usize = 256;

/// Refines `meshes` (with `bvh` built from them), adding at most about `budget`
/// vertices. The largest triangles of every mesh are looked at first, so the budget
/// goes to a receiver's large triangles before an object's small ones.
pub fn refine(meshes: &[TriangleMesh], bvh: &SceneBvh, budget: usize) -> Refinement {
    if budget == 0 {
        return Refinement::none(meshes);
    }
    let dirs = probe_directions();
    let scale = Scale::of(meshes);
    let mut builders: Vec<MeshBuilder> = meshes.iter().map(MeshBuilder::new).collect();
    let mut heap = std::collections::BinaryHeap::new();
    for (mesh, b) in builders.iter_mut().enumerate() {
        let originals: Vec<u32> = (0..b.originals as u32).collect();
        b.probe(&originals, bvh, &dirs);
        for (node, tri) in std::mem::take(&mut b.level) {
            let edge = b.longest_edge(tri).to_bits();
            heap.push(Candidate {
                edge,
                mesh,
                node,
                depth: 0,
                tri,
            });
        }
    }
    // Vertices the splits keep, counted three a split (shared midpoints make it an
    // upper bound); looked-at midpoints no split used are dropped at the end.
    let mut added = 0usize;
    while added < budget && !heap.is_empty() {
        let mut batch = Vec::with_capacity(BATCH);
        while batch.len() < BATCH
            && let Some(c) = heap.pop()
        {
            let edge = f64::from_bits(c.edge);
            if edge > scale.smallest && c.depth < MAX_DEPTH {
                batch.push(c);
            } else {
                builders[c.mesh].leaves.push((c.node, c.tri));
            }
        }
        // Looking one level ahead: the midpoints of every triangle in the batch.
        let mut pending = vec![Vec::new(); builders.len()];
        for c in &batch {
            builders[c.mesh].midpoints_of(c.tri, &mut pending[c.mesh]);
        }
        for (b, pending) in builders.iter_mut().zip(&pending) {
            b.probe(pending, bvh, &dirs);
        }
        for c in batch {
            let b = &mut builders[c.mesh];
            let [ab, bc, ca] = b.midpoints_of(c.tri, &mut Vec::new());
            let [x, y, z] = c.tri;
            let split = added < budget
                && (f64::from_bits(c.edge) > scale.largest || b.varies(&[x, y, z, ab, bc, ca]));
            if !split {
                b.leaves.push((c.node, c.tri));
                continue;
            }
            let first = b.nodes.len() as u32;
            b.nodes[c.node as usize] = Node::Split(first);
            for child in children(x, y, z, ab, bc, ca) {
                let node = b.nodes.len() as u32;
                b.nodes.push(Node::Leaf(u32::MAX));
                heap.push(Candidate {
                    edge: b.longest_edge(child).to_bits(),
                    mesh: c.mesh,
                    node,
                    depth: c.depth + 1,
                    tri: child,
                });
            }
            added += 3;
        }
    }
    for c in heap {
        builders[c.mesh].leaves.push((c.node, c.tri));
    }
    let mut out = Refinement::default();
    for b in builders {
        let (mesh, nodes, roots, added) = b.finish();
        out.meshes.push(mesh);
        out.nodes.push(nodes);
        out.roots.push(roots);
        out.added_vertices += added;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_point_of_a_split_triangle_lands_in_the_child_that_holds_it() {
        // The children in the parent's barycentrics: corners (0,0) (1,0) (0,1), and
        // the midpoints ab = (1/2, 0), bc = (1/2, 1/2), ca = (0, 1/2).
        let corner = |i: u32| match i {
            0 => DVec2::new(0.0, 0.0),
            1 => DVec2::new(1.0, 0.0),
            2 => DVec2::new(0.0, 1.0),
            3 => DVec2::new(0.5, 0.0),
            4 => DVec2::new(0.5, 0.5),
            _ => DVec2::new(0.0, 0.5),
        };
        let kids = children(0, 1, 2, 3, 4, 5);
        let n = 40;
        for i in 0..=n {
            for j in 0..=(n - i) {
                let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                let (k, cu, cv) = child_of(u, v);
                assert!(
                    (0.0..=1.0).contains(&cu)
                        && (0.0..=1.0).contains(&cv)
                        && cu + cv <= 1.0 + 1e-12,
                    "({u}, {v}) -> child {k} at ({cu}, {cv})"
                );
                let [a, b, c] = kids[k].map(corner);
                let back = a + (b - a) * cu + (c - a) * cv;
                assert!(
                    (back - DVec2::new(u, v)).length() < 1e-12,
                    "({u}, {v}) -> child {k} gives back {back}"
                );
            }
        }
    }
}
