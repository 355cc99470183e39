//! Analytic BRDFs in WGSL against core's f64: evaluation of every model across its
//! parameter ranges, and importance sampling (pdf and drawn direction).

use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::rng::SampleStream;

use crate::data::Words;

use super::kernel_cases::{Case, UNIT_ROUNDOFF, direction_pairs, evaluate, excess, random_brdf};

#[test]
fn every_brdf_model_matches_the_f64_reference() {
    let pairs = direction_pairs(1, 600);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    for (mi, model) in BrdfModel::ALL.into_iter().enumerate() {
        for set in 0..6u64 {
            let mut s = SampleStream::new(&[2, mi as u64, set]);
            let brdf = if set == 0 {
                AnalyticBrdf::with_defaults(model)
            } else {
                random_brdf(model, &mut s)
            };
            let record = words.push_brdf(&brdf);
            for &(wi, wo) in &pairs {
                cases.push(Case {
                    kind: 0,
                    record,
                    wi,
                    wo,
                    texel: 0,
                    residual: false,
                });
                reference.push((model, brdf, brdf.eval(wi, wo), wi, wo));
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst: Vec<(f64, String)> = vec![(0.0, String::new()); BrdfModel::ALL.len()];
    for (g, (model, brdf, c, wi, wo)) in got.iter().zip(&reference) {
        let g = g[0];
        assert!(
            g.is_finite() && g >= 0.0,
            "{model:?} {brdf:?} at {wi} {wo}: {g}"
        );
        // f32 carries 6e-8 relative; 1e-4 leaves room for the transcendental functions
        // of WGSL (a few ulp). Lafortune's s^n is exp2(n log2 s): the rounding of
        // log2 s (|s| up to 1e3 x 3) is amplified by n up to 1e4, so its tolerance grows
        // with n |log2 s|. And s itself is a dot product whose terms can cancel (C_x,
        // C_y and C_z of opposite signs): its f32 rounding, at most 4 unit roundoffs of
        // the terms' absolute sum (two products and two sums a term), is amplified by
        // that sum over |s| and by n. Mesa's lavapipe stayed within the first two
        // terms; the H200 did not (1.27 of them at a 220-fold cancellation).
        let rel = match brdf {
            AnalyticBrdf::Lafortune(b) => {
                let terms = DVec3::new(b.cx(), b.cy(), b.cz()) * *wi * *wo;
                let s = terms.element_sum();
                let cancellation = terms.abs().element_sum() / s.abs();
                1e-4 + 1e-6 * b.n() * s.abs().log2().abs().max(1.0)
                    + b.n() * 4.0 * UNIT_ROUNDOFF * cancellation
            }
            _ => 1e-4,
        };
        if *c > f32::MAX as f64 {
            continue;
        }
        let e = excess(g, *c, rel, 1e-6 * (1.0 + c.abs()));
        let slot = &mut worst[BrdfModel::ALL
            .iter()
            .position(|m| m == model)
            .expect("a model")];
        if e > slot.0 {
            *slot = (e, format!("{brdf:?} at wi {wi} wo {wo}: gpu {g}, f64 {c}"));
        }
    }
    for (model, (e, at)) in BrdfModel::ALL.iter().zip(&worst) {
        eprintln!("{model:?}: worst error {e:.3} of the tolerance ({at})");
    }
    for (model, (e, at)) in BrdfModel::ALL.iter().zip(&worst) {
        assert!(*e <= 1.0, "{model:?}: {e:.3} x the tolerance at {at}");
    }
}

/// BRDF importance sampling in WGSL (the environment's MIS) against core's f64
/// `sample` and `pdf`: each model at its defaults and five random parameter sets, the
/// pdf on the pairs of `direction_pairs`, and directions drawn from the same uniform
/// numbers. f32 limits: the pdf within 1e-3 relative (plus 1e-6 absolute; Lafortune's
/// power grows it as in `every_brdf_model_matches_the_f64_reference`), the drawn
/// direction within 1e-4 per component, drawn or not alike except where the CPU's
/// direction is within 1e-3 of the horizon (the f32 rounding decides there).
#[test]
fn brdf_sampling_matches_the_f64_reference() {
    use glam::DVec2;
    let pairs = direction_pairs(5, 400);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    for (mi, model) in BrdfModel::ALL.into_iter().enumerate() {
        for set in 0..6u64 {
            let mut s = SampleStream::new(&[6, mi as u64, set]);
            let brdf = if set == 0 {
                AnalyticBrdf::with_defaults(model)
            } else {
                random_brdf(model, &mut s)
            };
            let record = words.push_brdf(&brdf);
            for (k, &(wi, wo)) in pairs.iter().enumerate() {
                let mut case = Case {
                    kind: 3,
                    record,
                    wi,
                    wo,
                    texel: 0,
                    residual: false,
                };
                cases.push(case);
                reference.push((brdf, wi, wo, None));
                let u = DVec2::new(s.next(), s.next()).as_vec2().as_dvec2();
                let u = u.min(DVec2::splat(1.0 - 1e-7));
                case.kind = 4;
                case.wi = DVec3::new(u.x, u.y, 0.0);
                cases.push(case);
                reference.push((brdf, wi, wo, Some((u, k))));
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst_pdf: f64 = 0.0;
    let mut worst_dir: f64 = 0.0;
    let mut drawn = 0;
    for (g, (brdf, wi, wo, sample)) in got.iter().zip(&reference) {
        match sample {
            None => {
                let c = brdf.pdf(*wo, *wi);
                let g = g[0];
                assert!(g.is_finite() && g >= 0.0, "{brdf:?} pdf at {wi} {wo}: {g}");
                if c > 1e30 {
                    continue;
                }
                let rel = match brdf {
                    AnalyticBrdf::Lafortune(b) => {
                        let s = wi.dot(DVec3::new(b.cx(), b.cy(), b.cz()) * *wo);
                        1e-3 + 1e-5 * b.n() * s.abs().log2().abs().max(1.0)
                    }
                    _ => 1e-3,
                };
                let e = excess(g, c, rel, 1e-6 * (1.0 + c));
                assert!(
                    e <= 1.0,
                    "{brdf:?} pdf at wi {wi} wo {wo}: gpu {g}, f64 {c}"
                );
                worst_pdf = worst_pdf.max(e);
            }
            Some((u, _)) => {
                let c = brdf.sample(*wo, *u).map(|s| s.wi);
                let gv = DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64);
                assert!(gv.is_finite(), "{brdf:?} sample at {wo} {u}: {gv}");
                match c {
                    Some(c) if gv != DVec3::ZERO => {
                        let e = (gv - c).abs().max_element();
                        assert!(
                            e <= 1e-4,
                            "{brdf:?} sample at wo {wo} u {u}: gpu {gv}, f64 {c}"
                        );
                        worst_dir = worst_dir.max(e);
                        drawn += 1;
                    }
                    Some(c) => assert!(
                        c.z < 1e-3,
                        "{brdf:?} at wo {wo} u {u}: only the CPU draws {c}"
                    ),
                    None if gv != DVec3::ZERO => assert!(
                        gv.z < 1e-3,
                        "{brdf:?} at wo {wo} u {u}: only the GPU draws {gv}"
                    ),
                    None => {}
                }
            }
        }
    }
    eprintln!(
        "pdf: worst {worst_pdf:.3} of the tolerance; directions: {drawn} drawn, worst {worst_dir:.2e}"
    );
    assert!(drawn > cases.len() / 4, "most samples are drawn: {drawn}");
}
