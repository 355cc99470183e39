//! Triangle meshes of a scene: Wavefront OBJ through tobj, placed by the scene's
//! transform (uniform scale, then rotation about an axis, then translation), and
//! parallelogram quads. Missing normals are computed (area-weighted vertex normals);
//! missing texture coordinates get a spherical mapping about the mesh's bounding-box
//! centre (u = 0.5 + atan2(z, x) / 2 pi, v = 0.5 + asin(y / r) / pi, object space),
//! which wraps cleanly with tiling materials.

use std::io::Cursor;
use std::path::Path;

use glam::{DMat3, DVec2, DVec3};

use super::extent_problem;

/// World-space triangles sharing one material.
#[derive(Clone, Debug, PartialEq)]
pub struct TriangleMesh {
    pub positions: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    pub uvs: Vec<DVec2>,
    pub indices: Vec<[u32; 3]>,
    pub material: usize,
}

impl TriangleMesh {
    /// Why the tracer cannot take this mesh (for meshes made outside a scene file,
    /// e.g. by an edit): a vertex not finite or outside the scene extent, an index out
    /// of range, or per-vertex arrays of the wrong length.
    pub fn problem(&self) -> Option<String> {
        let n = self.positions.len();
        if self.normals.len() != n || self.uvs.len() != n {
            return Some(format!(
                "{n} positions but {} normals and {} uvs",
                self.normals.len(),
                self.uvs.len()
            ));
        }
        if let Some((i, p)) = self
            .positions
            .iter()
            .enumerate()
            .find_map(|(i, p)| extent_problem(*p).map(|p| (i, p)))
        {
            return Some(format!("vertex {i} {p}"));
        }
        self.indices
            .iter()
            .flatten()
            .find(|&&i| i as usize >= n)
            .map(|i| format!("index {i} out of range ({n} vertices)"))
    }
}

/// Scale, then rotate, then translate (docs/scenes.md).
#[derive(Clone, Copy, Debug)]
pub struct Placement {
    pub scale: f64,
    pub rotation: DMat3,
    pub translate: DVec3,
}

impl Placement {
    fn point(&self, p: DVec3) -> DVec3 {
        self.rotation * (p * self.scale) + self.translate
    }
    fn normal(&self, n: DVec3) -> DVec3 {
        // Uniform scale and a rotation: normals rotate like directions (the sign of a
        // negative scale is kept by the scene validation, which refuses it).
        (self.rotation * n).normalize_or_zero()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("cannot read OBJ `{}`: {message}", path.display())]
    Obj {
        path: std::path::PathBuf,
        message: String,
    },
    #[error("OBJ `{}` has no triangles", path.display())]
    Empty { path: std::path::PathBuf },
    #[error("OBJ `{}`: {what} index {index} out of range (count {count})", path.display())]
    Index {
        path: std::path::PathBuf,
        what: &'static str,
        index: u32,
        count: usize,
    },
    #[error("OBJ `{}` line {line}: vertex {vertex} is not finite in single precision", path.display())]
    NonFinite {
        path: std::path::PathBuf,
        line: usize,
        /// 1-based, as the file's faces count vertices.
        vertex: usize,
    },
    #[error("OBJ `{}` line {line}: vertex {vertex} placed in the scene {problem}", path.display())]
    Extent {
        path: std::path::PathBuf,
        line: usize,
        vertex: usize,
        problem: String,
    },
}

/// Checks an OBJ's text before tobj reads it, naming the file's line: every `v` line
/// as the tracer will receive it (each coordinate as tobj reads it, f32, finite; the
/// placed vertex within the scene's extent; vertices counted from 1 as faces count
/// them), and every index of `f`, `l` and `p` lines within the elements the file has
/// (absolute from 1, or relative from -1): tobj's own resolution of a far-out index
/// overflows.
fn check_obj_text(text: &str, path: &Path, placement: &Placement) -> Result<(), MeshError> {
    let count = |kind: &str| {
        text.lines()
            .filter(|l| l.split_whitespace().next() == Some(kind))
            .count() as i64
    };
    let totals = [count("v"), count("vt"), count("vn")];
    let mut seen = [0i64; 3];
    let index_error = |line: usize, what: &str| MeshError::Obj {
        path: path.to_path_buf(),
        message: format!("line {line}: {what}"),
    };
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                seen[0] += 1;
                // Lines tobj cannot parse are its errors to report.
                let Ok(xyz) = words
                    .take(3)
                    .map(|w| w.parse::<f32>())
                    .collect::<Result<Vec<f32>, _>>()
                else {
                    continue;
                };
                if xyz.len() < 3 {
                    continue;
                }
                if xyz.iter().any(|c| !c.is_finite()) {
                    return Err(MeshError::NonFinite {
                        path: path.to_path_buf(),
                        line: i + 1,
                        vertex: seen[0] as usize,
                    });
                }
                let p = DVec3::new(xyz[0] as f64, xyz[1] as f64, xyz[2] as f64);
                if let Some(problem) = extent_problem(placement.point(p)) {
                    return Err(MeshError::Extent {
                        path: path.to_path_buf(),
                        line: i + 1,
                        vertex: seen[0] as usize,
                        problem,
                    });
                }
            }
            Some("vt") => seen[1] += 1,
            Some("vn") => seen[2] += 1,
            Some("f" | "l" | "p") => {
                for corner in words {
                    for (k, part) in corner.split('/').enumerate().take(3) {
                        if part.is_empty() {
                            continue;
                        }
                        let Ok(index) = part.parse::<i64>() else {
                            return Err(index_error(i + 1, &format!("`{corner}` is not an index")));
                        };
                        let ok = match index {
                            0 => false,
                            n if n > 0 => n <= totals[k],
                            n => n >= -seen[k],
                        };
                        if !ok {
                            let kind = ["vertex", "texture coordinate", "normal"][k];
                            return Err(index_error(
                                i + 1,
                                &format!("{kind} index {index} is out of range"),
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Loads every object of an OBJ file into one mesh, placed in the world.
pub fn load_obj(
    path: &Path,
    placement: &Placement,
    material: usize,
) -> Result<TriangleMesh, MeshError> {
    let options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ..Default::default()
    };
    let obj_error = |message: String| MeshError::Obj {
        path: path.to_path_buf(),
        message,
    };
    let text = std::fs::read(path).map_err(|e| obj_error(e.to_string()))?;
    check_obj_text(&String::from_utf8_lossy(&text), path, placement)?;
    // Materials (`mtllib`) are not used: the scene assigns one material per mesh.
    let (models, _) =
        tobj::load_obj_buf(
            &mut Cursor::new(&text),
            &options,
            |_| Ok(Default::default()),
        )
        .map_err(|e| obj_error(e.to_string()))?;
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    let mut indices = Vec::new();
    let mut all_have_normals = true;
    let mut all_have_uvs = true;
    for m in &models {
        let mesh = &m.mesh;
        let base = positions.len() as u32;
        let count = mesh.positions.len() / 3;
        // Every `v` line was checked above (finite, within the extent once placed).
        for p in mesh.positions.chunks_exact(3) {
            positions.push(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        }
        all_have_normals &= mesh.normals.len() == mesh.positions.len();
        all_have_uvs &= mesh.texcoords.len() / 2 == count;
        normals.extend(
            mesh.normals
                .chunks_exact(3)
                .map(|n| DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64)),
        );
        uvs.extend(
            mesh.texcoords
                .chunks_exact(2)
                .map(|t| DVec2::new(t[0] as f64, t[1] as f64)),
        );
        for t in mesh.indices.chunks_exact(3) {
            for &i in t {
                if i as usize >= count {
                    return Err(MeshError::Index {
                        path: path.to_path_buf(),
                        what: "vertex",
                        index: i,
                        count,
                    });
                }
            }
            indices.push([base + t[0], base + t[1], base + t[2]]);
        }
    }
    if indices.is_empty() {
        return Err(MeshError::Empty {
            path: path.to_path_buf(),
        });
    }
    if !all_have_uvs {
        uvs = spherical_uvs(&positions);
    }
    let positions: Vec<DVec3> = positions.into_iter().map(|p| placement.point(p)).collect();
    let normals = if all_have_normals {
        normals.into_iter().map(|n| placement.normal(n)).collect()
    } else {
        vertex_normals(&positions, &indices)
    };
    Ok(TriangleMesh {
        positions,
        normals,
        uvs,
        indices,
        material,
    })
}

/// Area-weighted vertex normals; a vertex of degenerate triangles only gets +y.
pub fn vertex_normals(positions: &[DVec3], indices: &[[u32; 3]]) -> Vec<DVec3> {
    let mut acc = vec![DVec3::ZERO; positions.len()];
    for t in indices {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        // The cross product's length is twice the area: the weighting comes free.
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    acc.into_iter()
        .map(|n| n.try_normalize().unwrap_or(DVec3::Y))
        .collect()
}

fn spherical_uvs(positions: &[DVec3]) -> Vec<DVec2> {
    let lo = positions
        .iter()
        .fold(DVec3::splat(f64::INFINITY), |a, p| a.min(*p));
    let hi = positions
        .iter()
        .fold(DVec3::splat(f64::NEG_INFINITY), |a, p| a.max(*p));
    let centre = (lo + hi) * 0.5;
    positions
        .iter()
        .map(|p| {
            let d = (*p - centre).try_normalize().unwrap_or(DVec3::Y);
            DVec2::new(
                0.5 + d.z.atan2(d.x) / std::f64::consts::TAU,
                0.5 + d.y.clamp(-1.0, 1.0).asin() / std::f64::consts::PI,
            )
        })
        .collect()
}

/// A parallelogram as two triangles: uv = (s, t) along the edges, normal edge_u x edge_v.
pub fn quad(corner: DVec3, edge_u: DVec3, edge_v: DVec3, material: usize) -> TriangleMesh {
    let n = edge_u.cross(edge_v).normalize_or_zero();
    TriangleMesh {
        positions: vec![
            corner,
            corner + edge_u,
            corner + edge_u + edge_v,
            corner + edge_v,
        ],
        normals: vec![n; 4],
        uvs: vec![
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(1.0, 1.0),
            DVec2::new(0.0, 1.0),
        ],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        material,
    }
}
