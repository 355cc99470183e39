//! Pack round trips, validation messages and a corruption corpus: every rejection
//! names the tensor or metadata key at fault, and no input makes the reader panic.

use glam::DVec3;
use proptest::prelude::*;

use super::pack::{PackErrorKind, ResidualPrecision, decode_pack, encode_pack};
use crate::container::ContainerError;
pub(crate) use super::testing::sample_material;
use super::*;

/// `m` with its residual's mean and components rounded to half floats, as a pack read
/// from a file stored in f16 holds them (prepared tables are then half floats).
pub(crate) fn with_half_residual(m: &SpmmMaterial) -> SpmmMaterial {
    let mut r = m.residual().expect("a residual").clone();
    for x in r.mean.iter_mut().chain(r.components.iter_mut()) {
        *x = half::f16::from_f32(*x).to_f32();
    }
    let h = with_residual(m, r);
    assert!(h.residual_is_half() && !m.residual_is_half());
    h
}

/// `m` with its residual replaced by `r`.
fn with_residual(m: &SpmmMaterial, r: Residual) -> SpmmMaterial {
    SpmmMaterial::new(
        m.name().into(),
        m.provenance().into(),
        m.width(),
        m.height(),
        m.clusters().to_vec(),
        m.texel_cluster().to_vec(),
        m.weights().clone(),
        Some(r),
    )
    .expect("valid")
}

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

/// Re-encodes a pack with one tensor's raw data replaced (same dtype and shape).
fn with_tensor(bytes: &[u8], name: &str, edit: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).expect("JSON header");
    let info = &header[name]["data_offsets"];
    let (b, e) = (
        info[0].as_u64().expect("offset") as usize,
        info[1].as_u64().expect("offset") as usize,
    );
    let mut data = bytes[8 + n + b..8 + n + e].to_vec();
    edit(&mut data);
    assert_eq!(data.len(), e - b, "edits keep the size");
    let mut out = bytes.to_vec();
    out[8 + n + b..8 + n + e].copy_from_slice(&data);
    out
}

/// Re-encodes a pack with its JSON header edited.
fn with_header(bytes: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    let mut header: serde_json::Value =
        serde_json::from_slice(&bytes[8..8 + n]).expect("JSON header");
    edit(&mut header);
    let mut h = serde_json::to_vec(&header).expect("JSON");
    while !h.len().is_multiple_of(8) {
        h.push(b' ');
    }
    let mut out = (h.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&h);
    out.extend_from_slice(&bytes[8 + n..]);
    out
}

fn rejection(bytes: &[u8]) -> String {
    match decode_pack(bytes) {
        Ok(_) => panic!("a corrupted pack was accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn each_fault_is_named() {
    let good = encode_pack(&sample_material(4, 3, 3, Some(2)), ResidualPrecision::F32);
    let cases: Vec<(Vec<u8>, &[&str])> = vec![
        (
            with_tensor(&good, "basis_model", |d| d[1] = 9),
            &["basis_model", "[1]", "9"],
        ),
        (
            with_tensor(&good, "basis_params", |d| {
                d[..8].copy_from_slice(&f64::NAN.to_le_bytes())
            }),
            &["basis_params`[0][0]", "lambertian"],
        ),
        (
            with_tensor(&good, "basis_params", |d| {
                d[32..40].copy_from_slice(&f64::NAN.to_le_bytes())
            }),
            &["basis 1", "ax", "NaN"],
        ),
        (
            with_tensor(&good, "basis_params", |d| {
                d[4 * 8 + 8..4 * 8 + 16].copy_from_slice(&5.0f64.to_le_bytes())
            }),
            &["basis 1", "ay", "5"],
        ),
        (
            with_tensor(&good, "basis_normal", |d| {
                d[16..24].copy_from_slice(&2.0f64.to_le_bytes())
            }),
            &["basis 0", "normal"],
        ),
        (
            with_tensor(&good, "basis_normal", |d| {
                d[16..24].copy_from_slice(&(-1.0f64).to_le_bytes())
            }),
            &["basis 0", "normal"],
        ),
        (
            with_tensor(&good, "texel_cluster", |d| {
                d[4..8].copy_from_slice(&77u32.to_le_bytes())
            }),
            &["texel_cluster[1]", "77"],
        ),
        (
            with_tensor(&good, "weight_basis", |d| {
                d[..2].copy_from_slice(&500u16.to_le_bytes())
            }),
            &["weight_basis[0]", "500"],
        ),
        (
            with_tensor(&good, "weight_offsets", |d| {
                d[8..12].copy_from_slice(&0u32.to_le_bytes())
            }),
            &["weight_offsets[2]"],
        ),
        (
            with_tensor(&good, "weight_rgb", |d| {
                d[4..8].copy_from_slice(&f32::INFINITY.to_le_bytes())
            }),
            &["weight_rgb[1]", "inf"],
        ),
        (
            with_tensor(&good, "residual_mean", |d| {
                d[..4].copy_from_slice(&f32::NAN.to_le_bytes())
            }),
            &["residual_mean[0]"],
        ),
        (
            with_tensor(&good, "light_dirs", |d| {
                d[16..24].copy_from_slice(&(-0.5f64).to_le_bytes())
            }),
            &["light_dirs[0]"],
        ),
        (
            with_header(&good, |h| h["__metadata__"]["format"] = "other".into()),
            &["format", "other"],
        ),
        (
            with_header(&good, |h| h["__metadata__"]["version"] = "2".into()),
            &["version", "2"],
        ),
        (
            with_header(&good, |h| h["__metadata__"]["width"] = "5".into()),
            &["texel_cluster", "shape"],
        ),
        (
            with_header(&good, |h| h["__metadata__"]["clusters"] = "x".into()),
            &["clusters", "x"],
        ),
        (
            with_header(&good, |h| h["__metadata__"]["npca"] = "99999".into()),
            &["npca", "99999"],
        ),
        (
            with_header(&good, |h| h["texel_cluster"]["dtype"] = "I32".into()),
            &["texel_cluster", "dtype"],
        ),
        (
            with_header(&good, |h| {
                let v = h["basis_model"].clone();
                h.as_object_mut().expect("map").remove("basis_model");
                h["basis_mdoel"] = v;
            }),
            &["basis_mdoel"],
        ),
        (
            with_header(&good, |h| {
                h["weight_rgb"]["data_offsets"][1] = 10_000_000.into()
            }),
            &["safetensors"],
        ),
    ];
    for (i, (bytes, needles)) in cases.iter().enumerate() {
        let msg = match decode_pack(bytes) {
            Ok(_) => panic!("case {i} ({needles:?}) was accepted"),
            Err(e) => e.to_string(),
        };
        for needle in *needles {
            assert!(
                msg.contains(needle),
                "case {i}: `{needle}` missing from: {msg}"
            );
        }
    }
}

#[test]
fn truncation_at_every_length_is_rejected() {
    let good = encode_pack(&sample_material(3, 2, 2, Some(1)), ResidualPrecision::F16);
    for len in 0..good.len() {
        let msg = rejection(&good[..len]);
        assert!(!msg.is_empty());
    }
}

#[test]
fn a_header_claiming_huge_sizes_does_not_allocate() {
    // A header length of 2^60 and a tensor declaring 2^40 elements: both rejected
    // from the real buffer size, before any allocation of that size.
    let good = encode_pack(&sample_material(2, 2, 1, None), ResidualPrecision::F32);
    let mut huge = good.clone();
    huge[..8].copy_from_slice(&(1u64 << 60).to_le_bytes());
    assert!(rejection(&huge).contains("safetensors"));
    let claim = with_header(&good, |h| {
        h["weight_rgb"]["shape"] = serde_json::json!([1u64 << 40, 3])
    });
    assert!(!rejection(&claim).is_empty());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]
    /// Random byte edits anywhere (header or data): the reader returns Ok or a named
    /// error, never panics. 2000 cases x 64 edits each = 128 000 mutated inputs.
    #[test]
    fn mutated_packs_never_panic(edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8), seed in any::<u64>()) {
        let good = encode_pack(&sample_material(3, 3, 2, Some(1)), ResidualPrecision::F32);
        for k in 0..64u64 {
            let mut bytes = good.clone();
            for (i, (pos, value)) in edits.iter().enumerate() {
                let at = (*pos ^ (seed.wrapping_mul(k + 1) as usize).rotate_left(i as u32)) % bytes.len();
                bytes[at] = *value ^ (k as u8);
            }
            if let Err(e) = decode_pack(&bytes) {
                prop_assert!(!e.to_string().is_empty());
            }
        }
    }
}

#[test]
fn errors_have_the_expected_kind() {
    let good = encode_pack(&sample_material(2, 2, 1, None), ResidualPrecision::F32);
    let missing = with_header(&good, |h| {
        h.as_object_mut().expect("map").remove("weight_basis");
    });
    assert!(matches!(
        decode_pack(&missing),
        Err(PackErrorKind::Container(
            ContainerError::Invalid(_) | ContainerError::MissingTensor(_)
        ))
    ));
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

mod evaluation {
    use glam::{DVec2, DVec3};

    use super::sample_material;
    use crate::brdf::warp::spherical;
    use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
    use crate::rng::SampleStream;
    use crate::spmm::{Cluster, EvalSettings, SparseWeights, SpmmMaterial, TexelFilter};

    fn one_texel(bases: Vec<BasisFunction>, rgb: Vec<[f32; 3]>) -> SpmmMaterial {
        let n = bases.len();
        SpmmMaterial::new(
            "t".into(),
            "test".into(),
            1,
            1,
            vec![Cluster { bases }],
            vec![0],
            SparseWeights {
                offsets: vec![0, n as u32],
                basis: (0..n as u16).collect(),
                rgb,
            },
            None,
        )
        .expect("valid")
    }

    #[test]
    fn one_lambertian_basis_is_alpha_over_pi_times_cos() {
        let lamb = BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
            .expect("unit");
        let m = one_texel(vec![lamb], vec![[0.8, 0.5, 0.2]]);
        for (ci, co) in [(1.0, 1.0), (0.5, 0.9), (1e-3, 0.3)] {
            let (wi, wo) = (spherical(ci, 0.4), spherical(co, 2.0));
            let got = m.eval_texel(0, wi, wo, true, usize::MAX);
            let expected =
                DVec3::new(0.8f32 as f64, 0.5f32 as f64, 0.2f32 as f64) * ci / std::f64::consts::PI;
            assert!((got - expected).length() < 1e-15, "{got} vs {expected}");
        }
        assert_eq!(
            m.eval_texel(0, spherical(-0.2, 0.0), DVec3::Z, true, 8),
            DVec3::ZERO
        );
    }

    #[test]
    fn a_basis_sum_is_the_sum_of_the_brdf_values() {
        // With n_j = z, rho_j = f_j cos_i: compare against AnalyticBrdf::eval directly.
        let brdfs = [
            AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.1), ("ay", 0.3)]).expect("valid"),
            AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.2), ("f0", 0.5)]).expect("valid"),
            AnalyticBrdf::new(BrdfModel::OrenNayar, &[("sigma", 0.4)]).expect("valid"),
        ];
        let weights = [[0.2f32, 0.3, 0.4], [0.5, 0.5, 0.1], [0.9, 0.2, 0.05]];
        let bases = brdfs
            .iter()
            .map(|b| BasisFunction::new(*b, DVec3::Z).expect("unit"))
            .collect();
        let m = one_texel(bases, weights.to_vec());
        for k in 0..200u64 {
            let mut s = SampleStream::new(&[8, k]);
            let wi = spherical(s.next().max(1e-3), 6.3 * s.next());
            let wo = spherical(s.next().max(1e-3), 6.3 * s.next());
            let expected: DVec3 = brdfs
                .iter()
                .zip(weights)
                .map(|(b, w)| {
                    DVec3::new(w[0] as f64, w[1] as f64, w[2] as f64) * b.eval(wi, wo) * wi.z
                })
                .sum();
            let got = m.eval_texel(0, wi, wo, true, usize::MAX);
            assert!(
                (got - expected).length() <= 1e-12 * expected.length().max(1e-30),
                "{got} vs {expected}"
            );
        }
    }

    /// The residual part alone at texel `t`: evaluation with it minus without it.
    fn residual_part(m: &SpmmMaterial, t: usize, wi: DVec3, wo: DVec3, max_npca: usize) -> DVec3 {
        m.eval_texel(t, wi, wo, true, max_npca) - m.eval_texel(t, wi, wo, false, max_npca)
    }

    #[test]
    fn residual_is_exact_at_the_tabulated_directions_and_honours_npca() {
        let m = sample_material(4, 3, 3, Some(3));
        let r = m.residual().expect("residual");
        let (nl, nv, k) = (r.light_dirs.len(), r.view_dirs.len(), r.npca);
        for t in [0usize, 5, 11] {
            let c = m.texel_cluster()[t] as usize;
            for l in 0..nl {
                for v in 0..nv {
                    let rgb = |table: &[f32], i: usize| {
                        DVec3::new(table[i] as f64, table[i + 1] as f64, table[i + 2] as f64)
                    };
                    let mean = rgb(&r.mean, ((c * nl + l) * nv + v) * 3);
                    for limit in [0, 1, k, usize::MAX] {
                        let mut expected = mean;
                        for kk in 0..k.min(limit) {
                            expected += r.coefficients[t * k + kk] as f64
                                * rgb(&r.components, (((c * k + kk) * nl + l) * nv + v) * 3);
                        }
                        let got = residual_part(&m, t, r.light_dirs[l], r.view_dirs[v], limit);
                        assert!(
                            (got - expected).length() < 1e-12,
                            "t {t} l {l} v {v} npca {limit}: {got} vs {expected}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn residual_is_continuous_between_table_directions() {
        let m = sample_material(2, 2, 1, Some(2));
        let wo = spherical(0.7, 1.0);
        let mut prev = residual_part(&m, 0, DVec3::Z, wo, 2);
        for k in 1..=5000 {
            let theta = 1.5 * k as f64 / 5000.0;
            let v = residual_part(&m, 0, spherical(theta.cos(), 0.8), wo, 2);
            assert!(
                (v - prev).length() < 5e-3,
                "jump at theta {theta}: {prev} -> {v}"
            );
            prev = v;
        }
    }

    #[test]
    fn uv_lookup_tiles_wraps_and_filters() {
        let m = sample_material(4, 2, 3, None);
        let s = DVec2::ONE;
        // v up, row 0 on top: uv (0.1, 0.9) is column 0, row 0; (0.9, 0.1) column 3, row 1.
        assert_eq!(m.texel_at(DVec2::new(0.1, 0.9), s), 0);
        assert_eq!(m.texel_at(DVec2::new(0.9, 0.1), s), 7);
        assert_eq!(
            m.texel_at(DVec2::new(1.1, -0.1), s),
            m.texel_at(DVec2::new(0.1, 0.9), s)
        );
        assert_eq!(
            m.texel_at(DVec2::new(0.3, 0.9), DVec2::splat(2.0)),
            m.texel_at(DVec2::new(0.6, 0.8), s)
        );
        let (wi, wo) = (spherical(0.8, 0.3), spherical(0.6, 2.0));
        let nearest = EvalSettings::default();
        let bilinear = EvalSettings {
            filter: TexelFilter::Bilinear,
            ..EvalSettings::default()
        };
        // At a texel centre the two filters agree.
        let centre = DVec2::new(1.5 / 4.0, 1.0 - 0.5 / 2.0);
        let (a, b) = (
            m.eval_uv(centre, wi, wo, &nearest),
            m.eval_uv(centre, wi, wo, &bilinear),
        );
        assert!((a - b).length() < 1e-12, "{a} vs {b}");
        // Bilinear is continuous across the wrap seam at u = 0.
        let (l, r) = (
            m.eval_uv(DVec2::new(1.0 - 1e-9, 0.3), wi, wo, &bilinear),
            m.eval_uv(DVec2::new(1e-9, 0.3), wi, wo, &bilinear),
        );
        assert!((l - r).length() < 1e-6, "{l} vs {r}");
        assert_eq!(
            m.eval_uv(DVec2::new(f64::NAN, 0.0), wi, wo, &nearest),
            DVec3::ZERO
        );
    }
}

mod prepared {
    use glam::{DVec2, DVec3};

    use super::{sample_material, with_half_residual};
    use crate::brdf::warp::spherical;
    use crate::rng::SampleStream;
    use crate::spmm::{EvalSettings, PrepareRequest, SpmmMaterial, TexelFilter};

    fn points(n: u64, texels: usize) -> Vec<(usize, DVec3, DVec3)> {
        (0..n)
            .map(|k| {
                let mut s = SampleStream::new(&[21, k]);
                let t = (s.next() * texels as f64) as usize;
                (
                    t,
                    spherical(s.next().max(0.05), 6.3 * s.next()),
                    spherical(s.next().max(0.05), 6.3 * s.next()),
                )
            })
            .collect()
    }

    /// After a weight edit the residual tables are reused, after a residual edit
    /// rebuilt: either way the data evaluates exactly as a fresh preparation.
    #[test]
    fn data_prepared_after_an_edit_equals_a_fresh_preparation() {
        use crate::spmm::WeightTarget;
        let m = sample_material(6, 5, 4, Some(3));
        let request = PrepareRequest {
            used_clusters: None,
            residual: true,
            max_npca: 2,
        };
        let before = m.prepare(&request);
        let scaled = m
            .with_weight_scale(&WeightTarget::basis(1, 0), [2.0, 0.5, 1.0])
            .expect("valid");
        let off = m.with_cluster_residual_off(2).expect("valid");
        for after in [&scaled, &off] {
            let reused = after.prepare_after_edit(&request, &m, &before);
            let fresh = after.prepare(&request);
            assert_eq!(reused.bytes(), fresh.bytes());
            for (t, wi, wo) in points(500, 30) {
                assert_eq!(reused.eval_texel(t, wi, wo), fresh.eval_texel(t, wi, wo));
                assert_eq!(
                    reused.eval_texel(t, wi, wo),
                    after.eval_texel(t, wi, wo, true, 2)
                );
            }
        }
        // The weight edit changed what the texels of cluster 1 show.
        let t = (0..30)
            .find(|&t| m.texel_cluster()[t] == 1 && m.texel_weights(t).any(|(j, _)| j == 0))
            .expect("a texel of cluster 1 weighs basis 0");
        let (wi, wo) = (DVec3::new(0.3, 0.1, 0.9).normalize(), DVec3::Z);
        assert_ne!(
            scaled
                .prepare_after_edit(&request, &m, &before)
                .eval_texel(t, wi, wo),
            before.eval_texel(t, wi, wo)
        );
    }

    /// Bit for bit, whatever the layout: 3 components (cells packed), 8 (cells padded
    /// to whole cache lines, `cell_stride`), fewer kept than stored, none, or no
    /// residual, in f32 and in half floats; on x86-64 with AVX (and F16C) this checks
    /// the 4-wide cell sums too.
    #[test]
    fn prepared_evaluation_equals_the_reference() {
        let three = sample_material(6, 5, 4, Some(3));
        let eight = sample_material(6, 5, 4, Some(8));
        // Tables of half floats: 3 components packed, 8 padded to one line per cell.
        let (half_three, half_eight) = (with_half_residual(&three), with_half_residual(&eight));
        for (m, residual, max_npca) in [
            (&three, true, usize::MAX),
            (&three, true, 2),
            (&three, true, 0),
            (&three, false, usize::MAX),
            (&eight, true, usize::MAX),
            (&eight, true, 7),
            (&half_three, true, usize::MAX),
            (&half_three, true, 0),
            (&half_eight, true, usize::MAX),
            (&half_eight, true, 5),
        ] {
            let p = m.prepare(&PrepareRequest {
                used_clusters: None,
                residual,
                max_npca,
            });
            for (t, wi, wo) in points(500, 30) {
                assert_eq!(
                    p.eval_texel(t, wi, wo),
                    m.eval_texel(t, wi, wo, residual, max_npca),
                    "{residual} {max_npca}"
                );
            }
            let s = EvalSettings {
                residual,
                max_npca,
                filter: TexelFilter::Bilinear,
                uv_scale: DVec2::new(2.0, 3.0),
            };
            let (wi, wo) = (spherical(0.7, 0.2), spherical(0.5, 2.2));
            for k in 0..100 {
                let uv = DVec2::new(0.013 * k as f64, 1.0 - 0.021 * k as f64);
                assert_eq!(p.eval_uv(uv, wi, wo, &s), m.eval_uv(uv, wi, wo, &s));
            }
        }
    }

    #[test]
    fn only_used_clusters_and_kept_components_are_held() {
        let m = sample_material(6, 5, 4, Some(3));
        let (l, v, texels) = (5, 4, 30);
        let used = m.clusters_of_texels((0..texels).filter(|&t| m.texel_cluster()[t] == 1));
        assert_eq!(used, vec![false, true, false, false]);
        let full = m.prepare(&PrepareRequest {
            used_clusters: None,
            residual: true,
            max_npca: 3,
        });
        let part = m.prepare(&PrepareRequest {
            used_clusters: Some(used),
            residual: true,
            max_npca: 2,
        });
        assert_eq!((full.clusters_used(), part.clusters_used()), (4, 1));
        full.make_all_resident();
        part.make_all_resident();
        // Residual bytes: per used cluster L x V cells of (1 + k) RGB floats, the table
        // rounded up to whole 64-byte lines (k = 2: 180 floats take 12 lines of 16),
        // plus k coefficients per texel.
        assert_eq!(full.bytes().residual, (4 * l * v * 4 * 3 + texels * 3) * 4);
        assert_eq!(part.bytes().residual, (12 * 16 + texels * 2) * 4);
        let off = m.prepare(&PrepareRequest {
            used_clusters: None,
            residual: false,
            max_npca: 3,
        });
        assert_eq!(off.bytes().residual, 0);
        assert!(off.bytes().total() < part.bytes().total());
        // Half-float tables: k = 3, 12 halves a cell, 20 cells in 8 lines plus the
        // spare one, per cluster; the estimate says the same.
        let half = with_half_residual(&m);
        let request = PrepareRequest {
            used_clusters: None,
            residual: true,
            max_npca: 3,
        };
        let halved = half.prepare(&request);
        halved.make_all_resident();
        assert_eq!(halved.bytes().residual, 4 * 9 * 64 + texels * 3 * 4);
        assert_eq!(halved.bytes(), half.prepared_bytes(&request));
        // The estimate a render reports for materials it has not prepared.
        for (prepared, request) in [
            (&full, (None, true, 3)),
            (&part, (Some(m.clusters_of_texels([1usize, 5])), true, 2)),
            (&off, (None, false, 3)),
        ] {
            let request = PrepareRequest {
                used_clusters: request.0,
                residual: request.1,
                max_npca: request.2,
            };
            let fresh = m.prepare(&request);
            fresh.make_all_resident();
            assert_eq!(fresh.bytes(), m.prepared_bytes(&request));
            assert_eq!(
                m.prepared_bytes(&request).total() == prepared.bytes().total(),
                fresh.bytes().total() == prepared.bytes().total()
            );
        }
        // Texels of the used cluster evaluate exactly as the reference with N_PCA = 2.
        for (t, wi, wo) in points(300, texels) {
            if m.texel_cluster()[t] == 1 {
                assert_eq!(part.eval_texel(t, wi, wo), m.eval_texel(t, wi, wo, true, 2));
            }
        }
    }

    /// The parts a device uploads hold the cells packed, `[light][view][1 + k][3]`,
    /// whatever padding the CPU's tables carry (8 components: padded to 32 floats).
    #[test]
    fn device_parts_hold_the_cells_unpadded() {
        let single = sample_material(6, 5, 4, Some(8));
        // Half-float tables reach the device as f32, unpadded, like f32 ones.
        for m in [&single, &with_half_residual(&single)] {
            device_parts_of(m);
        }
    }

    fn device_parts_of(m: &SpmmMaterial) {
        let r = m.residual().expect("residual");
        let (nl, nv, k) = (r.light_dirs.len(), r.view_dirs.len(), 8);
        let p = m.prepare(&PrepareRequest {
            used_clusters: None,
            residual: true,
            max_npca: k,
        });
        let parts = p.parts();
        let pr = parts.residual.expect("residual prepared");
        assert_eq!(pr.cells.len(), 4 * nl * nv * (1 + k) * 3);
        for c in 0..4 {
            let base = pr.cluster_offset[c].expect("every cluster prepared");
            for (l, v) in [(0, 0), (nl - 1, nv - 1), (1, 2)] {
                let start = base + (l * nv + v) * (1 + k) * 3;
                let cell: Vec<f32> = (start..start + (1 + k) * 3)
                    .map(|i| pr.cells.value(i))
                    .collect();
                let m0 = ((c * nl + l) * nv + v) * 3;
                assert_eq!(cell[..3], r.mean[m0..m0 + 3]);
                for kk in 0..k {
                    let b = (((c * r.npca + kk) * nl + l) * nv + v) * 3;
                    assert_eq!(cell[3 + 3 * kk..6 + 3 * kk], r.components[b..b + 3]);
                }
            }
        }
    }

    /// A cluster's residual tables are laid out when a texel of it is first evaluated:
    /// the bytes grow by exactly that cluster's tables, and every value equals the
    /// evaluation of data laid out up front.
    #[test]
    fn residual_tables_are_laid_out_per_cluster_when_first_reached() {
        let m = sample_material(6, 5, 4, Some(3));
        let (l, v, texels, k) = (5, 4, 30, 3);
        let request = PrepareRequest {
            used_clusters: None,
            residual: true,
            max_npca: k,
        };
        let eager = m.prepare(&request);
        eager.make_all_resident();
        let lazy = m.prepare(&request);
        let table = l * v * (1 + k) * 3 * 4;
        let coefficients = texels * k * 4;
        assert_eq!(lazy.bytes().residual, coefficients, "no table laid out yet");
        let mut reached = [false; 4];
        for (t, wi, wo) in points(400, texels) {
            let c = m.texel_cluster()[t] as usize;
            assert_eq!(
                lazy.eval_texel(t, wi, wo).to_array().map(f64::to_bits),
                eager.eval_texel(t, wi, wo).to_array().map(f64::to_bits)
            );
            reached[c] = true;
            let held = reached.iter().filter(|&&r| r).count();
            assert_eq!(lazy.bytes().residual, coefficients + held * table);
        }
        assert_eq!(
            lazy.bytes(),
            eager.bytes(),
            "every cluster reached in the end"
        );
        // Below the horizon nothing is evaluated, so nothing is laid out.
        let fresh = m.prepare(&request);
        fresh.eval_texel(0, DVec3::new(0.0, 0.6, -0.8), DVec3::Z);
        assert_eq!(fresh.bytes().residual, coefficients);
        // A uv look-up lays out the clusters of the texels the filter reads.
        let s = EvalSettings {
            residual: true,
            max_npca: k,
            filter: TexelFilter::Nearest,
            uv_scale: DVec2::ONE,
        };
        let uv = DVec2::new(0.5 / 6.0, 0.5 / 5.0);
        fresh.make_resident_at(uv, &s);
        assert_eq!(fresh.bytes().residual, coefficients + table);
        // The parts a device uploads hold every used cluster's tables, laid out.
        let parts = fresh.parts();
        let r = parts.residual.expect("residual prepared");
        assert_eq!(r.cells.len() * 4, 4 * table);
        assert_eq!(fresh.bytes(), eager.bytes());
    }
}

/// A sample material whose clusters keep 3, 1 and 0 of their 3 components (the rest
/// zero), as a byte budget leaves them.
fn ragged_material() -> SpmmMaterial {
    let m = sample_material(5, 4, 3, Some(3));
    super::components::with_component_counts(&m, &[3, 1, 0]).expect("valid")
}

#[test]
fn per_cluster_npca_stores_only_the_kept_components_and_reads_back() {
    let m = ragged_material();
    let r = m.residual().expect("residual");
    assert_eq!(pack::cluster_component_counts(&m), vec![3, 1, 0]);
    let table = r.light_dirs.len() * r.view_dirs.len() * 3;
    for precision in [ResidualPrecision::F32, ResidualPrecision::F16] {
        let bytes = encode_pack(&m, precision);
        let header = |b: &[u8]| -> serde_json::Value {
            let n = u64::from_le_bytes(b[..8].try_into().expect("8 bytes")) as usize;
            serde_json::from_slice(&b[8..8 + n]).expect("JSON header")
        };
        let h = header(&bytes);
        assert_eq!(h["cluster_npca"]["shape"], serde_json::json!([3]));
        assert_eq!(
            h["residual_components"]["shape"],
            serde_json::json!([4, 5, 4, 3])
        );
        // Per texel, its cluster's count of coefficients.
        let coefs: usize = m
            .texel_cluster()
            .iter()
            .map(|&c| [3, 1, 0][c as usize])
            .sum();
        assert_eq!(
            h["residual_coefficients"]["shape"],
            serde_json::json!([coefs])
        );
        let back = decode_pack(&bytes).expect("a valid pack");
        assert_eq!(encode_pack(&back, precision), bytes, "{precision:?}");
        if precision == ResidualPrecision::F32 {
            // Exactly the material: the dropped parts were zero in it too.
            assert_eq!(back, m);
        }
        // The padded layout of the same values would be 5 components' tables larger.
        let elem = if precision == ResidualPrecision::F16 {
            2
        } else {
            4
        };
        let padded = 9 * table * elem + 3 * m.texel_cluster().len() * 4;
        let ragged = 4 * table * elem + coefs * 4;
        let full = encode_pack(&sample_material(5, 4, 3, Some(3)), precision).len();
        let saved = full - bytes.len();
        // Less the ragged file's `cluster_npca` (12 bytes and its header entry).
        assert!(
            saved <= padded - ragged && saved + 200 >= padded - ragged,
            "saved {saved} of {}",
            padded - ragged
        );
    }
    // Evaluation agrees with the padded material everywhere (the zeros add nothing).
    let back = decode_pack(&encode_pack(&m, ResidualPrecision::F32)).expect("valid");
    for t in 0..20 {
        for (wi, wo) in [
            (DVec3::new(0.3, 0.1, 0.95), DVec3::new(-0.2, 0.4, 0.89)),
            (DVec3::new(-0.6, 0.2, 0.77), DVec3::new(0.5, -0.5, 0.71)),
        ] {
            let (wi, wo) = (wi.normalize(), wo.normalize());
            assert_eq!(
                m.eval_texel(t, wi, wo, true, usize::MAX),
                back.eval_texel(t, wi, wo, true, usize::MAX)
            );
        }
    }
}

#[test]
fn per_cluster_npca_faults_are_named() {
    let good = encode_pack(&ragged_material(), ResidualPrecision::F16);
    let cases: Vec<(Vec<u8>, &[&str])> = vec![
        (
            with_tensor(&good, "cluster_npca", |d| {
                d[4..8].copy_from_slice(&4u32.to_le_bytes())
            }),
            &["cluster_npca`[1] = 4", "npca"],
        ),
        (
            // Counts that no longer match the stored components' shape.
            with_tensor(&good, "cluster_npca", |d| {
                d[8..12].copy_from_slice(&1u32.to_le_bytes())
            }),
            &["residual_components", "shape"],
        ),
        (
            // A half-float infinity (0x7c00) in a stored component.
            with_tensor(&good, "residual_components", |d| {
                d[6..8].copy_from_slice(&0x7c00u16.to_le_bytes())
            }),
            &["residual_components`[3]", "not finite"],
        ),
    ];
    for (bytes, needles) in cases {
        let msg = rejection(&bytes);
        for n in needles {
            assert!(msg.contains(n), "`{msg}` lacks `{n}`");
        }
    }
}

/// `bytes` re-encoded with its tensors edited by `edit` (a file another writer
/// could make; `with_tensor` keeps every tensor's size).
fn reencoded(
    bytes: &[u8],
    edit: impl FnOnce(&mut std::collections::BTreeMap<String, crate::container::Tensor>),
) -> Vec<u8> {
    let st = safetensors::SafeTensors::deserialize(bytes).expect("a valid container");
    let (_, meta) = safetensors::SafeTensors::read_metadata(bytes).expect("metadata");
    let metadata: Vec<(&str, String)> = meta
        .metadata()
        .as_ref()
        .map(|m| m.iter().map(|(k, v)| (k.as_str(), v.clone())).collect())
        .unwrap_or_default();
    let mut tensors: std::collections::BTreeMap<String, crate::container::Tensor> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| {
            let t = crate::container::Tensor {
                dtype: v.dtype(),
                shape: v.shape().to_vec(),
                data: v.data().to_vec(),
            };
            (n, t)
        })
        .collect();
    edit(&mut tensors);
    let named = tensors
        .iter()
        .map(|(n, t)| (n.as_str(), t.clone()))
        .collect();
    crate::container::encode(&metadata, &named)
}

/// `m` with its residual's component tables replaced by `edit` of them.
fn with_components(m: &SpmmMaterial, edit: impl FnOnce(&mut Vec<f32>)) -> SpmmMaterial {
    let mut r = m.residual().expect("residual").clone();
    edit(&mut r.components);
    with_residual(m, r)
}

#[test]
fn i8_components_load_within_half_a_step_and_save_back_byte_identical() {
    let base = sample_material(5, 4, 3, Some(3));
    let (v, d) = {
        let r = base.residual().expect("residual");
        (
            r.view_dirs.len(),
            r.light_dirs.len() * r.view_dirs.len() * 3,
        )
    };
    let run = v * 3;
    // Runs of every kind: zero, tiny (below the finest step), large, and the
    // sample's noise (up to 0.05).
    let m = with_components(&base, |c| {
        c[..run].fill(0.0);
        for (i, x) in c[run..2 * run].iter_mut().enumerate() {
            *x = 1e-8 * i as f32;
        }
        for (i, x) in c[2 * run..3 * run].iter_mut().enumerate() {
            *x = 700.0 - 37.0 * i as f32;
        }
    });
    for m in [m, ragged_material()] {
        let bytes = encode_pack(&m, ResidualPrecision::I8);
        assert_eq!(pack::residual_precision(&bytes), ResidualPrecision::I8);
        let back = decode_pack(&bytes).expect("a valid pack");
        assert_eq!(encode_pack(&back, ResidualPrecision::I8), bytes);
        // Decoded values are half floats, so a render keeps half-float tables.
        assert!(back.residual_is_half());
        let (a, b) = (
            m.residual().expect("residual"),
            back.residual().expect("residual"),
        );
        for (i, (x, y)) in a
            .components
            .chunks(run)
            .zip(b.components.chunks(run))
            .enumerate()
        {
            let max = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            // Half a step: under max / 127, or 2^-25 where the finest step binds.
            let bound = (max / 127.0).max(2f32.powi(-25)) * 1.0001;
            for (p, q) in x.iter().zip(y) {
                assert!(
                    (p - q).abs() <= bound,
                    "run {i}: {p} read as {q} (bound {bound})"
                );
            }
        }
        // The mean is stored as at F16.
        let half = decode_pack(&encode_pack(&m, ResidualPrecision::F16)).expect("valid");
        assert_eq!(half.residual().expect("residual").mean, b.mean);
        // Components take half the bytes of F16 plus one exponent per run.
        let f16_len = encode_pack(&m, ResidualPrecision::F16).len();
        let components = pack::cluster_component_counts(&m).iter().sum::<usize>() * d;
        let saved = f16_len - bytes.len();
        let expected = components - components / run;
        assert!(
            saved <= expected && saved + 200 >= expected,
            "saved {saved}, expected about {expected}"
        );
    }
}

#[test]
fn i8_faults_are_named() {
    let good = encode_pack(&ragged_material(), ResidualPrecision::I8);
    let cases: Vec<(Vec<u8>, &[&str])> = vec![
        (
            with_tensor(&good, "residual_component_exponents", |d| d[2] = 101),
            &["residual_component_exponents`[2] = 101", "-24..=100"],
        ),
        (
            with_tensor(&good, "residual_components", |d| d[5] = 0x80),
            &["residual_components", "-128", "-127..=127"],
        ),
        (
            reencoded(&good, |t| {
                t.remove("residual_component_exponents");
            }),
            &["residual_component_exponents", "missing"],
        ),
        (
            with_header(&good, |h| h["residual_components"]["dtype"] = "U8".into()),
            &["residual_components", "U8", "F16, F32 or I8"],
        ),
    ];
    for (bytes, needles) in cases {
        let msg = rejection(&bytes);
        for n in needles {
            assert!(msg.contains(n), "`{msg}` lacks `{n}`");
        }
    }
    // Exponents next to F16 components.
    let exponents = reencoded(&good, |t| {
        t.retain(|n, _| n == "residual_component_exponents");
    });
    let half = reencoded(
        &encode_pack(&ragged_material(), ResidualPrecision::F16),
        |t| {
            let st = safetensors::SafeTensors::deserialize(&exponents).expect("valid");
            let e = st.tensor("residual_component_exponents").expect("kept");
            t.insert(
                "residual_component_exponents".into(),
                crate::container::Tensor {
                    dtype: e.dtype(),
                    shape: e.shape().to_vec(),
                    data: e.data().to_vec(),
                },
            );
        },
    );
    let msg = rejection(&half);
    assert!(msg.contains("not I8"), "{msg}");
}
