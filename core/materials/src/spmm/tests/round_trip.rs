//! Pack round trips: byte-identical save and load, the file named, and Python reading
//! the documented tensors.

use super::*;

#[test]
fn save_load_save_is_byte_identical() {
    for (residual, precision) in [
        (None, ResidualPrecision::F32),
        (Some(3), ResidualPrecision::F32),
        (Some(2), ResidualPrecision::F16),
    ] {
        let m = sample_material(6, 5, 4, residual);
        let bytes = encode_pack(&m, precision);
        let back = decode_pack(&bytes).expect("a valid pack");
        assert_eq!(
            encode_pack(&back, precision),
            bytes,
            "{residual:?} {precision:?}"
        );
        assert_eq!(pack::residual_precision(&bytes), precision);
        if precision == ResidualPrecision::F32 {
            assert_eq!(back, m, "f32 tables load back exactly");
        }
    }
    // f16 tables round to the nearest half: within 2^-11 relative of the original.
    let m = sample_material(4, 4, 2, Some(2));
    let back = decode_pack(&encode_pack(&m, ResidualPrecision::F16)).expect("valid");
    let (a, b) = (
        m.residual().expect("residual"),
        back.residual().expect("residual"),
    );
    for (x, y) in a.mean.iter().zip(&b.mean) {
        assert!((x - y).abs() <= x.abs() * 4.9e-4 + 6e-8, "{x} {y}");
    }
}

#[test]
fn edited_flag_round_trips() {
    let mut m = sample_material(3, 3, 2, None);
    assert!(
        !decode_pack(&encode_pack(&m, ResidualPrecision::F32))
            .expect("valid")
            .edited()
    );
    m.mark_edited();
    assert!(
        decode_pack(&encode_pack(&m, ResidualPrecision::F32))
            .expect("valid")
            .edited()
    );
}

#[test]
fn file_round_trip_is_atomic_and_names_the_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("m.spmm");
    let m = sample_material(5, 3, 3, Some(1));
    pack::write_pack(&path, &m, ResidualPrecision::F32).expect("write");
    assert_eq!(pack::read_pack(&path).expect("read"), m);
    std::fs::write(&path, b"garbage").expect("write");
    let err = pack::read_pack(&path).expect_err("garbage");
    assert!(err.to_string().contains("m.spmm"), "{err}");
}

/// Python (`safetensors.numpy.load_file`) reads a pack with the documented names,
/// shapes and dtypes. Runs when `MESO_PYTHON` (default `python3`) has safetensors and
/// numpy; otherwise it says so and passes, except under `CI`, where it fails
/// (`container::python_with_safetensors`).
#[test]
fn python_reads_the_documented_tensors() {
    let Some(python) = crate::container::python_with_safetensors() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("m.spmm");
    let m = sample_material(5, 4, 3, Some(2));
    pack::write_pack(&path, &m, ResidualPrecision::F16).expect("write");
    let script = r#"
import sys, json
from safetensors import safe_open
from safetensors.numpy import load_file
t = load_file(sys.argv[1])
with safe_open(sys.argv[1], framework="np") as f:
    meta = f.metadata()
print(json.dumps({"meta": meta, "tensors": {k: [str(v.dtype), list(v.shape)] for k, v in t.items()},
                  "weight_rgb_sum": float(t["weight_rgb"].astype("float64").sum())}))
"#;
    let v = crate::container::python_json(&python, script, &path);
    assert_eq!(v["meta"]["format"], "meso-spmm");
    assert_eq!(v["meta"]["version"], "1");
    let nnz = m.weights().basis.len();
    let expect = |name: &str, dtype: &str, shape: serde_json::Value| {
        assert_eq!(
            v["tensors"][name],
            serde_json::json!([dtype, shape]),
            "{name}"
        );
    };
    expect("texel_cluster", "uint32", serde_json::json!([4, 5]));
    expect("cluster_basis_offsets", "uint32", serde_json::json!([4]));
    expect("weight_basis", "uint16", serde_json::json!([nnz]));
    expect("weight_rgb", "float32", serde_json::json!([nnz, 3]));
    expect(
        "basis_params",
        "float64",
        serde_json::json!([m.clusters().iter().map(|c| c.bases.len()).sum::<usize>(), 4]),
    );
    expect("residual_mean", "float16", serde_json::json!([3, 5, 4, 3]));
    expect(
        "residual_components",
        "float16",
        serde_json::json!([3, 2, 5, 4, 3]),
    );
    expect(
        "residual_coefficients",
        "float32",
        serde_json::json!([20, 2]),
    );
    let sum: f64 = m.weights().rgb.iter().flatten().map(|&x| x as f64).sum();
    assert!((v["weight_rgb_sum"].as_f64().expect("sum") - sum).abs() < 1e-9 * sum.max(1.0));

    // I8 components decode in Python with the documented formula to what Meso reads.
    pack::write_pack(&path, &m, ResidualPrecision::I8).expect("write");
    let script = r#"
import sys, json
import numpy as np
from safetensors.numpy import load_file
t = load_file(sys.argv[1])
q, e = t["residual_components"], t["residual_component_exponents"]
b = q.astype(np.float32) * np.exp2(e.astype(np.float32))[..., None, None]
print(json.dumps({"dtypes": [str(q.dtype), str(e.dtype)], "shape": list(e.shape),
                  "components": [float(x) for x in b.ravel()]}))
"#;
    let v = crate::container::python_json(&python, script, &path);
    assert_eq!(v["dtypes"], serde_json::json!(["int8", "int8"]));
    assert_eq!(v["shape"], serde_json::json!([3, 2, 5]));
    let read = pack::read_pack(&path).expect("read");
    let ours = &read.residual().expect("residual").components;
    let theirs: Vec<f32> = v["components"]
        .as_array()
        .expect("values")
        .iter()
        .map(|x| x.as_f64().expect("number") as f32)
        .collect();
    assert_eq!(&theirs, ours);
}
