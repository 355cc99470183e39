//! The macro-scale transfer matrix T (Sun et al. 2010, section 4.1): row j = p M + m
//! (vertex p, local direction cell m), column k = cube-map pixel. Each vertex has a
//! shading frame (its normal; the tangent along +u, averaged over its triangles as the
//! spmm mode builds it per hit). For every cube pixel, s x s rays (sub-pixel centres)
//! from the vertex test visibility through the BVH; rays below the vertex's horizon
//! count as blocked. The visible fraction c / s^2, times the pixel's solid angle, goes
//! to the one cell containing the pixel's centre direction (`HemisphereGrid::cell_of`).
//! Entries are stored as the count c (1..=s^2) and a per-column scale, so they take
//! few distinct values per column: the property biclustering exploits.

use glam::DVec3;
use rayon::prelude::*;

use super::cubemap::CubeLayout;
use super::hemisphere::HemisphereGrid;
use meso_render::geometry::SceneBvh;
use meso_render::scene::TriangleMesh;
use meso_render::shading::{dpdu, tangent_frame};
use meso_render::{Cancelled, Prepare};

/// Offset of visibility rays along the normal, relative to the vertex's magnitude (the
/// spmm mode's lift of secondary rays).
const EPSILON_REL: f64 = 1e-5;

/// Per vertex of every mesh (meshes in scene order), the shading frame.
#[derive(Clone, Debug, PartialEq)]
pub struct VertexFrames {
    pub positions: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    pub tangents: Vec<DVec3>,
    pub bitangents: Vec<DVec3>,
    /// Index of each mesh's first vertex; one more entry at the end.
    pub mesh_offsets: Vec<usize>,
}

impl VertexFrames {
    pub fn of(meshes: &[TriangleMesh]) -> Self {
        let mut f = VertexFrames {
            positions: Vec::new(),
            normals: Vec::new(),
            tangents: Vec::new(),
            bitangents: Vec::new(),
            mesh_offsets: vec![0],
        };
        for mesh in meshes {
            let mut tangent_sum = vec![DVec3::ZERO; mesh.positions.len()];
            for tri in &mesh.indices {
                let [i0, i1, i2] = tri.map(|i| i as usize);
                let (p0, p1, p2) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
                // A mesh made in code may lack UVs: its tangents fall back to any
                // perpendicular (`tangent_frame`) instead of reading out of range.
                let uv = |i: usize| mesh.uvs.get(i).copied().unwrap_or_default();
                let (u0, u1, u2) = (uv(i0), uv(i1), uv(i2));
                let d = dpdu(p1 - p0, p2 - p0, u1 - u0, u2 - u0).normalize_or_zero();
                for i in [i0, i1, i2] {
                    tangent_sum[i] += d;
                }
            }
            for (i, &p) in mesh.positions.iter().enumerate() {
                let n = mesh.normals[i].normalize_or(DVec3::Y);
                let (t, b) = tangent_frame(n, tangent_sum[i]);
                f.positions.push(p);
                f.normals.push(n);
                f.tangents.push(t);
                f.bitangents.push(b);
            }
            f.mesh_offsets.push(f.positions.len());
        }
        f
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// World direction `w` in vertex `p`'s frame.
    pub fn to_local(&self, p: usize, w: DVec3) -> DVec3 {
        DVec3::new(
            w.dot(self.tangents[p]),
            w.dot(self.bitangents[p]),
            w.dot(self.normals[p]),
        )
    }
}

/// The sparse transfer matrix, rows in CSR order with sorted columns.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferMatrix {
    pub rows: usize,
    pub cols: usize,
    pub row_offsets: Vec<u32>,
    pub columns: Vec<u32>,
    /// Visible sub-rays c in 1..=s^2 of each entry; its value is c * `column_scale[k]`.
    pub counts: Vec<u8>,
    /// Per column: the pixel's solid angle / s^2.
    pub column_scale: Vec<f32>,
}

impl TransferMatrix {
    pub fn nonzeros(&self) -> usize {
        self.columns.len()
    }

    /// The entries of row j: (column, value).
    pub fn row(&self, j: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let r = self.row_offsets[j] as usize..self.row_offsets[j + 1] as usize;
        self.columns[r.clone()]
            .iter()
            .zip(&self.counts[r])
            .map(|(&k, &c)| (k as usize, c as f32 * self.column_scale[k as usize]))
    }

    /// L* = T L, RGB, in f64 (the reference the compressed forms are checked against).
    pub fn apply_f64(&self, light: &[[f32; 3]]) -> Vec<[f64; 3]> {
        (0..self.rows)
            .into_par_iter()
            .map(|j| {
                let mut acc = [0.0f64; 3];
                for (k, v) in self.row(j) {
                    for c in 0..3 {
                        acc[c] += v as f64 * light[k][c] as f64;
                    }
                }
                acc
            })
            .collect()
    }

    /// L* = T L in f32, the dense multiply the biclustering is measured against.
    pub fn apply(&self, light: &[[f32; 3]]) -> Vec<[f32; 3]> {
        (0..self.rows)
            .into_par_iter()
            .map(|j| {
                let mut acc = [0.0f32; 3];
                for (k, v) in self.row(j) {
                    for c in 0..3 {
                        acc[c] += v * light[k][c];
                    }
                }
                acc
            })
            .collect()
    }

    /// Multiply-adds of one dense product per colour channel (2 nnz FLOPs).
    pub fn dense_flops(&self) -> u64 {
        2 * self.nonzeros() as u64
    }
}

/// Per vertex, the cube pixels it sees: (pixel, visible sub-rays), in pixel order.
pub type Visibility = Vec<Vec<(u32, u8)>>;

/// The visibility pass: for every vertex and cube pixel, how many of the pixel's
/// s x s rays leave the scene above the vertex's horizon. Reported as stage
/// "visibility", cancellable between batches of vertices.
pub fn visibility(
    frames: &VertexFrames,
    bvh: &SceneBvh,
    cube: CubeLayout,
    rays_per_side: u32,
    prepare: &Prepare,
) -> Result<Visibility, Cancelled> {
    let s = rays_per_side.clamp(1, 15);
    let per = (s * s) as usize;
    let sub: Vec<DVec3> = (0..cube.len())
        .flat_map(|k| {
            (0..s * s).map(move |i| {
                cube.direction(
                    k,
                    ((i % s) as f64 + 0.5) / s as f64,
                    ((i / s) as f64 + 0.5) / s as f64,
                )
            })
        })
        .collect();
    let mut out: Visibility = Vec::with_capacity(frames.len());
    let batch = 32;
    for start in (0..frames.len()).step_by(batch) {
        prepare.report("visibility", start as f32 / frames.len().max(1) as f32)?;
        let end = (start + batch).min(frames.len());
        let seen: Visibility = (start..end)
            .into_par_iter()
            .map(|p| {
                let n = frames.normals[p];
                let pos = frames.positions[p];
                let origin = pos + n * (EPSILON_REL * pos.abs().max_element().max(1.0));
                let mut row = Vec::new();
                for k in 0..cube.len() {
                    let visible = sub[k * per..(k + 1) * per]
                        .iter()
                        .filter(|d| {
                            d.dot(n) > 0.0 && !bvh.occluded(origin, **d, 0.0, f64::INFINITY)
                        })
                        .count();
                    if visible > 0 {
                        row.push((k as u32, visible as u8));
                    }
                }
                row
            })
            .collect();
        out.extend(seen);
    }
    prepare.report("visibility", 1.0)?;
    Ok(out)
}

/// The binning pass: each visible pixel's count goes to the local cell containing the
/// pixel's centre direction in the vertex's frame; rows assembled in CSR order.
pub fn bin(
    frames: &VertexFrames,
    seen: &Visibility,
    cube: CubeLayout,
    local: HemisphereGrid,
    rays_per_side: u32,
) -> TransferMatrix {
    let s = rays_per_side.clamp(1, 15);
    let mc = local.len();
    let centres: Vec<DVec3> = (0..cube.len()).map(|k| cube.centre(k)).collect();
    let per_vertex: Vec<Vec<Vec<(u32, u8)>>> = seen
        .par_iter()
        .enumerate()
        .map(|(p, row)| {
            let mut cells = vec![Vec::new(); mc];
            for &(k, c) in row {
                let m = local.cell_of(frames.to_local(p, centres[k as usize]));
                cells[m].push((k, c));
            }
            cells
        })
        .collect();
    let mut row_offsets = Vec::with_capacity(frames.len() * mc + 1);
    row_offsets.push(0u32);
    let (mut columns, mut counts) = (Vec::new(), Vec::new());
    for r in per_vertex.into_iter().flatten() {
        for (k, c) in r {
            columns.push(k);
            counts.push(c);
        }
        row_offsets.push(columns.len() as u32);
    }
    let scale = 1.0 / (s * s) as f64;
    TransferMatrix {
        rows: frames.len() * mc,
        cols: cube.len(),
        row_offsets,
        columns,
        counts,
        column_scale: cube
            .solid_angles()
            .iter()
            .map(|w| (w * scale) as f32)
            .collect(),
    }
}

impl TransferMatrix {
    /// Why these arrays cannot be the transfer of `rows` x `cols` with `s^2` rays.
    pub fn problem(&self, max_count: u8) -> Option<String> {
        if self.row_offsets.len() != self.rows + 1 {
            return Some(format!(
                "{} row offsets for {} rows",
                self.row_offsets.len(),
                self.rows
            ));
        }
        if self.row_offsets[0] != 0
            || self.row_offsets.windows(2).any(|w| w[0] > w[1])
            || *self.row_offsets.last()? as usize != self.columns.len()
        {
            return Some("row offsets are not increasing from 0 to the entry count".into());
        }
        if self.counts.len() != self.columns.len() {
            return Some("columns and counts differ in length".into());
        }
        if let Some(k) = self.columns.iter().find(|&&k| k as usize >= self.cols) {
            return Some(format!("column {k} out of range ({} columns)", self.cols));
        }
        if let Some(c) = self.counts.iter().find(|&&c| c == 0 || c > max_count) {
            return Some(format!("count {c} outside 1..={max_count}"));
        }
        None
    }
}
