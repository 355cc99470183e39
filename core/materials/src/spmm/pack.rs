//! The `.spmm` pack: an SPMM material in the safetensors container (named tensors and a
//! string metadata map with `format = "meso-spmm"`, `version = "1"`), specified in
//! docs/formats/spmm.md. Reading parses the container with the `safetensors` crate
//! (offsets and sizes checked against the real file, so a lying header cannot make
//! it allocate) and then checks every shape, dtype, index and range before building
//! the material. Writing emits a deterministic header, so save -> load -> save is
//! byte-identical, and goes through `atomic::write_atomic`.
//!
//! Writing is in `encode.rs`, reading and its checks in `decode.rs`, the I8 residual
//! encoding both share in `quantize.rs`; this module holds the format's constants, its
//! errors and the file operations.

use std::path::Path;

use super::material::{SpmmError, SpmmMaterial};
use crate::atomic::write_bytes_atomic;
use crate::brdf::{BrdfError, BrdfModel};
use crate::container::{self, ContainerError, FileError};

mod decode;
mod encode;
mod quantize;

pub use decode::{decode_pack, residual_precision, tensor_sizes};
pub use encode::{cluster_component_counts, encode_pack};
pub use quantize::{I8_EXPONENT_MAX, I8_EXPONENT_MIN};

pub const FORMAT: &str = "meso-spmm";
pub const VERSION: &str = "1";
/// Columns of `basis_params`: enough for the model with the most parameters.
pub const PARAM_COLUMNS: usize = 4;
/// Packs larger than this are refused before reading (a material is MBs, not GBs).
pub const MAX_FILE_BYTES: u64 = 1 << 31;

/// Precision of the residual tables on disk (f16 halves the largest part of a pack).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResidualPrecision {
    F16,
    F32,
    /// Components as signed 8-bit integers, each run of `V x 3` values (one component,
    /// one light direction) scaled by a power of two of its own; the mean as F16. Half
    /// the bytes of F16 per component, so twice the components at equal bytes.
    I8,
}

impl ResidualPrecision {
    /// The command-line and documentation name.
    pub fn name(self) -> &'static str {
        match self {
            Self::F16 => "f16",
            Self::F32 => "f32",
            Self::I8 => "i8",
        }
    }
}

/// A pack that cannot be read or written: the file and what is wrong with it.
pub type PackError = FileError<PackErrorKind>;

/// What is wrong with a pack: what every container file can have wrong
/// (`ContainerError`), or what only a pack can.
#[derive(Debug, thiserror::Error)]
pub enum PackErrorKind {
    #[error(transparent)]
    Container(#[from] ContainerError),
    #[error(
        "tensor `basis_model`[{index}] = {value}: model ids are 0..=6 (lambertian .. ashikhmin_shirley)"
    )]
    ModelId { index: usize, value: u8 },
    #[error("basis {index} (tensors basis_params/basis_normal row {index}): {source}")]
    Basis { index: usize, source: BrdfError },
    #[error(
        "tensor `basis_params`[{index}][{column}] = {value}: model `{model}` has {used} parameter(s), unused columns must be 0"
    )]
    UnusedParam {
        index: usize,
        column: usize,
        value: f64,
        model: &'static str,
        used: usize,
    },
    #[error("{0}")]
    Ragged(String),
    /// An I8 residual table that cannot be decoded (docs/formats/spmm.md).
    #[error("{0}")]
    Quantized(String),
    #[error("tensor `cluster_basis_offsets`: {0}")]
    ClusterOffsets(String),
    #[error("{0}")]
    Material(#[from] SpmmError),
}

/// How a pack's size limit and unknown tensors are named in `ContainerError`.
const FILE_NOUN: &str = "a pack";
const FORMAT_NOUN: &str = "format";

/// The model id stored in `basis_model`: the index in `BrdfModel::ALL`.
pub fn model_id(model: BrdfModel) -> u8 {
    BrdfModel::ALL
        .iter()
        .position(|m| *m == model)
        .expect("ALL lists every model") as u8
}

/// Reads and validates a pack file.
pub fn read_pack(path: &Path) -> Result<SpmmMaterial, PackError> {
    let at = |kind: PackErrorKind| PackError::at(path, kind);
    let bytes =
        container::read_limited(path, MAX_FILE_BYTES, FILE_NOUN).map_err(|e| at(e.into()))?;
    decode_pack(&bytes).map_err(at)
}

/// Writes a pack atomically (the previous file survives a failed write).
pub fn write_pack(
    path: &Path,
    material: &SpmmMaterial,
    precision: ResidualPrecision,
) -> Result<(), PackError> {
    write_bytes_atomic(path, &encode_pack(material, precision))
        .map_err(|e| PackError::at(path, ContainerError::from(e)))
}
