//! The `.btf` file: a BTF in the safetensors container (like the `.spmm` pack) with
//! metadata `format = "meso-btf"`, `version = "1"` and three tensors, specified in
//! docs/formats/btf.md. Reading checks the container against the real file size,
//! then every metadata key, tensor name, dtype and shape, then the values (via
//! `Btf::new`); writing emits a deterministic header and goes through `write_atomic`.

use std::collections::BTreeMap;
use std::path::Path;

use glam::DVec3;
use safetensors::{Dtype, SafeTensors};

use super::{Btf, BtfError};
use crate::atomic::write_bytes_atomic;
use crate::container::{self, ContainerError, FileError, Tensor};

pub const FORMAT: &str = "meso-btf";
pub const VERSION: &str = "1";
/// Files larger than this are refused before reading.
pub const MAX_FILE_BYTES: u64 = 8 << 30;
/// Largest magnitude an f16 holds; larger values force F32 storage.
const F16_MAX: f32 = 65504.0;

/// Precision of the reflectance tensor on disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BtfPrecision {
    /// Half the size; relative rounding 2^-11 (about 5e-4), enough for 8-16 bit captures.
    F16,
    F32,
}

/// A `.btf` that cannot be read or written: the file and what is wrong with it.
pub type BtfFileError = FileError<BtfFileErrorKind>;

/// What is wrong with a `.btf`: what every container file can have wrong
/// (`ContainerError`), or what only a `.btf` can.
#[derive(Debug, thiserror::Error)]
pub enum BtfFileErrorKind {
    #[error(transparent)]
    Container(#[from] ContainerError),
    #[error(
        "values {precision:?} cannot hold reflectance[{index}] = {value} (F16 holds magnitudes up to 65504)"
    )]
    Precision {
        precision: BtfPrecision,
        index: usize,
        value: f32,
    },
    #[error("tensor {0}")]
    Btf(#[from] BtfError),
}

/// How a `.btf`'s size limit and unknown tensors are named in `ContainerError`.
const FILE_NOUN: &str = "a .btf";
const FORMAT_NOUN: &str = ".btf format";

/// Reads and validates a `.btf` file.
pub fn read_btf(path: &Path) -> Result<Btf, BtfFileError> {
    let at = |kind: BtfFileErrorKind| BtfFileError::at(path, kind);
    let bytes =
        container::read_limited(path, MAX_FILE_BYTES, FILE_NOUN).map_err(|e| at(e.into()))?;
    decode_btf(&bytes).map_err(at)
}

/// Writes a `.btf` atomically; F16 is refused when a value exceeds its range.
pub fn write_btf(path: &Path, btf: &Btf, precision: BtfPrecision) -> Result<(), BtfFileError> {
    let at = |kind: BtfFileErrorKind| BtfFileError::at(path, kind);
    let bytes = encode_btf(btf, precision).map_err(at)?;
    write_bytes_atomic(path, &bytes).map_err(|e| at(ContainerError::from(e).into()))
}

/// The precision to store `btf` in: F16 when every value fits, else F32.
pub fn best_precision(btf: &Btf) -> BtfPrecision {
    if btf.data().iter().all(|x| x.abs() <= F16_MAX) {
        BtfPrecision::F16
    } else {
        BtfPrecision::F32
    }
}

fn dir_bytes(d: &[DVec3]) -> Vec<u8> {
    d.iter()
        .flat_map(|v| v.to_array())
        .flat_map(f64::to_le_bytes)
        .collect()
}

/// Serialises a BTF: header with sorted keys, data in the order of decreasing element
/// size then name (every tensor aligned to its element size).
pub fn encode_btf(btf: &Btf, precision: BtfPrecision) -> Result<Vec<u8>, BtfFileErrorKind> {
    let (l, v) = (btf.light_dirs().len(), btf.view_dirs().len());
    let (w, h) = (btf.width() as usize, btf.height() as usize);
    let values = match precision {
        BtfPrecision::F32 => btf.data().iter().flat_map(|x| x.to_le_bytes()).collect(),
        BtfPrecision::F16 => {
            if let Some(index) = btf.data().iter().position(|x| x.abs() > F16_MAX) {
                return Err(BtfFileErrorKind::Precision {
                    precision,
                    index,
                    value: btf.data()[index],
                });
            }
            btf.data()
                .iter()
                .flat_map(|&x| half::f16::from_f32(x).to_le_bytes())
                .collect::<Vec<u8>>()
        }
    };
    let dtype = match precision {
        BtfPrecision::F16 => Dtype::F16,
        BtfPrecision::F32 => Dtype::F32,
    };
    let tensor = |dtype, shape, data| Tensor { dtype, shape, data };
    let tensors = BTreeMap::from([
        (
            "light_dirs",
            tensor(Dtype::F64, vec![l, 3], dir_bytes(btf.light_dirs())),
        ),
        (
            "view_dirs",
            tensor(Dtype::F64, vec![v, 3], dir_bytes(btf.view_dirs())),
        ),
        ("reflectance", tensor(dtype, vec![h, w, l, v, 3], values)),
    ]);
    let metadata = [
        ("format", FORMAT.to_string()),
        ("version", VERSION.to_string()),
        ("name", btf.name().to_string()),
        ("provenance", btf.provenance().to_string()),
        ("width", btf.width().to_string()),
        ("height", btf.height().to_string()),
    ];
    Ok(container::encode(&metadata, &tensors))
}

fn meta_count(
    meta: &std::collections::HashMap<String, String>,
    key: &'static str,
) -> Result<u32, BtfFileErrorKind> {
    let raw = meta
        .get(key)
        .ok_or_else(|| ContainerError::missing_metadata(key))?;
    let v: u32 = raw.parse().map_err(|_| ContainerError::Metadata {
        key,
        problem: format!("`{raw}` is not a count"),
    })?;
    if !(1..=super::MAX_SIDE).contains(&v) {
        return Err(ContainerError::Metadata {
            key,
            problem: format!("{v} is outside 1..={}", super::MAX_SIDE),
        }
        .into());
    }
    Ok(v)
}

fn directions(st: &SafeTensors, name: &'static str) -> Result<Vec<DVec3>, ContainerError> {
    let t = st
        .tensor(name)
        .map_err(|_| ContainerError::MissingTensor(name))?;
    if t.dtype() != Dtype::F64 {
        return Err(ContainerError::Dtype {
            name,
            found: format!("{:?}", t.dtype()),
            expected: "F64",
        });
    }
    if t.shape().len() != 2 || t.shape()[1] != 3 {
        return Err(ContainerError::Shape {
            name,
            found: t.shape().to_vec(),
            expected: "[N, 3]".into(),
        });
    }
    Ok(dirs_of_bytes(t.data()))
}

/// Directions from their tensor's bytes (`dir_bytes` read back: three little-endian
/// f64 each; a trailing partial direction is ignored, the shape check names it).
pub(crate) fn dirs_of_bytes(bytes: &[u8]) -> Vec<DVec3> {
    bytes
        .chunks_exact(24)
        .map(|c| {
            let f = |k: usize| {
                let mut b = [0u8; 8];
                b.copy_from_slice(&c[k * 8..k * 8 + 8]);
                f64::from_le_bytes(b)
            };
            DVec3::new(f(0), f(1), f(2))
        })
        .collect()
}

/// Parses and validates `.btf` bytes (see `read_btf`).
pub fn decode_btf(bytes: &[u8]) -> Result<Btf, BtfFileErrorKind> {
    let container::Opened {
        tensors: st,
        metadata: meta,
    } = container::open(bytes, FORMAT, VERSION)?;
    let text = |key: &'static str| {
        meta.get(key)
            .cloned()
            .ok_or_else(|| ContainerError::missing_metadata(key))
    };
    let name = text("name")?;
    let provenance = text("provenance")?;
    let width = meta_count(&meta, "width")?;
    let height = meta_count(&meta, "height")?;
    for n in st.names() {
        if !["light_dirs", "view_dirs", "reflectance"].contains(&n) {
            return Err(ContainerError::UnknownTensor {
                name: n.to_string(),
                format: FORMAT_NOUN,
                version: VERSION,
            }
            .into());
        }
    }
    let light_dirs = directions(&st, "light_dirs")?;
    let view_dirs = directions(&st, "view_dirs")?;
    let t = st
        .tensor("reflectance")
        .map_err(|_| ContainerError::MissingTensor("reflectance"))?;
    let expected = [
        height as usize,
        width as usize,
        light_dirs.len(),
        view_dirs.len(),
        3,
    ];
    if t.shape() != expected {
        return Err(ContainerError::Shape {
            name: "reflectance",
            found: t.shape().to_vec(),
            expected: format!("{expected:?} (height, width, lights, views, rgb)"),
        }
        .into());
    }
    let data: Vec<f32> = match t.dtype() {
        Dtype::F16 => t
            .data()
            .chunks_exact(2)
            .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect(),
        Dtype::F32 => t
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        other => {
            return Err(ContainerError::Dtype {
                name: "reflectance",
                found: format!("{other:?}"),
                expected: "F16 or F32",
            }
            .into());
        }
    };
    Ok(Btf::new(
        name, provenance, width, height, light_dirs, view_dirs, data,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::btf::directions;

    fn small() -> Btf {
        let dirs = directions::rings(&[(0.0, 1), (45.0, 3)]);
        let data: Vec<f32> = (0..2 * 3 * 16 * 3).map(|i| i as f32 * 0.25).collect();
        Btf::new("t".into(), "test".into(), 2, 3, dirs.clone(), dirs, data).expect("valid")
    }

    /// Rewrites the header JSON of `bytes` with `edit` (offsets unchanged).
    fn edit_header(bytes: &[u8], edit: impl Fn(&mut serde_json::Value)) -> Vec<u8> {
        let n = u64::from_le_bytes(bytes[..8].try_into().expect("8")) as usize;
        let mut h: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).expect("json");
        edit(&mut h);
        let mut hb = serde_json::to_vec(&h).expect("json");
        while !hb.len().is_multiple_of(8) {
            hb.push(b' ');
        }
        let mut out = (hb.len() as u64).to_le_bytes().to_vec();
        out.extend(hb);
        out.extend_from_slice(&bytes[8 + n..]);
        out
    }

    #[test]
    fn round_trip_is_exact_and_deterministic() {
        let b = small();
        for p in [BtfPrecision::F32, BtfPrecision::F16] {
            let bytes = encode_btf(&b, p).expect("encode");
            // Quarter steps up to 71.75 are exact in f16.
            assert_eq!(decode_btf(&bytes).expect("decode"), b);
            assert_eq!(
                encode_btf(&decode_btf(&bytes).expect("decode"), p).expect("encode"),
                bytes
            );
        }
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("a.btf");
        write_btf(&path, &b, best_precision(&b)).expect("write");
        assert_eq!(read_btf(&path).expect("read"), b);
        assert_eq!(best_precision(&b), BtfPrecision::F16);
    }

    #[test]
    fn corrupt_files_are_refused_with_the_place_named() {
        let good = encode_btf(&small(), BtfPrecision::F32).expect("encode");
        let cases: Vec<(Vec<u8>, &[&str])> = vec![
            (good[..good.len() - 4].to_vec(), &["safetensors"]),
            (b"garbage".to_vec(), &["safetensors"]),
            (
                edit_header(&good, |h| h["__metadata__"]["format"] = "meso-spmm".into()),
                &["format", "meso-spmm"],
            ),
            (
                edit_header(&good, |h| h["__metadata__"]["version"] = "2".into()),
                &["version", "`2`"],
            ),
            (
                edit_header(&good, |h| h["__metadata__"]["width"] = "3".into()),
                &["reflectance", "shape", "[3, 3, 4, 4, 3]"],
            ),
            (
                edit_header(&good, |h| h["__metadata__"]["width"] = "0".into()),
                &["width", "1..="],
            ),
            (
                edit_header(&good, |h| {
                    h["__metadata__"]
                        .as_object_mut()
                        .expect("map")
                        .remove("name");
                }),
                &["`name`", "missing"],
            ),
            (
                edit_header(&good, |h| {
                    let t = h["light_dirs"].clone();
                    h.as_object_mut().expect("map").insert("extra".into(), t);
                }),
                &[],
            ),
            (
                edit_header(&good, |h| h["light_dirs"]["dtype"] = "F32".into()),
                &[],
            ),
        ];
        for (bytes, needles) in cases {
            let e = decode_btf(&bytes).expect_err("must be refused").to_string();
            for n in needles {
                assert!(e.contains(n), "`{e}` should mention `{n}`");
            }
        }
        // A NaN value names its texel, light, view and channel.
        let mut b = good.clone();
        let n = u64::from_le_bytes(b[..8].try_into().expect("8")) as usize;
        // light_dirs and view_dirs (F64, 4 x 3 each) come first, then reflectance.
        // Texel 1, light 2, view 3, channel 1 of a 4 x 4 direction table.
        let texel_1 = 4 * 4 * 3;
        let at = 8 + n + 2 * 4 * 3 * 8 + (texel_1 + (2 * 4 + 3) * 3 + 1) * 4;
        b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        let e = decode_btf(&b).expect_err("NaN").to_string();
        assert!(
            e.contains("texel 1, light 2, view 3, channel 1") && e.contains("not finite"),
            "{e}"
        );
        // A direction below the horizon.
        let mut b = good.clone();
        let at = 8 + n + 3 * 8 * 3 + 2 * 8; // light_dirs[3].z
        b[at..at + 8].copy_from_slice(&(-0.5f64).to_le_bytes());
        let e = decode_btf(&b).expect_err("below horizon").to_string();
        assert!(e.contains("light_dirs[3]") && e.contains("z > 0"), "{e}");
        // Too large for F16.
        let mut big = small().data().to_vec();
        big[5] = 1e6;
        let dirs = small().light_dirs().to_vec();
        let b = Btf::new("t".into(), "".into(), 2, 3, dirs.clone(), dirs, big).expect("valid");
        assert!(encode_btf(&b, BtfPrecision::F16).is_err());
        assert_eq!(best_precision(&b), BtfPrecision::F32);
    }

    /// Python (`safetensors.numpy.load_file`, independent of our reader) finds the
    /// metadata, names, dtypes and shapes of docs/formats/btf.md, and the values at
    /// `reflectance[row, column, light, view, channel]` with row 0 the top row.
    /// Skipped without Python's safetensors/numpy, except under `CI`
    /// (`container::python_with_safetensors`).
    #[test]
    fn python_reads_the_documented_tensors() {
        let Some(python) = crate::container::python_with_safetensors() else {
            return;
        };
        let b = small();
        let dir = tempfile::tempdir().expect("dir");
        let script = r#"
import sys, json
from safetensors import safe_open
from safetensors.numpy import load_file
t = load_file(sys.argv[1])
with safe_open(sys.argv[1], framework="np") as f:
    meta = f.metadata()
r = t["reflectance"]
print(json.dumps({"meta": meta,
                  "tensors": {k: [str(v.dtype), list(v.shape)] for k, v in t.items()},
                  "light_dirs": t["light_dirs"].tolist(), "view_dirs": t["view_dirs"].tolist(),
                  "values": [[[[[float(r[y, x, l, v, c]) for c in range(3)]
                                for v in range(r.shape[3])] for l in range(r.shape[2])]
                              for x in range(r.shape[1])] for y in range(r.shape[0])]}))
"#;
        for (p, dtype) in [
            (BtfPrecision::F16, "float16"),
            (BtfPrecision::F32, "float32"),
        ] {
            let path = dir.path().join(format!("{dtype}.btf"));
            write_btf(&path, &b, p).expect("write");
            let v = crate::container::python_json(&python, script, &path);
            let meta = &v["meta"];
            assert_eq!(meta["format"], "meso-btf");
            assert_eq!(meta["version"], "1");
            assert_eq!(meta["name"], "t");
            assert_eq!(meta["provenance"], "test");
            assert_eq!(
                (&meta["width"], &meta["height"]),
                (&"2".into(), &"3".into())
            );
            let (l, vn) = (b.light_dirs().len(), b.view_dirs().len());
            assert_eq!(
                v["tensors"],
                serde_json::json!({
                    "light_dirs": ["float64", [l, 3]],
                    "view_dirs": ["float64", [vn, 3]],
                    "reflectance": [dtype, [3, 2, l, vn, 3]],
                }),
                "{dtype}"
            );
            let dirs =
                |d: &[DVec3]| serde_json::json!(d.iter().map(|d| d.to_array()).collect::<Vec<_>>());
            assert_eq!(v["light_dirs"], dirs(b.light_dirs()));
            assert_eq!(v["view_dirs"], dirs(b.view_dirs()));
            // Quarter steps up to 71.75 are exact in f16 too.
            for y in 0..3 {
                for x in 0..2 {
                    for li in 0..l {
                        for vi in 0..vn {
                            let want = b.value(y * 2 + x, li, vi);
                            for (c, w) in want.iter().enumerate() {
                                assert_eq!(
                                    v["values"][y][x][li][vi][c].as_f64(),
                                    Some(*w as f64),
                                    "{dtype} row {y} column {x} light {li} view {vi} channel {c}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
