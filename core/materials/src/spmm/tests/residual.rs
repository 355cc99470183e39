//! The residual's storage: per-cluster N_PCA (ragged) and I8 components, read back
//! and their faults named.

use super::*;

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
