//! The safetensors container as Meso writes and opens it (`.spmm` packs, `.btf` BTFs).
//! Writing is our own and deterministic: the safetensors crate serialises its metadata
//! map in random order, which would break byte-identical round trips. Keys are sorted,
//! tensors ordered by decreasing element size then name (so each starts aligned to its
//! element size), the header padded with spaces to 8 bytes. Opening checks what both
//! formats share: the container parses and its `format` and `version` match. Both
//! formats report what they share with one error type (`ContainerError`, the path
//! added by `FileError`); each format's own error kinds embed it.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors};
use serde_json::json;

use crate::atomic::AtomicWriteError;

/// The Python interpreter the independent format checks run (`MESO_PYTHON`, default
/// `python3`), if it imports safetensors and numpy. Elsewhere the checks say they are
/// skipped and pass (tests must not require Python); where the environment variable
/// `CI` is set they must run (`.ci/run` installs both), so a missing module fails.
#[cfg(test)]
pub(crate) fn python_with_safetensors() -> Option<String> {
    let python = std::env::var("MESO_PYTHON").unwrap_or_else(|_| "python3".into());
    let probe = std::process::Command::new(&python)
        .args(["-c", "import safetensors.numpy, numpy"])
        .output();
    if probe.is_ok_and(|o| o.status.success()) {
        return Some(python);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but `{python}` lacks safetensors/numpy (set MESO_PYTHON; .ci/run installs them)"
    );
    eprintln!("skipped: `{python}` lacks safetensors/numpy (set MESO_PYTHON)");
    None
}

/// Runs the Python `script` (from `python_with_safetensors`) on `path` and parses the
/// one JSON object it prints: how the independent format checks read a file.
#[cfg(test)]
pub(crate) fn python_json(python: &str, script: &str, path: &std::path::Path) -> serde_json::Value {
    let out = std::process::Command::new(python)
        .args(["-c", script])
        .arg(path)
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("the script prints one JSON object")
}

/// One tensor to write: little-endian data of `shape` elements of `dtype`.
#[derive(Clone)]
pub struct Tensor {
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub data: Vec<u8>,
}

/// The name safetensors headers use for a dtype.
pub fn dtype_name(d: Dtype) -> &'static str {
    match d {
        Dtype::U8 => "U8",
        Dtype::I8 => "I8",
        Dtype::U16 => "U16",
        Dtype::U32 => "U32",
        Dtype::F16 => "F16",
        Dtype::F32 => "F32",
        Dtype::F64 => "F64",
        _ => "other",
    }
}

/// The container bytes of `tensors` with string `metadata`.
pub fn encode(metadata: &[(&str, String)], tensors: &BTreeMap<&str, Tensor>) -> Vec<u8> {
    let mut order: Vec<&str> = tensors.keys().copied().collect();
    order.sort_by_key(|name| (std::cmp::Reverse(tensors[name].dtype.bitsize()), *name));
    let mut header = serde_json::Map::new();
    let meta: serde_json::Map<String, serde_json::Value> = metadata
        .iter()
        .map(|(k, v)| (k.to_string(), json!(v)))
        .collect();
    header.insert("__metadata__".into(), serde_json::Value::Object(meta));
    let mut offset = 0usize;
    for name in &order {
        let t = &tensors[name];
        header.insert(
            name.to_string(),
            json!({"dtype": dtype_name(t.dtype), "shape": t.shape, "data_offsets": [offset, offset + t.data.len()]}),
        );
        offset += t.data.len();
    }
    let mut header_bytes = serde_json::to_vec(&serde_json::Value::Object(header))
        .expect("a JSON map of strings and numbers always serialises");
    while !header_bytes.len().is_multiple_of(8) {
        header_bytes.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + header_bytes.len() + offset);
    out.extend_from_slice(&(header_bytes.len() as u64).to_le_bytes());
    out.extend_from_slice(&header_bytes);
    for name in &order {
        out.extend_from_slice(&tensors[name].data);
    }
    out
}

/// What is wrong with a container file, in the terms both formats share. What the
/// formats say differently (the size limit and how a file is named, the format an
/// unknown tensor is not part of) is carried as data, so one type serves both.
#[derive(Debug, thiserror::Error)]
pub enum ContainerError {
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    #[error("file is {bytes} bytes, more than the {limit} {file} may have")]
    TooLarge {
        bytes: u64,
        limit: u64,
        /// The file as the limit names it: "a pack", "a .btf".
        file: &'static str,
    },
    #[error("not a valid safetensors container: {0}")]
    Invalid(String),
    #[error("metadata `{key}`: {problem}")]
    Metadata { key: &'static str, problem: String },
    #[error("tensor `{0}` is missing")]
    MissingTensor(&'static str),
    #[error("tensor `{name}` is not part of {format} version {version}")]
    UnknownTensor {
        name: String,
        /// The format as the message names it: "format", ".btf format".
        format: &'static str,
        version: &'static str,
    },
    #[error("tensor `{name}` has dtype {found}, expected {expected}")]
    Dtype {
        name: &'static str,
        found: String,
        expected: &'static str,
    },
    #[error("tensor `{name}` has shape {found:?}, expected {expected}")]
    Shape {
        name: &'static str,
        found: Vec<usize>,
        /// The expected shape as the message shows it: `[2, 3]`, `[N, 3]`.
        expected: String,
    },
    #[error("cannot write: {0}")]
    Write(#[from] AtomicWriteError),
}

impl ContainerError {
    /// A required metadata key that is absent.
    pub fn missing_metadata(key: &'static str) -> Self {
        Self::Metadata {
            key,
            problem: "missing".into(),
        }
    }
}

/// A container file that cannot be read or written: the file and what is wrong with
/// it, `K` being the format's own error kinds (`spmm::pack::PackErrorKind`,
/// `btf::file::BtfFileErrorKind`), which embed `ContainerError`.
#[derive(Debug, thiserror::Error)]
#[error("`{}`: {kind}", path.display())]
pub struct FileError<K> {
    pub path: PathBuf,
    pub kind: K,
}

impl<K> FileError<K> {
    /// `kind` at `path`.
    pub fn at(path: &Path, kind: impl Into<K>) -> Self {
        Self {
            path: path.to_path_buf(),
            kind: kind.into(),
        }
    }
}

/// The bytes of a container file, refused before reading when larger than `limit`
/// (a lying size cannot make it allocate); `file` names such a file in the refusal.
pub fn read_limited(
    path: &Path,
    limit: u64,
    file: &'static str,
) -> Result<Vec<u8>, ContainerError> {
    let bytes = std::fs::metadata(path)?.len();
    if bytes > limit {
        return Err(ContainerError::TooLarge { bytes, limit, file });
    }
    Ok(std::fs::read(path)?)
}

/// A parsed container and its metadata.
pub struct Opened<'a> {
    pub tensors: SafeTensors<'a>,
    pub metadata: HashMap<String, String>,
}

impl Opened<'_> {
    /// A required metadata string.
    pub fn text(&self, key: &'static str) -> Result<String, ContainerError> {
        self.metadata
            .get(key)
            .cloned()
            .ok_or_else(|| ContainerError::missing_metadata(key))
    }
}

/// Parses `bytes` and checks `format` and `version`.
pub fn open<'a>(
    bytes: &'a [u8],
    format: &str,
    version: &str,
) -> Result<Opened<'a>, ContainerError> {
    let (_, header) =
        SafeTensors::read_metadata(bytes).map_err(|e| ContainerError::Invalid(e.to_string()))?;
    let tensors =
        SafeTensors::deserialize(bytes).map_err(|e| ContainerError::Invalid(e.to_string()))?;
    let opened = Opened {
        tensors,
        metadata: header.metadata().clone().unwrap_or_default(),
    };
    let found = opened.text("format")?;
    if found != format {
        return Err(ContainerError::Metadata {
            key: "format",
            problem: format!("`{found}`, expected `{format}`"),
        });
    }
    let found = opened.text("version")?;
    if found != version {
        return Err(ContainerError::Metadata {
            key: "version",
            problem: format!("`{found}`, this build reads `{version}`"),
        });
    }
    Ok(opened)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::btf::{self, Btf};
    use crate::spmm::{pack, testing::sample_material};

    /// `bytes` (a valid container) with one more tensor, `extra`.
    fn with_extra_tensor(bytes: &[u8]) -> Vec<u8> {
        let st = SafeTensors::deserialize(bytes).expect("valid");
        let (_, header) = SafeTensors::read_metadata(bytes).expect("valid");
        let meta = header.metadata().clone().expect("metadata");
        let metadata: Vec<(&str, String)> =
            meta.iter().map(|(k, v)| (k.as_str(), v.clone())).collect();
        let owned: Vec<(String, Tensor)> = st
            .tensors()
            .into_iter()
            .map(|(name, view)| {
                let t = Tensor {
                    dtype: view.dtype(),
                    shape: view.shape().to_vec(),
                    data: view.data().to_vec(),
                };
                (name, t)
            })
            .collect();
        let mut tensors: BTreeMap<&str, Tensor> =
            owned.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
        let t = Tensor {
            dtype: Dtype::U8,
            shape: vec![1],
            data: vec![0],
        };
        tensors.insert("extra", t);
        encode(&metadata, &tensors)
    }

    /// The messages both formats share keep each format's own words: the size limit
    /// and the noun of the file, the format an unknown tensor is not part of.
    #[test]
    fn shared_messages_keep_each_formats_words() {
        let dir = tempfile::tempdir().expect("dir");
        let pack_path = dir.path().join("big.spmm");
        let file = std::fs::File::create(&pack_path).expect("create");
        // Sparse: the size is refused before anything is read.
        file.set_len(pack::MAX_FILE_BYTES + 1).expect("sparse file");
        assert_eq!(
            pack::read_pack(&pack_path)
                .expect_err("too large")
                .to_string(),
            format!(
                "`{}`: file is 2147483649 bytes, more than the 2147483648 a pack may have",
                pack_path.display()
            )
        );
        let btf_path = dir.path().join("big.btf");
        let file = std::fs::File::create(&btf_path).expect("create");
        file.set_len(btf::file::MAX_FILE_BYTES + 1)
            .expect("sparse file");
        assert_eq!(
            btf::file::read_btf(&btf_path)
                .expect_err("too large")
                .to_string(),
            format!(
                "`{}`: file is 8589934593 bytes, more than the 8589934592 a .btf may have",
                btf_path.display()
            )
        );

        let good = pack::encode_pack(
            &sample_material(2, 2, 1, None),
            pack::ResidualPrecision::F32,
        );
        assert_eq!(
            pack::decode_pack(&with_extra_tensor(&good))
                .expect_err("unknown tensor")
                .to_string(),
            "tensor `extra` is not part of format version 1"
        );
        let dirs = btf::directions::rings(&[(0.0, 1)]);
        let b = Btf::new(
            "t".into(),
            "".into(),
            1,
            1,
            dirs.clone(),
            dirs,
            vec![0.5; 3],
        )
        .expect("valid");
        let good = btf::file::encode_btf(&b, btf::file::BtfPrecision::F32).expect("encode");
        assert_eq!(
            btf::file::decode_btf(&with_extra_tensor(&good))
                .expect_err("unknown tensor")
                .to_string(),
            "tensor `extra` is not part of .btf format version 1"
        );
        let shape = ContainerError::Shape {
            name: "basis_normal",
            found: vec![2, 4],
            expected: format!("{:?}", [2, 3]),
        };
        assert_eq!(
            shape.to_string(),
            "tensor `basis_normal` has shape [2, 4], expected [2, 3]"
        );
    }
}
