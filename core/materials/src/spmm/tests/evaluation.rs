//! Evaluation at shading points: the analytic sums, the residual at and between the
//! tabulated directions, texture-coordinate lookup.

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
            .map(|(b, w)| DVec3::new(w[0] as f64, w[1] as f64, w[2] as f64) * b.eval(wi, wo) * wi.z)
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
