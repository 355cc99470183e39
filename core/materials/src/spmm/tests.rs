//! The SPMM material's tests, one module per concept: pack round trips (`round_trip.rs`),
//! validation messages and a corruption corpus, every rejection naming the tensor or
//! metadata key at fault and no input making the reader panic (`faults.rs`),
//! evaluation (`evaluation.rs`), prepared data (`prepared.rs`), and the residual's
//! storage, ragged per cluster and in I8 (`residual.rs`). The pack helpers they share
//! are here.

use glam::DVec3;
use proptest::prelude::*;

use super::pack::{PackErrorKind, ResidualPrecision, decode_pack, encode_pack};
pub(crate) use super::testing::sample_material;
use super::*;
use crate::container::ContainerError;

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

/// A sample material whose clusters keep 3, 1 and 0 of their 3 components (the rest
/// zero), as a byte budget leaves them.
fn ragged_material() -> SpmmMaterial {
    let m = sample_material(5, 4, 3, Some(3));
    super::components::with_component_counts(&m, &[3, 1, 0]).expect("valid")
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

mod evaluation;
mod faults;
mod prepared;
mod residual;
mod round_trip;
