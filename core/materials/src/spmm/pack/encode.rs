//! Writing a pack: the material's tensors and metadata in the container's
//! deterministic layout. Its own module: the write side of the format, apart from the
//! checks of the read side.

use std::collections::BTreeMap;

use glam::DVec3;
use safetensors::Dtype;

use super::quantize::quantize_i8;
use super::{FORMAT, PARAM_COLUMNS, ResidualPrecision, VERSION, model_id};
use crate::brdf::BasisFunction;
use crate::container::{self, Tensor};
use crate::spmm::material::{Residual, SpmmMaterial};

/// The tensors of a pack by name.
type Tensors = BTreeMap<&'static str, Tensor>;

fn le_bytes<T: Copy, const N: usize>(values: &[T], to: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    values.iter().flat_map(|v| to(*v)).collect()
}

/// Serialises a material. The header lists tensors by name with sorted keys, and the
/// data follows in the order of decreasing element size then name, so every tensor
/// starts aligned to its element size.
pub fn encode_pack(m: &SpmmMaterial, precision: ResidualPrecision) -> Vec<u8> {
    let mut tensors = Tensors::new();
    put_mixture(&mut tensors, m);
    if let Some(r) = m.residual() {
        put_residual(&mut tensors, m, r, precision);
    }
    container::encode(&metadata(m), &tensors)
}

/// The clusters' bases and the texels' sparse weights.
fn put_mixture(tensors: &mut Tensors, m: &SpmmMaterial) {
    let (w, h) = (m.width() as usize, m.height() as usize);
    let mut put = |name, dtype, shape: Vec<usize>, data| {
        tensors.insert(name, Tensor { dtype, shape, data });
    };
    put(
        "texel_cluster",
        Dtype::U32,
        vec![h, w],
        le_bytes(m.texel_cluster(), u32::to_le_bytes),
    );
    let bases: Vec<&BasisFunction> = m.clusters().iter().flat_map(|c| &c.bases).collect();
    let mut offsets = vec![0u32];
    for c in m.clusters() {
        offsets.push(offsets.last().copied().unwrap_or(0) + c.bases.len() as u32);
    }
    put(
        "cluster_basis_offsets",
        Dtype::U32,
        vec![offsets.len()],
        le_bytes(&offsets, u32::to_le_bytes),
    );
    let models: Vec<u8> = bases.iter().map(|b| model_id(b.brdf().model())).collect();
    put("basis_model", Dtype::U8, vec![bases.len()], models);
    let params: Vec<f64> = bases
        .iter()
        .flat_map(|b| {
            let mut row = [0.0; PARAM_COLUMNS];
            for (slot, v) in row.iter_mut().zip(b.brdf().param_values()) {
                *slot = v;
            }
            row
        })
        .collect();
    put(
        "basis_params",
        Dtype::F64,
        vec![bases.len(), PARAM_COLUMNS],
        le_bytes(&params, f64::to_le_bytes),
    );
    let normals: Vec<f64> = bases.iter().flat_map(|b| b.normal().to_array()).collect();
    put(
        "basis_normal",
        Dtype::F64,
        vec![bases.len(), 3],
        le_bytes(&normals, f64::to_le_bytes),
    );
    let wts = m.weights();
    put(
        "weight_offsets",
        Dtype::U32,
        vec![wts.offsets.len()],
        le_bytes(&wts.offsets, u32::to_le_bytes),
    );
    put(
        "weight_basis",
        Dtype::U16,
        vec![wts.basis.len()],
        le_bytes(&wts.basis, u16::to_le_bytes),
    );
    put(
        "weight_rgb",
        Dtype::F32,
        vec![wts.rgb.len(), 3],
        le_bytes(wts.rgb.as_flattened(), f32::to_le_bytes),
    );
}

/// The residual's directions, mean, components (dense or ragged per cluster, at
/// `precision`) and coefficients.
fn put_residual(
    tensors: &mut Tensors,
    m: &SpmmMaterial,
    r: &Residual,
    precision: ResidualPrecision,
) {
    let (w, h) = (m.width() as usize, m.height() as usize);
    let mut put = |name, dtype, shape: Vec<usize>, data| {
        tensors.insert(name, Tensor { dtype, shape, data });
    };
    let dirs = |d: &[DVec3]| {
        le_bytes(
            &d.iter().flat_map(|v| v.to_array()).collect::<Vec<_>>(),
            f64::to_le_bytes,
        )
    };
    put(
        "light_dirs",
        Dtype::F64,
        vec![r.light_dirs.len(), 3],
        dirs(&r.light_dirs),
    );
    put(
        "view_dirs",
        Dtype::F64,
        vec![r.view_dirs.len(), 3],
        dirs(&r.view_dirs),
    );
    let (c, l, v, k) = (
        m.clusters().len(),
        r.light_dirs.len(),
        r.view_dirs.len(),
        r.npca,
    );
    let half = |values: &[f32]| {
        (
            Dtype::F16,
            le_bytes(values, |x| half::f16::from_f32(x).to_le_bytes()),
        )
    };
    let (dt, data) = match precision {
        ResidualPrecision::F32 => (Dtype::F32, le_bytes(&r.mean, f32::to_le_bytes)),
        ResidualPrecision::F16 | ResidualPrecision::I8 => half(&r.mean),
    };
    put("residual_mean", dt, vec![c, l, v, 3], data);
    // Components, shaped `[.., L, V, 3]` (`lead` leading dimensions); at I8 with
    // their exponents, shaped `[.., L]`.
    let mut put_components = |values: &[f32], lead: Vec<usize>| {
        let shape = |tail: &[usize]| [lead.as_slice(), tail].concat();
        match precision {
            ResidualPrecision::F32 => put(
                "residual_components",
                Dtype::F32,
                shape(&[l, v, 3]),
                le_bytes(values, f32::to_le_bytes),
            ),
            ResidualPrecision::F16 => {
                let (dt, data) = half(values);
                put("residual_components", dt, shape(&[l, v, 3]), data);
            }
            ResidualPrecision::I8 => {
                let (codes, exponents) = quantize_i8(values, v * 3);
                put("residual_components", Dtype::I8, shape(&[l, v, 3]), codes);
                put(
                    "residual_component_exponents",
                    Dtype::I8,
                    shape(&[l]),
                    exponents,
                );
            }
        }
    };
    let counts = cluster_component_counts(m);
    if counts.iter().all(|&n| n == k) {
        put_components(&r.components, vec![c, k]);
        put(
            "residual_coefficients",
            Dtype::F32,
            vec![w * h, k],
            le_bytes(&r.coefficients, f32::to_le_bytes),
        );
    } else {
        // Ragged: each cluster stores only its leading components that are not all
        // zero (a trailing zero component adds nothing whatever its coefficients).
        let d = l * v * 3;
        let components: Vec<f32> = (0..c)
            .flat_map(|ci| &r.components[ci * k * d..(ci * k + counts[ci]) * d])
            .copied()
            .collect();
        let coefficients: Vec<f32> = m
            .texel_cluster()
            .iter()
            .enumerate()
            .flat_map(|(t, &ci)| &r.coefficients[t * k..t * k + counts[ci as usize]])
            .copied()
            .collect();
        let total: usize = counts.iter().sum();
        let n_coef = coefficients.len();
        put_components(&components, vec![total]);
        put(
            "residual_coefficients",
            Dtype::F32,
            vec![n_coef],
            le_bytes(&coefficients, f32::to_le_bytes),
        );
        let counts: Vec<u32> = counts.iter().map(|&n| n as u32).collect();
        put(
            "cluster_npca",
            Dtype::U32,
            vec![c],
            le_bytes(&counts, u32::to_le_bytes),
        );
    }
}

/// The metadata map, `edited_clusters` only when the material is edited.
fn metadata(m: &SpmmMaterial) -> Vec<(&'static str, String)> {
    let mut metadata = vec![
        ("format", FORMAT.to_string()),
        ("version", VERSION.to_string()),
        ("name", m.name().to_string()),
        ("provenance", m.provenance().to_string()),
        (
            "edited",
            if m.edited() { "true" } else { "false" }.to_string(),
        ),
        ("width", m.width().to_string()),
        ("height", m.height().to_string()),
        ("clusters", m.clusters().len().to_string()),
        ("npca", m.npca().to_string()),
    ];
    if m.edited() {
        let list: Vec<String> = m.edited_clusters().iter().map(|c| c.to_string()).collect();
        metadata.push(("edited_clusters", list.join(",")));
    }
    metadata
}

/// Per cluster, how many leading components the file must store: one past the last
/// component that is not all zero in the table or in a coefficient of the cluster's
/// texels (the fitter's per-cluster choice of N_PCA, and `fit::budget`'s trimming,
/// leave the rest zero in both, so dropping them loses nothing; a cluster whose
/// residual was switched off keeps its coefficients and so its components). Empty
/// without a residual.
pub fn cluster_component_counts(m: &SpmmMaterial) -> Vec<usize> {
    let Some(r) = m.residual() else {
        return Vec::new();
    };
    let (clusters, k) = (m.clusters().len(), r.npca);
    let d = r.light_dirs.len() * r.view_dirs.len() * 3;
    let mut used = vec![false; clusters * k];
    for (t, &c) in m.texel_cluster().iter().enumerate() {
        for (kk, x) in r.coefficients[t * k..(t + 1) * k].iter().enumerate() {
            used[c as usize * k + kk] |= *x != 0.0;
        }
    }
    (0..clusters)
        .map(|c| {
            (0..k)
                .rev()
                .find(|&kk| {
                    let at = (c * k + kk) * d;
                    used[c * k + kk] || r.components[at..at + d].iter().any(|x| *x != 0.0)
                })
                .map_or(0, |kk| kk + 1)
        })
        .collect()
}
