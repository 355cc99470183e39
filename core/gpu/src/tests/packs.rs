//! SPMM packs in WGSL against core's f64: basis functions and texels (with the
//! residual, as f32 or halves, and the moving camera's components), and the pack
//! sampler.

use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use meso_materials::rng::SampleStream;

use crate::data::Words;

use super::kernel_cases::{Case, direction_pairs, evaluate, excess};

#[test]
fn basis_functions_and_spmm_texels_match_the_f64_reference() {
    let pairs = direction_pairs(3, 400);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference: Vec<(String, DVec3)> = Vec::new();
    // Basis functions with tilted normals (the spec's frame rule, both branches).
    for normal in [
        DVec3::Z,
        DVec3::new(0.3, -0.2, 0.9).normalize(),
        DVec3::new(0.0, 0.999, 0.0447).normalize(),
        DVec3::new(0.6, 0.0, 0.8),
    ]
    .into_iter()
    {
        for model in BrdfModel::ALL {
            // The models' own ranges are covered above; here the tilt and the cosine.
            let basis = BasisFunction::new(AnalyticBrdf::with_defaults(model), normal)
                .expect("unit normal");
            let record = words.push_basis(&basis);
            for &(wi, wo) in &pairs {
                cases.push(Case {
                    kind: 1,
                    record,
                    wi,
                    wo,
                    texel: 0,
                    residual: false,
                });
                reference.push((format!("{basis:?}"), DVec3::splat(basis.eval(wi, wo))));
            }
        }
    }
    // SPMM texels: the basis sum, with and without the interpolated residual, whose
    // tables go up as f32 or, when every value is a half float (a pack read from an F16
    // file), as halves two to a word; and with the first `MOVING_NPCA` of its 6
    // components (the moving camera: kind 11).
    let material = meso_materials::spmm::testing::sample_material(4, 3, 3, Some(6));
    let half_material =
        meso_materials::spmm::pack::decode_pack(&meso_materials::spmm::pack::encode_pack(
            &material,
            meso_materials::spmm::pack::ResidualPrecision::F16,
        ))
        .expect("an F16 pack reads back");
    for (material, residual, halves) in [
        (&material, false, false),
        (&material, true, false),
        (&half_material, true, true),
    ] {
        let prepared = material.prepare(&meso_materials::spmm::PrepareRequest {
            used_clusters: None,
            residual,
            max_npca: usize::MAX,
        });
        assert_eq!(prepared.has_residual(), residual);
        if let Some(r) = prepared.parts().residual {
            let held_as_halves = matches!(r.cells, meso_materials::spmm::ResidualCells::F16(_));
            assert_eq!(held_as_halves, halves, "the tables' precision");
        }
        let record = words.push_spmm(&prepared, glam::DVec2::ONE, None);
        for t in 0..12u32 {
            for &(wi, wo) in pairs.iter().step_by(4) {
                let texel_case = |kind| Case {
                    kind,
                    record,
                    wi,
                    wo,
                    texel: t,
                    residual: true,
                };
                cases.push(texel_case(2));
                reference.push((
                    format!("texel {t}, residual {residual}, halves {halves}"),
                    prepared.eval_texel(t as usize, wi, wo),
                ));
                if residual {
                    let moving = meso_materials::spmm::MOVING_NPCA;
                    cases.push(texel_case(11));
                    reference.push((
                        format!("texel {t}, {moving} components, halves {halves}"),
                        material.eval_texel(t as usize, wi, wo, true, moving),
                    ));
                }
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst = (0.0f64, String::new());
    for (g, (what, c)) in got.iter().zip(&reference) {
        for ch in 0..3 {
            assert!(g[ch].is_finite(), "{what}: {g:?}");
            // The residual may be negative; the scale of the texel's value sets the floor.
            let e = excess(g[ch], c[ch], 1e-4, 1e-5 * (1.0 + c.abs().max_element()));
            if e > worst.0 {
                worst = (e, format!("{what}: gpu {g:?}, f64 {c}"));
            }
        }
    }
    eprintln!(
        "basis functions and SPMM texels: worst {:.3} of the tolerance ({})",
        worst.0, worst.1
    );
    assert!(
        worst.0 <= 1.0,
        "{:.3} x the tolerance: {}",
        worst.0,
        worst.1
    );
}

/// The pack sampler in WGSL (`spmm_sample_texel`, `spmm_texel_pdf`) against
/// `PreparedSpmm::sample_texel` / `texel_pdf` (the CPU's `PackSampling::Bases`) on
/// every texel of a pack of tilted Lambertian, Ward, Ashikhmin-Shirley, Lafortune and
/// Oren-Nayar bases (one texel's weights zeroed: the defensive mixture alone), on
/// random and grazing direction pairs. f32 limits: the pdf within 1e-3 relative plus
/// 1e-6 of its scale (as the BRDF samplers' pdfs); the direction drawn from the same
/// numbers within 1e-3 per component, drawn or not alike, except on at most 2% of
/// draws (a number within f32 rounding of a basis's selection interval edge picks the
/// neighbouring basis; the horizon decides near-grazing draws).
#[test]
fn pack_sampling_matches_the_cpus() {
    use glam::DVec2;
    let mut material = meso_materials::spmm::testing::sample_material(4, 3, 3, None);
    // Texel 5 without weight: the sampler falls back to the defensive mixture alone.
    {
        let w = material.weights().clone();
        let mut rgb = w.rgb.clone();
        for v in &mut rgb[w.offsets[5] as usize..w.offsets[6] as usize] {
            *v = [0.0; 3];
        }
        material = meso_materials::spmm::SpmmMaterial::new(
            material.name().to_string(),
            material.provenance().to_string(),
            material.width(),
            material.height(),
            material.clusters().to_vec(),
            material.texel_cluster().to_vec(),
            meso_materials::spmm::SparseWeights {
                offsets: w.offsets.clone(),
                basis: w.basis.clone(),
                rgb,
            },
            None,
        )
        .expect("valid material");
    }
    let prepared = material.prepare(&meso_materials::spmm::PrepareRequest {
        used_clusters: None,
        residual: false,
        max_npca: 0,
    });
    let mut words = Words::default();
    let record = words.push_spmm(&prepared, glam::DVec2::ONE, None);
    let pairs = direction_pairs(11, 240);
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    let mut s = SampleStream::new(&[12]);
    for t in 0..12u32 {
        for &(wi, wo) in &pairs {
            let case = Case {
                kind: 8,
                record,
                wi,
                wo,
                texel: t,
                residual: false,
            };
            cases.push(case);
            reference.push((t, wi, wo, None));
            let u = DVec2::new(s.next(), s.next()).as_vec2().as_dvec2();
            let u = u.min(DVec2::splat(1.0 - 1e-7));
            cases.push(Case {
                kind: 9,
                wi: DVec3::new(u.x, u.y, 0.0),
                ..case
            });
            reference.push((t, wi, wo, Some(u)));
        }
    }
    let got = evaluate(&words.words, &cases);
    let (mut worst_pdf, mut worst_dir, mut drawn, mut off, mut draws) = (0.0f64, 0.0f64, 0, 0, 0);
    for (g, &(t, wi, wo, u)) in got.iter().zip(&reference) {
        let t = t as usize;
        match u {
            None => {
                let c = prepared.texel_pdf(t, wi, wo);
                let g = g[0];
                assert!(g.is_finite() && g >= 0.0, "texel {t} pdf at {wi} {wo}: {g}");
                let e = excess(g, c, 1e-3, 1e-6 * (1.0 + c));
                assert!(
                    e <= 1.0,
                    "texel {t} pdf at wi {wi} wo {wo}: gpu {g}, f64 {c}"
                );
                worst_pdf = worst_pdf.max(e);
            }
            Some(u) => {
                draws += 1;
                let c = prepared.sample_texel(t, wo, u).map(|s| s.0);
                let gv = DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64);
                assert!(gv.is_finite(), "texel {t} sample at {wo} {u}: {gv}");
                match c {
                    Some(c) if gv != DVec3::ZERO => {
                        let e = (gv - c).abs().max_element();
                        if e > 1e-3 {
                            off += 1;
                        } else {
                            worst_dir = worst_dir.max(e);
                            drawn += 1;
                        }
                    }
                    None if gv == DVec3::ZERO => {}
                    _ => off += 1,
                }
            }
        }
    }
    eprintln!(
        "pack sampling: pdf worst {worst_pdf:.3} of the tolerance; {draws} draws, {drawn} alike (worst {worst_dir:.2e}), {off} off"
    );
    assert!(
        off * 50 <= draws,
        "{off} of {draws} draws differ from the CPU's"
    );
    assert!(
        drawn > draws / 2,
        "most samples are drawn: {drawn} of {draws}"
    );
}
