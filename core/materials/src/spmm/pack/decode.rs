//! Reading a pack: every shape, dtype, index and range checked before the material is
//! built, in the order of the file's sections. Its own module: the read side of the
//! format, the longest part of it, apart from the writer.

use std::collections::HashMap;

use glam::DVec3;
use safetensors::{Dtype, SafeTensors};

use super::quantize::dequantize_i8;
use super::{FORMAT, FORMAT_NOUN, PARAM_COLUMNS, PackErrorKind, ResidualPrecision, VERSION};
use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use crate::container::{self, ContainerError, dtype_name};
use crate::spmm::material::{Cluster, Residual, SparseWeights, SpmmMaterial};

const KNOWN_TENSORS: [&str; 15] = [
    "texel_cluster",
    "cluster_basis_offsets",
    "basis_model",
    "basis_params",
    "basis_normal",
    "weight_offsets",
    "weight_basis",
    "weight_rgb",
    "light_dirs",
    "view_dirs",
    "residual_mean",
    "residual_components",
    "residual_coefficients",
    "cluster_npca",
    "residual_component_exponents",
];

/// The validated contents of one tensor, typed.
struct Reader<'a> {
    st: SafeTensors<'a>,
}

impl<'a> Reader<'a> {
    fn view(
        &self,
        name: &'static str,
        dtypes: &[Dtype],
        expected: &[Option<usize>],
    ) -> Result<(Dtype, Vec<usize>, &'a [u8]), PackErrorKind> {
        let t = self
            .st
            .tensor(name)
            .map_err(|_| ContainerError::MissingTensor(name))?;
        if !dtypes.contains(&t.dtype()) {
            let expected = match dtypes {
                [one] => dtype_name(*one),
                [_, _] => "F16 or F32",
                _ => "F16, F32 or I8",
            };
            return Err(ContainerError::Dtype {
                name,
                found: format!("{:?}", t.dtype()),
                expected,
            }
            .into());
        }
        let shape = t.shape().to_vec();
        let matches = shape.len() == expected.len()
            && shape
                .iter()
                .zip(expected)
                .all(|(s, e)| e.is_none_or(|e| e == *s));
        if !matches {
            let expected: Vec<usize> = expected.iter().map(|e| e.unwrap_or(0)).collect();
            return Err(ContainerError::Shape {
                name,
                found: shape,
                expected: format!("{expected:?}"),
            }
            .into());
        }
        Ok((t.dtype(), shape, t.data()))
    }
}

fn u32s(data: &[u8]) -> Vec<u32> {
    data.chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}
fn u16s(data: &[u8]) -> Vec<u16> {
    data.chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect()
}
fn f32s(data: &[u8]) -> Vec<f32> {
    data.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}
fn f64s(data: &[u8]) -> Vec<f64> {
    data.chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8")))
        .collect()
}
fn table_f32(dtype: Dtype, data: &[u8]) -> Vec<f32> {
    match dtype {
        Dtype::F16 => data
            .chunks_exact(2)
            .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect(),
        _ => f32s(data),
    }
}

fn meta_usize(
    meta: &HashMap<String, String>,
    key: &'static str,
    max: usize,
) -> Result<usize, PackErrorKind> {
    let raw = meta
        .get(key)
        .ok_or_else(|| ContainerError::missing_metadata(key))?;
    let v: usize = raw.parse().map_err(|_| ContainerError::Metadata {
        key,
        problem: format!("`{raw}` is not a count"),
    })?;
    if v > max {
        return Err(ContainerError::Metadata {
            key,
            problem: format!("{v} exceeds the limit {max}"),
        }
        .into());
    }
    Ok(v)
}

/// Parses and validates pack bytes (see `read_pack`); also used by the fuzz tests.
/// The checks run in the order of the file's sections, so a pack with several faults
/// is refused for the same one every time.
pub fn decode_pack(bytes: &[u8]) -> Result<SpmmMaterial, PackErrorKind> {
    let opened = container::open(bytes, FORMAT, VERSION)?;
    let container::Opened {
        tensors: st,
        metadata: meta,
    } = opened;
    let Header {
        name,
        provenance,
        edited,
        width,
        height,
        n_clusters,
        npca,
    } = read_header(&meta)?;
    for name in st.names() {
        if !KNOWN_TENSORS.contains(&name) {
            return Err(ContainerError::UnknownTensor {
                name: name.to_string(),
                format: FORMAT_NOUN,
                version: VERSION,
            }
            .into());
        }
    }

    let r = Reader { st };
    let (_, _, data) = r.view("texel_cluster", &[Dtype::U32], &[Some(height), Some(width)])?;
    let texel_cluster = u32s(data);
    let clusters = read_clusters(&r, n_clusters)?;
    let weights = read_weights(&r, width * height)?;
    let residual = read_residual(&r, n_clusters, npca, &texel_cluster)?;

    let mut material = SpmmMaterial::new(
        name,
        provenance,
        width as u32,
        height as u32,
        clusters,
        texel_cluster,
        weights,
        residual,
    )?;
    match (edited, meta.get("edited_clusters")) {
        (false, None) => {}
        // Written before clusters were tracked: any cluster may have changed.
        (true, None) => material.mark_edited(),
        (true, Some(list)) => {
            let clusters = edited_cluster_list(list, n_clusters)?;
            material.mark_clusters_edited(clusters);
        }
        (false, Some(_)) => {
            return Err(ContainerError::Metadata {
                key: "edited_clusters",
                problem: "present in a pack whose `edited` is false".into(),
            }
            .into());
        }
    }
    Ok(material)
}

/// The metadata the tensors are checked against.
struct Header {
    name: String,
    provenance: String,
    edited: bool,
    width: usize,
    height: usize,
    n_clusters: usize,
    npca: usize,
}

fn read_header(meta: &HashMap<String, String>) -> Result<Header, PackErrorKind> {
    let text = |key: &'static str| {
        meta.get(key)
            .cloned()
            .ok_or_else(|| ContainerError::missing_metadata(key))
    };
    let name = text("name")?;
    let provenance = text("provenance")?;
    let edited = match text("edited")?.as_str() {
        "true" => true,
        "false" => false,
        other => {
            return Err(ContainerError::Metadata {
                key: "edited",
                problem: format!("`{other}`, expected true or false"),
            }
            .into());
        }
    };
    let width = meta_usize(meta, "width", 16384)?;
    let height = meta_usize(meta, "height", 16384)?;
    let n_clusters = meta_usize(meta, "clusters", 1 << 20)?;
    let npca = meta_usize(meta, "npca", 4096)?;
    Ok(Header {
        name,
        provenance,
        edited,
        width,
        height,
        n_clusters,
        npca,
    })
}

/// The clusters' basis dictionaries: offsets, models, parameters and normals, each
/// basis validated as its model requires.
fn read_clusters(r: &Reader, n_clusters: usize) -> Result<Vec<Cluster>, PackErrorKind> {
    let (_, _, data) = r.view(
        "cluster_basis_offsets",
        &[Dtype::U32],
        &[Some(n_clusters + 1)],
    )?;
    let cluster_offsets = u32s(data);
    let (_, shape, data) = r.view("basis_model", &[Dtype::U8], &[None])?;
    let n_bases = shape[0];
    let models = data.to_vec();
    let (_, _, data) = r.view(
        "basis_params",
        &[Dtype::F64],
        &[Some(n_bases), Some(PARAM_COLUMNS)],
    )?;
    let params = f64s(data);
    let (_, _, data) = r.view("basis_normal", &[Dtype::F64], &[Some(n_bases), Some(3)])?;
    let normals = f64s(data);

    if cluster_offsets.first() != Some(&0)
        || cluster_offsets.last().map(|&v| v as usize) != Some(n_bases)
    {
        return Err(PackErrorKind::ClusterOffsets(format!(
            "must start at 0 and end at the basis count {n_bases}, found {:?} .. {:?}",
            cluster_offsets.first(),
            cluster_offsets.last()
        )));
    }
    if let Some(i) = cluster_offsets.windows(2).position(|w| w[1] < w[0]) {
        return Err(PackErrorKind::ClusterOffsets(format!(
            "element {} decreases",
            i + 1
        )));
    }
    let mut bases = Vec::with_capacity(n_bases);
    for i in 0..n_bases {
        let model = *BrdfModel::ALL
            .get(usize::from(models[i]))
            .ok_or(PackErrorKind::ModelId {
                index: i,
                value: models[i],
            })?;
        let row = &params[i * PARAM_COLUMNS..(i + 1) * PARAM_COLUMNS];
        let used = model.param_specs().len();
        // Garbage in an unused column would hide a model id written wrongly.
        if let Some(column) =
            (used..PARAM_COLUMNS).find(|&k| row[k] != 0.0 || row[k].is_sign_negative())
        {
            return Err(PackErrorKind::UnusedParam {
                index: i,
                column,
                value: row[column],
                model: model.name(),
                used,
            });
        }
        let named: Vec<(&str, f64)> = model
            .param_specs()
            .iter()
            .map(|s| s.name)
            .zip(row.iter().copied())
            .collect();
        let brdf = AnalyticBrdf::new(model, &named)
            .map_err(|source| PackErrorKind::Basis { index: i, source })?;
        let n = DVec3::from_slice(&normals[i * 3..i * 3 + 3]);
        bases.push(
            BasisFunction::new(brdf, n)
                .map_err(|source| PackErrorKind::Basis { index: i, source })?,
        );
    }
    Ok(cluster_offsets
        .windows(2)
        .map(|w| Cluster {
            bases: bases[w[0] as usize..w[1] as usize].to_vec(),
        })
        .collect())
}

/// The texels' sparse RGB weights (`weight_offsets` has one entry per texel and one).
fn read_weights(r: &Reader, texels: usize) -> Result<SparseWeights, PackErrorKind> {
    let (_, _, data) = r.view("weight_offsets", &[Dtype::U32], &[Some(texels + 1)])?;
    let offsets = u32s(data);
    let (_, shape, data) = r.view("weight_basis", &[Dtype::U16], &[None])?;
    let nnz = shape[0];
    let basis = u16s(data);
    let (_, _, data) = r.view("weight_rgb", &[Dtype::F32], &[Some(nnz), Some(3)])?;
    let rgb: Vec<[f32; 3]> = f32s(data)
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Ok(SparseWeights {
        offsets,
        basis,
        rgb,
    })
}

/// The residual if the pack has any of its tensors (then it must have all of them);
/// without one, `npca` must be 0.
fn read_residual(
    r: &Reader,
    n_clusters: usize,
    npca: usize,
    texel_cluster: &[u32],
) -> Result<Option<Residual>, PackErrorKind> {
    let has_residual = KNOWN_TENSORS[8..].iter().any(|n| r.st.tensor(n).is_ok());
    Ok(if has_residual {
        let (_, shape, data) = r.view("light_dirs", &[Dtype::F64], &[None, Some(3)])?;
        let light_dirs: Vec<DVec3> = f64s(data).chunks_exact(3).map(DVec3::from_slice).collect();
        let l = shape[0];
        let (_, shape, data) = r.view("view_dirs", &[Dtype::F64], &[None, Some(3)])?;
        let view_dirs: Vec<DVec3> = f64s(data).chunks_exact(3).map(DVec3::from_slice).collect();
        let v = shape[0];
        let halves = [Dtype::F16, Dtype::F32];
        let (dt, _, data) = r.view(
            "residual_mean",
            &halves,
            &[Some(n_clusters), Some(l), Some(v), Some(3)],
        )?;
        let mean = table_f32(dt, data);
        let (components, coefficients) = if r.st.tensor("cluster_npca").is_ok() {
            read_ragged_residual(r, n_clusters, npca, l, v, texel_cluster)?
        } else {
            let components = read_components(r, &[Some(n_clusters), Some(npca)], l, v)?;
            let (_, _, data) = r.view(
                "residual_coefficients",
                &[Dtype::F32],
                &[Some(texel_cluster.len()), Some(npca)],
            )?;
            (components, f32s(data))
        };
        Some(Residual {
            light_dirs,
            view_dirs,
            npca,
            mean,
            components,
            coefficients,
        })
    } else {
        if npca != 0 {
            return Err(ContainerError::Metadata {
                key: "npca",
                problem: format!("{npca} but the pack has no residual tensors"),
            }
            .into());
        }
        None
    })
}

/// The ragged residual (docs/formats/spmm.md, "Per-cluster N_PCA"): `cluster_npca`
/// components per cluster, stored one cluster after the other, and per texel its
/// cluster's count of coefficients; expanded to the padded in-memory layout
/// [C, npca, L, V, 3] and [T, npca] with zeros, so every reader of a material sees
/// one layout.
fn read_ragged_residual(
    r: &Reader,
    n_clusters: usize,
    npca: usize,
    l: usize,
    v: usize,
    texel_cluster: &[u32],
) -> Result<(Vec<f32>, Vec<f32>), PackErrorKind> {
    let (_, _, data) = r.view("cluster_npca", &[Dtype::U32], &[Some(n_clusters)])?;
    let counts = u32s(data);
    if let Some((c, &n)) = counts.iter().enumerate().find(|(_, n)| **n as usize > npca) {
        return Err(PackErrorKind::Ragged(format!(
            "tensor `cluster_npca`[{c}] = {n}: more than the metadata `npca` = {npca}"
        )));
    }
    let total: usize = counts.iter().map(|&n| n as usize).sum();
    let stored = read_components(r, &[Some(total)], l, v)?;
    if let Some(i) = stored.iter().position(|x| !x.is_finite()) {
        return Err(PackErrorKind::Ragged(format!(
            "tensor `residual_components`[{i}] = {} is not finite",
            stored[i]
        )));
    }
    let d = l * v * 3;
    let mut components = vec![0.0f32; n_clusters * npca * d];
    let mut at = 0;
    for (c, &n) in counts.iter().enumerate() {
        let n = n as usize;
        components[c * npca * d..(c * npca + n) * d].copy_from_slice(&stored[at..at + n * d]);
        at += n * d;
    }
    // Texel clusters are checked against C only when the material is built.
    let count_of = |t: usize| {
        counts
            .get(texel_cluster[t] as usize)
            .map_or(0, |&n| n as usize)
    };
    let expected: usize = (0..texel_cluster.len()).map(count_of).sum();
    let (_, _, data) = r.view("residual_coefficients", &[Dtype::F32], &[Some(expected)])?;
    let stored = f32s(data);
    let mut coefficients = vec![0.0f32; texel_cluster.len() * npca];
    let mut at = 0;
    for t in 0..texel_cluster.len() {
        let n = count_of(t);
        coefficients[t * npca..t * npca + n].copy_from_slice(&stored[at..at + n]);
        at += n;
    }
    Ok((components, coefficients))
}

/// `residual_components`, shaped `lead` then `[L, V, 3]`, as f32: F16 and F32 as
/// stored, I8 decoded with `residual_component_exponents` (shaped `lead` then `[L]`),
/// which must be present exactly when the components are I8.
fn read_components(
    r: &Reader,
    lead: &[Option<usize>],
    l: usize,
    v: usize,
) -> Result<Vec<f32>, PackErrorKind> {
    let shape = |tail: &[usize]| -> Vec<Option<usize>> {
        lead.iter()
            .copied()
            .chain(tail.iter().map(|&n| Some(n)))
            .collect()
    };
    let (dt, _, data) = r.view(
        "residual_components",
        &[Dtype::F16, Dtype::F32, Dtype::I8],
        &shape(&[l, v, 3]),
    )?;
    let has_exponents = r.st.tensor("residual_component_exponents").is_ok();
    match (dt, has_exponents) {
        (Dtype::I8, true) => {
            let (_, _, exponents) =
                r.view("residual_component_exponents", &[Dtype::I8], &shape(&[l]))?;
            dequantize_i8(data, exponents, v * 3)
        }
        (Dtype::I8, false) => {
            Err(ContainerError::MissingTensor("residual_component_exponents").into())
        }
        (_, true) => Err(PackErrorKind::Quantized(
            "tensor `residual_component_exponents` is present but `residual_components` \
             is not I8"
                .into(),
        )),
        (dt, false) => Ok(table_f32(dt, data)),
    }
}

/// The `edited_clusters` metadata: comma-separated cluster indices below `clusters`
/// (empty: an edit that changed no cluster's mixture, such as a residual switched off).
fn edited_cluster_list(list: &str, clusters: usize) -> Result<Vec<usize>, PackErrorKind> {
    if list.is_empty() {
        return Ok(Vec::new());
    }
    list.split(',')
        .map(|item| match item.parse::<usize>() {
            Ok(c) if c < clusters => Ok(c),
            _ => Err(ContainerError::Metadata {
                key: "edited_clusters",
                problem: format!("`{item}` is not a cluster index below {clusters}"),
            }
            .into()),
        })
        .collect()
}

/// The precision a pack's residual tables were stored in (F32 when it has none).
pub fn residual_precision(bytes: &[u8]) -> ResidualPrecision {
    let Ok(st) = SafeTensors::deserialize(bytes) else {
        return ResidualPrecision::F32;
    };
    let dtype = |name| st.tensor(name).ok().map(|t| t.dtype());
    match dtype("residual_mean") {
        Some(Dtype::F16) if dtype("residual_components") == Some(Dtype::I8) => {
            ResidualPrecision::I8
        }
        Some(Dtype::F16) => ResidualPrecision::F16,
        _ => ResidualPrecision::F32,
    }
}

/// Bytes taken by each tensor of a pack, and by the header, for `meso pack info`.
pub fn tensor_sizes(bytes: &[u8]) -> Result<Vec<(String, usize)>, PackErrorKind> {
    let invalid = |e: safetensors::SafeTensorError| ContainerError::Invalid(e.to_string());
    let (header_len, _) = SafeTensors::read_metadata(bytes).map_err(invalid)?;
    let mut sizes: Vec<(String, usize)> = vec![("(header)".into(), 8 + header_len)];
    let st = SafeTensors::deserialize(bytes).map_err(invalid)?;
    let mut tensors: Vec<(String, usize)> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| (n, v.data().len()))
        .collect();
    tensors.sort();
    sizes.extend(tensors);
    Ok(sizes)
}
