//! The safetensors container as Meso writes and opens it (`.spmm` packs, `.btf` BTFs).
//! Writing is our own and deterministic: the safetensors crate serialises its metadata
//! map in random order, which would break byte-identical round trips. Keys are sorted,
//! tensors ordered by decreasing element size then name (so each starts aligned to its
//! element size), the header padded with spaces to 8 bytes. Opening checks what both
//! formats share: the container parses and its `format` and `version` match.

use std::collections::{BTreeMap, HashMap};

use safetensors::{Dtype, SafeTensors};
use serde_json::json;

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

/// Why a container cannot be opened.
#[derive(Debug)]
pub enum OpenError {
    Container(String),
    Metadata { key: &'static str, problem: String },
}

/// A parsed container and its metadata.
pub struct Opened<'a> {
    pub tensors: SafeTensors<'a>,
    pub metadata: HashMap<String, String>,
}

impl Opened<'_> {
    /// A required metadata string.
    pub fn text(&self, key: &'static str) -> Result<String, OpenError> {
        self.metadata.get(key).cloned().ok_or(OpenError::Metadata {
            key,
            problem: "missing".into(),
        })
    }
}

/// Parses `bytes` and checks `format` and `version`.
pub fn open<'a>(bytes: &'a [u8], format: &str, version: &str) -> Result<Opened<'a>, OpenError> {
    let (_, header) =
        SafeTensors::read_metadata(bytes).map_err(|e| OpenError::Container(e.to_string()))?;
    let tensors =
        SafeTensors::deserialize(bytes).map_err(|e| OpenError::Container(e.to_string()))?;
    let opened = Opened {
        tensors,
        metadata: header.metadata().clone().unwrap_or_default(),
    };
    let found = opened.text("format")?;
    if found != format {
        return Err(OpenError::Metadata {
            key: "format",
            problem: format!("`{found}`, expected `{format}`"),
        });
    }
    let found = opened.text("version")?;
    if found != version {
        return Err(OpenError::Metadata {
            key: "version",
            problem: format!("`{found}`, this build reads `{version}`"),
        });
    }
    Ok(opened)
}
