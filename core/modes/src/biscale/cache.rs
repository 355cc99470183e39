//! The biscale precomputation on disk: a safetensors container (`container.rs`, the
//! packs' writer and opening check) with `format = "meso-biscale-cache"`, a version,
//! the key of its inputs (`precompute::cache_key`) and a checksum of every tensor's
//! bytes. Reading validates all of it (key, checksum, shapes, offsets, indices,
//! ranges) before anything is used; any fault is an error naming the file and the
//! part, and the caller rebuilds. Frames and column scales are not stored: they follow
//! from the scene and the settings the key covers.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use safetensors::Dtype;

use super::BiscaleSettings;
use super::bicluster::Biclustering;
use super::cubemap::CubeLayout;
use super::hemisphere::HemisphereGrid;
use super::transfer::TransferMatrix;
use meso_materials::container::{self, Tensor};
use meso_materials::hash::Fnv1a;

pub const FORMAT: &str = "meso-biscale-cache";
pub const VERSION: &str = "1";

/// Tensors in the order the checksum reads them.
const NAMES: [&str; 8] = [
    "t_row_offsets",
    "t_columns",
    "t_counts",
    "bc_col_offsets",
    "bc_columns",
    "bc_values",
    "bc_row_offsets",
    "bc_row_biclusters",
];

#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    #[error("cache `{path}`: {problem}")]
    Invalid { path: PathBuf, problem: String },
    #[error("cache `{path}`: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cache `{path}`: {source}")]
    Write {
        path: PathBuf,
        source: meso_materials::atomic::AtomicWriteError,
    },
}

/// The file of key `key` in `dir`.
pub fn path_in(dir: &Path, key: u64) -> PathBuf {
    dir.join(format!("biscale-{key:016x}.safetensors"))
}

fn u32_bytes(v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn checksum(parts: &[&[u8]]) -> u64 {
    let mut h = Fnv1a::default();
    for p in parts {
        h.word(p.len() as u64);
        h.bytes(p);
    }
    h.finish()
}

/// The container bytes of a precomputation.
pub fn encode(key: u64, s: &BiscaleSettings, t: &TransferMatrix, b: &Biclustering) -> Vec<u8> {
    let data: [(Dtype, Vec<u8>); 8] = [
        (Dtype::U32, u32_bytes(&t.row_offsets)),
        (Dtype::U32, u32_bytes(&t.columns)),
        (Dtype::U8, t.counts.clone()),
        (Dtype::U32, u32_bytes(&b.col_offsets)),
        (Dtype::U32, u32_bytes(&b.columns)),
        (Dtype::F32, f32_bytes(&b.values)),
        (Dtype::U32, u32_bytes(&b.row_offsets)),
        (Dtype::U32, u32_bytes(&b.row_biclusters)),
    ];
    let sum = checksum(&data.iter().map(|d| d.1.as_slice()).collect::<Vec<_>>());
    let mut tensors = BTreeMap::new();
    for (name, (dtype, bytes)) in NAMES.iter().zip(data) {
        let size = match dtype {
            Dtype::U8 => 1,
            _ => 4,
        };
        tensors.insert(
            *name,
            Tensor {
                dtype,
                shape: vec![bytes.len() / size],
                data: bytes,
            },
        );
    }
    let meta = [
        ("format", FORMAT.to_string()),
        ("version", VERSION.to_string()),
        ("key", format!("{key:016x}")),
        ("checksum", format!("{sum:016x}")),
        ("cube_n", s.cube_n.to_string()),
        ("local_res", s.local_res.to_string()),
        ("rays_per_side", s.rays_per_side.to_string()),
        ("rows", t.rows.to_string()),
    ];
    container::encode(&meta, &tensors)
}

/// Writes the cache atomically (the folder is created if missing).
pub fn write(
    path: &Path,
    key: u64,
    s: &BiscaleSettings,
    t: &TransferMatrix,
    b: &Biclustering,
) -> Result<(), CacheError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| CacheError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    }
    meso_materials::atomic::write_bytes_atomic(path, &encode(key, s, t, b)).map_err(|source| {
        CacheError::Write {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// Reads and validates a cache for `key` with `vertices` vertices.
pub fn read(
    path: &Path,
    key: u64,
    s: &BiscaleSettings,
    vertices: usize,
) -> Result<(TransferMatrix, Biclustering), CacheError> {
    let bytes = std::fs::read(path).map_err(|source| CacheError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode(&bytes, key, s, vertices).map_err(|problem| CacheError::Invalid {
        path: path.to_path_buf(),
        problem,
    })
}

fn as_u32(b: &[u8]) -> Vec<u32> {
    b.chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Validates container bytes against the expected key and shapes.
pub fn decode(
    bytes: &[u8],
    key: u64,
    s: &BiscaleSettings,
    vertices: usize,
) -> Result<(TransferMatrix, Biclustering), String> {
    let opened = container::open(bytes, FORMAT, VERSION).map_err(|e| match e {
        container::ContainerError::Invalid(m) => format!("not a readable container: {m}"),
        other => other.to_string(),
    })?;
    let text = |k: &'static str| {
        opened
            .text(k)
            .map_err(|_| format!("metadata `{k}` is missing"))
    };
    let found = text("key")?;
    if found != format!("{key:016x}") {
        return Err(format!(
            "stale: made for inputs {found}, the scene and settings now hash to {key:016x}"
        ));
    }
    let mut data = Vec::with_capacity(NAMES.len());
    for (name, dtype) in NAMES.iter().zip([
        Dtype::U32,
        Dtype::U32,
        Dtype::U8,
        Dtype::U32,
        Dtype::U32,
        Dtype::F32,
        Dtype::U32,
        Dtype::U32,
    ]) {
        let t = opened
            .tensors
            .tensor(name)
            .map_err(|_| format!("tensor `{name}` is missing"))?;
        if t.dtype() != dtype || t.shape().len() != 1 {
            return Err(format!(
                "tensor `{name}` is {:?} {:?}, expected a {dtype:?} vector",
                t.dtype(),
                t.shape()
            ));
        }
        data.push(t.data());
    }
    let sum = checksum(&data);
    if text("checksum")? != format!("{sum:016x}") {
        return Err("checksum mismatch: the tensors were changed or damaged".into());
    }
    let cube = CubeLayout::new(s.cube_n);
    let local = HemisphereGrid::new(s.local_res);
    let rows = vertices * local.len();
    let per = s.rays_per_side * s.rays_per_side;
    let scale = 1.0 / per as f64;
    let t = TransferMatrix {
        rows,
        cols: cube.len(),
        row_offsets: as_u32(data[0]),
        columns: as_u32(data[1]),
        counts: data[2].to_vec(),
        column_scale: cube
            .solid_angles()
            .iter()
            .map(|w| (w * scale) as f32)
            .collect(),
    };
    if let Some(p) = t.problem(per as u8) {
        return Err(format!("transfer matrix: {p}"));
    }
    let b = Biclustering {
        rows,
        cols: cube.len(),
        col_offsets: as_u32(data[3]),
        columns: as_u32(data[4]),
        values: data[5]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        row_offsets: as_u32(data[6]),
        row_biclusters: as_u32(data[7]),
    };
    if let Some(p) = b.problem() {
        return Err(format!("biclusters: {p}"));
    }
    Ok((t, b))
}
