//! Validation: every fault named, truncations and mutations refused without a panic
//! or a huge allocation.

use super::*;

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
