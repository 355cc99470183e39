use std::sync::atomic::AtomicBool;

use glam::DVec3;

use super::*;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use meso_materials::btf::{Btf, directions};
use meso_materials::rng::SampleStream;
use meso_materials::spmm::{Cluster, SparseWeights, SpmmMaterial};

fn basis(model: BrdfModel, params: &[(&str, f64)], normal: DVec3) -> BasisFunction {
    BasisFunction::new(
        AnalyticBrdf::new(model, params).expect("valid"),
        normal.normalize(),
    )
    .expect("valid")
}

/// A known SPMM without residual: two clusters (left and right half of an 8x8 grid)
/// of two bases each; in the second, a quarter of the texels use only the diffuse
/// basis (a Lambertian-only texel in the first would be a third shape, which the
/// k-means may rightly put with the Oren-Nayar texels).
fn known_material() -> SpmmMaterial {
    let a = Cluster {
        bases: vec![
            basis(BrdfModel::Lambertian, &[], DVec3::Z),
            basis(
                BrdfModel::Ward,
                &[("ax", 0.2), ("ay", 0.1)],
                DVec3::new(0.1, 0.0, 1.0),
            ),
        ],
    };
    let b = Cluster {
        bases: vec![
            basis(BrdfModel::OrenNayar, &[("sigma", 0.6)], DVec3::Z),
            basis(
                BrdfModel::CookTorrance,
                &[("m", 0.3), ("f0", 0.5)],
                DVec3::Z,
            ),
        ],
    };
    let (w, h) = (8u32, 8u32);
    let mut texel_cluster = Vec::new();
    let mut weights = SparseWeights {
        offsets: vec![0],
        basis: Vec::new(),
        rgb: Vec::new(),
    };
    for t in 0..(w * h) as usize {
        let c = u32::from(t % 8 >= 4);
        texel_cluster.push(c);
        let s = SampleStream::new(&[11, t as u64]);
        let diffuse = [
            0.2 + 0.6 * s.at(0),
            0.2 + 0.6 * s.at(1),
            0.2 + 0.6 * s.at(2),
        ]
        .map(|x| x as f32);
        weights.basis.push(0);
        weights.rgb.push(diffuse);
        if c == 0 || t % 4 != 0 {
            let spec = 0.3 + 0.3 * s.at(3);
            weights.basis.push(1);
            weights
                .rgb
                .push([spec as f32, (spec * 0.9) as f32, (spec * 0.8) as f32]);
        }
        weights.offsets.push(weights.basis.len() as u32);
    }
    SpmmMaterial::new(
        "known".into(),
        "test".into(),
        w,
        h,
        vec![a, b],
        texel_cluster,
        weights,
        None,
    )
    .expect("valid")
}

fn btf_of(m: &SpmmMaterial, dirs: &[DVec3]) -> Btf {
    let mut data = Vec::new();
    for t in 0..(m.width() * m.height()) as usize {
        for wi in dirs {
            for wo in dirs {
                let v = m.eval_texel(t, *wi, *wo, false, 0);
                data.extend([v.x as f32, v.y as f32, v.z as f32]);
            }
        }
    }
    Btf::new(
        "b".into(),
        "".into(),
        m.width(),
        m.height(),
        dirs.to_vec(),
        dirs.to_vec(),
        data,
    )
    .expect("valid")
}

pub(crate) fn quiet(_: Stage, _: usize, _: usize) {}

#[test]
fn fitting_a_known_spmm_recovers_it() {
    let truth = known_material();
    let dirs = directions::rings(&[(0.0, 1), (25.0, 6), (50.0, 8), (70.0, 8)]);
    let btf = btf_of(&truth, &dirs);
    let settings = FitSettings {
        clusters: 2,
        subclusters: 3,
        max_bases: 4,
        npca: 0,
        // The true Cook-Torrance and Ward bases grow far beyond 4x the BTF's maximum
        // towards the horizon (the lobe bound's second check): with the weight caps on,
        // they cannot be recovered exactly (checked at the end).
        hemisphere_bound: false,
        ..FitSettings::default()
    };
    let out = fit_btf(
        &btf,
        "fit",
        "test",
        &settings,
        &AtomicBool::new(false),
        &quiet,
    )
    .expect("fit");
    let r = &out.report;
    // The BTF holds f32 values (relative rounding 6e-8); the fit reaches 4.4e-8 of the
    // mean. Bound: 1e-6, 20x that.
    let relative = r.overall.rmse_basis / r.mean_reflectance;
    assert!(relative < 1e-6, "RMSE {relative:e} of the mean");
    // The partition is the true one up to relabelling: one fitted label per true one,
    // and different true clusters get different labels.
    let m = &out.material;
    let mut label = [None::<u32>; 2];
    for (t, (&want, &got)) in truth
        .texel_cluster()
        .iter()
        .zip(m.texel_cluster())
        .enumerate()
    {
        let l = label[want as usize].get_or_insert(got);
        assert_eq!(*l, got, "texel {t}: true cluster {want} split");
    }
    assert_ne!(label[0], label[1], "the two true clusters merged");
    // Every true basis is among the fitted bases of its cluster: the same function (its
    // values at the tabulated pairs parallel to a fitted basis's within 1e-9) and, but
    // for the Lambertian (which the dictionary also spans as Oren-Nayar with sigma -> 0
    // or a Blinn-Phong lobe of exponent -> 0), the same model, parameters and normal
    // within 1e-6 relative (measured: 4e-8).
    let pairs: Vec<(DVec3, DVec3)> = dirs
        .iter()
        .flat_map(|a| dirs.iter().map(move |b| (*a, *b)))
        .collect();
    let col =
        |b: &BasisFunction| -> Vec<f64> { pairs.iter().map(|(i, o)| b.eval(*i, *o)).collect() };
    let cos = |a: &[f64], b: &[f64]| {
        let d: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
        d / (a.iter().map(|x| x * x).sum::<f64>().sqrt()
            * b.iter().map(|x| x * x).sum::<f64>().sqrt())
    };
    for (tc, cluster) in truth.clusters().iter().enumerate() {
        let fitted = &m.clusters()[label[tc].expect("labelled") as usize].bases;
        for want in &cluster.bases {
            let wc = col(want);
            let same_function = fitted.iter().any(|f| cos(&col(f), &wc) > 1.0 - 1e-9);
            assert!(same_function, "cluster {tc}: no fitted basis is {want:?}");
            if want.brdf().model() == BrdfModel::Lambertian {
                continue;
            }
            let close = fitted.iter().any(|f| {
                f.brdf().model() == want.brdf().model()
                    && f.brdf()
                        .param_values()
                        .iter()
                        .zip(want.brdf().param_values())
                        .all(|(x, y)| (x - y).abs() <= 1e-6 * y.abs())
                    && (f.normal() - want.normal()).length() <= 1e-6
            });
            assert!(close, "cluster {tc}: {want:?} not recovered: {fitted:?}");
        }
    }
    // Same non-zero bases: each fitted basis with a weight is identified with the true
    // basis whose values at the tabulated pairs it correlates with best.
    let true_cols: Vec<Vec<Vec<f64>>> = truth
        .clusters()
        .iter()
        .map(|c| c.bases.iter().map(col).collect())
        .collect();
    let mut same = 0;
    for t in 0..64 {
        let tc = truth.texel_cluster()[t] as usize;
        let mut want: Vec<u16> = truth.texel_weights(t).map(|(j, _)| j).collect();
        want.sort();
        let fc = m.texel_cluster()[t] as usize;
        let mut got: Vec<u16> = m
            .texel_weights(t)
            .map(|(j, _)| {
                let c = col(&m.clusters()[fc].bases[usize::from(j)]);
                (0..true_cols[tc].len())
                    .max_by(|&x, &y| {
                        cos(&c, &true_cols[tc][x]).total_cmp(&cos(&c, &true_cols[tc][y]))
                    })
                    .expect("two true bases") as u16
            })
            .collect();
        got.sort();
        got.dedup();
        same += usize::from(got == want);
    }
    assert!(
        same >= 58,
        "{same} of 64 texels have the true non-zero bases"
    );
    // The truth breaks the hemisphere bound; with it on (the default) the fit keeps
    // every lobe within it, at the price of exactness.
    let bounded = fit_btf(
        &btf,
        "fit",
        "test",
        &FitSettings {
            hemisphere_bound: true,
            ..settings
        },
        &AtomicBool::new(false),
        &quiet,
    )
    .expect("fit");
    meso_materials::spmm::lobe_bound::check_lobes(&bounded.material).expect("within the bound");
    let relative = bounded.report.overall.rmse_basis / bounded.report.mean_reflectance;
    assert!(
        relative > 1e-3,
        "RMSE {relative:e} of the mean: the caps never bound"
    );
}

pub(crate) fn weave_btf() -> Btf {
    let text = r#"
version = 1
name = "w"
width = 8
height = 8
direction_rings = [[0.0, 1], [40.0, 5], [70.0, 6]]
detail = 2
supersample = 1
[mesostructure]
kind = "weave"
depth = 3.0
threads = 2
[[region]]
tangent_deg = 90.0
[[region.lobe]]
model = "lambertian"
weight = [0.5, 0.2, 0.1]
[[region.lobe]]
model = "ward"
params = { ax = 0.1, ay = 0.3 }
weight = [0.2, 0.2, 0.2]
[[region]]
[[region.lobe]]
model = "oren_nayar"
params = { sigma = 0.4 }
weight = [0.3, 0.3, 0.6]
[[region]]
[[region.lobe]]
model = "lambertian"
weight = [0.05, 0.05, 0.05]
"#;
    let setup = meso_materials::btf::synth::parse_recipe(text, std::path::Path::new("."), "t")
        .expect("recipe");
    meso_materials::btf::synth::synthesize(&setup, &AtomicBool::new(false), &|_, _| {})
        .expect("synth")
}

#[test]
fn full_rank_residual_is_exact_and_error_falls_with_npca() {
    let btf = weave_btf();
    let settings = FitSettings {
        clusters: 3,
        subclusters: 2,
        max_bases: 3,
        npca: 64,
        fit_pairs: 300,
        ..FitSettings::default()
    };
    let out = fit_btf(&btf, "w", "t", &settings, &AtomicBool::new(false), &quiet).expect("fit");
    let m = &out.material;
    let (dl, dv) = (btf.light_dirs(), btf.view_dirs());
    let rmse = |k: usize, residual: bool| {
        let mut sse = 0.0;
        for t in 0..btf.texels() {
            for (l, wi) in dl.iter().enumerate() {
                for (v, wo) in dv.iter().enumerate() {
                    let got = m.eval_texel(t, *wi, *wo, residual, k);
                    let want = btf.value(t, l, v);
                    sse += (got.x - f64::from(want[0])).powi(2)
                        + (got.y - f64::from(want[1])).powi(2)
                        + (got.z - f64::from(want[2])).powi(2);
                }
            }
        }
        (sse / btf.data().len() as f64).sqrt()
    };
    let mean = btf.mean_value();
    let full = rmse(64, true);
    assert!(full < 1e-5 * mean, "full rank RMSE {full} vs mean {mean}");
    let mut prev = rmse(0, false);
    for k in [0, 1, 2, 4, 8, 16, 64] {
        let e = rmse(k, true);
        assert!(e <= prev * (1.0 + 1e-6), "N_PCA {k}: {e} after {prev}");
        prev = e;
    }
    // The report's closed form agrees with the evaluated material.
    for (k, e) in &out.report.overall.rmse_npca {
        let direct = rmse(*k, true);
        assert!(
            (e - direct).abs() <= 1e-4 * mean + 1e-3 * direct,
            "N_PCA {k}: report {e}, direct {direct}"
        );
    }
    assert!((out.report.overall.rmse_basis - rmse(0, false)).abs() <= 1e-4 * mean);
}

#[test]
fn fits_are_the_same_bytes_on_1_and_2_threads_and_cancellable() {
    let btf = weave_btf();
    let settings = FitSettings {
        clusters: 2,
        subclusters: 2,
        max_bases: 3,
        npca: 2,
        fit_pairs: 60,
        seed: 5,
        ..FitSettings::default()
    };
    // docs/fitting.md: independent of the thread count. Fitted on pools of 1 and 2
    // threads, the packs are the same bytes.
    let fit_on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        let out = pool.install(|| {
            fit_btf(&btf, "w", "t", &settings, &AtomicBool::new(false), &quiet).expect("fit")
        });
        meso_materials::spmm::pack::encode_pack(
            &out.material,
            meso_materials::spmm::pack::ResidualPrecision::F32,
        )
    };
    let one = fit_on(1);
    assert!(one == fit_on(2), "1 and 2 threads fit different packs");
    assert!(matches!(
        fit_btf(&btf, "w", "t", &settings, &AtomicBool::new(true), &quiet),
        Err(FitError::Cancelled)
    ));
    let bad = FitSettings {
        clusters: 0,
        ..settings
    };
    let e = fit_btf(&btf, "w", "t", &bad, &AtomicBool::new(false), &quiet)
        .err()
        .expect("refused");
    assert!(e.to_string().contains("--clusters"), "{e}");
}

/// The grain leather recipe (materials/btf_recipes/grain_leather.toml) at 8x8 texels,
/// all 81 x 81 Bonn directions, without supersampling or inter-reflection: its glossy
/// Cook-Torrance grain is what made the all-pairs refit peak between the tabulated
/// directions.
fn small_leather_btf() -> Btf {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../materials/btf_recipes/grain_leather.toml");
    let text = std::fs::read_to_string(&path)
        .expect("the shipped recipe")
        .replace("width = 64", "width = 8")
        .replace("height = 64", "height = 8")
        .replace("detail = 4", "detail = 1")
        .replace("supersample = 2", "supersample = 1")
        .replace("interreflection_samples = 8", "interreflection_samples = 0")
        .replace("cells = 40", "cells = 8");
    let setup =
        meso_materials::btf::synth::parse_recipe(&text, std::path::Path::new("."), "leather")
            .expect("recipe");
    meso_materials::btf::synth::synthesize(&setup, &AtomicBool::new(false), &|_, _| {})
        .expect("synth")
}

#[test]
fn fitted_leather_keeps_every_lobe_within_the_bound() {
    let btf = small_leather_btf();
    let settings = FitSettings {
        clusters: 3,
        subclusters: 3,
        npca: 2,
        ..FitSettings::default()
    };
    let m = fit_btf(
        &btf,
        "leather",
        "test",
        &settings,
        &AtomicBool::new(false),
        &quiet,
    )
    .expect("fits")
    .material;
    meso_materials::spmm::lobe_bound::check_lobes(&m).expect("no basis beyond the lobe bound");
    assert!(m.clusters().iter().all(|c| !c.bases.is_empty()));
}

/// Per-cluster N_PCA under a byte budget (`budget.rs`): the pack fits the budget, one
/// more component would not, its evaluated table error is the closed form's (the fit's
/// mean-only error minus the kept components' energies), the file stores only the kept
/// components, and the budget fit beats an even split of the same bytes.
#[test]
fn a_byte_budget_keeps_the_components_that_remove_most_error() {
    use meso_materials::spmm::pack::{ResidualPrecision, decode_pack, encode_pack};
    let btf = weave_btf();
    let base = FitSettings {
        clusters: 3,
        subclusters: 2,
        max_bases: 3,
        npca: 12,
        fit_pairs: 300,
        ..FitSettings::default()
    };
    let full = fit_btf(&btf, "w", "t", &base, &AtomicBool::new(false), &quiet).expect("fit");
    let sse = |m: &SpmmMaterial| {
        let (dl, dv) = (btf.light_dirs(), btf.view_dirs());
        let mut sse = 0.0;
        for t in 0..btf.texels() {
            for (l, wi) in dl.iter().enumerate() {
                for (v, wo) in dv.iter().enumerate() {
                    let got = m.eval_texel(t, *wi, *wo, true, usize::MAX);
                    let want = btf.value(t, l, v);
                    sse += (got.x - f64::from(want[0])).powi(2)
                        + (got.y - f64::from(want[1])).powi(2)
                        + (got.z - f64::from(want[2])).powi(2);
                }
            }
        }
        sse
    };
    // An even split of 4 components per cluster, and the budget its file takes.
    let even = budget::with_component_counts(&full.material, &[4, 4, 4]).expect("valid");
    let even_bytes = encode_pack(&even, ResidualPrecision::F32).len() as u64;
    let settings = FitSettings {
        max_bytes: Some(even_bytes),
        precision: ResidualPrecision::F32,
        ..base
    };
    let out = fit_btf(&btf, "w", "t", &settings, &AtomicBool::new(false), &quiet).expect("fit");
    let counts = out
        .report
        .cluster_npca
        .clone()
        .expect("the budget's choice");
    let bytes = encode_pack(&out.material, ResidualPrecision::F32);
    assert!(
        bytes.len() as u64 <= even_bytes,
        "{} > {even_bytes}",
        bytes.len()
    );
    // The ragged file's extra tensor and the coefficients of larger clusters may cost
    // one component of the even split's 12.
    let total: usize = counts.iter().sum();
    assert!((11..=12).contains(&total), "{counts:?}");
    assert_ne!(
        counts,
        vec![4, 4, 4],
        "the clusters' errors differ: so do their shares"
    );
    // One more component, the next in the greedy order, would not fit.
    let energies = budget::component_energies(&full.material);
    let order = budget::greedy_order(&energies);
    let mut more = counts.clone();
    more[order[total]] += 1;
    let over = budget::with_component_counts(&full.material, &more).expect("valid");
    assert!(encode_pack(&over, ResidualPrecision::F32).len() as u64 > even_bytes);
    // The evaluated error is the closed form's, and lower than the even split's.
    let got = sse(&out.material);
    let mean_only = budget::with_component_counts(&full.material, &[0, 0, 0]).expect("valid");
    let kept: f64 = energies
        .iter()
        .zip(&counts)
        .map(|(e, &n)| e[..n].iter().sum::<f64>())
        .sum();
    let closed = sse(&mean_only) - kept;
    assert!(
        (got - closed).abs() <= 1e-4 * sse(&mean_only),
        "evaluated {got}, closed form {closed}"
    );
    let n = btf.data().len() as f64;
    let rmse_budget = out.report.rmse_budget.expect("reported");
    assert!(((got / n).sqrt() - rmse_budget).abs() <= 1e-3 * rmse_budget + 1e-9);
    let even_sse = sse(&even);
    assert!(got < even_sse, "budget {got} vs even split {even_sse}");
    // The file holds the chosen counts and reads back to the same values.
    let back = decode_pack(&bytes).expect("valid");
    assert_eq!(
        meso_materials::spmm::pack::cluster_component_counts(&back),
        counts
    );
    assert_eq!(encode_pack(&back, ResidualPrecision::F32), bytes);
    assert!((sse(&back) - got).abs() <= 1e-9 * got.max(1e-30));
    // At 8 bits the same bytes hold more components, and the file as read back, its
    // rounding included, leaves less error.
    let i8 = budget::trim_to_bytes(&full.material, even_bytes, ResidualPrecision::I8)
        .expect("within the budget");
    let i8_bytes = encode_pack(&i8.material, ResidualPrecision::I8);
    assert!(i8_bytes.len() as u64 <= even_bytes);
    assert_eq!(i8.bytes, i8_bytes.len());
    let i8_total: usize = i8.cluster_npca.iter().sum();
    assert!(i8_total > total, "{:?} vs {counts:?}", i8.cluster_npca);
    let i8_sse = sse(&decode_pack(&i8_bytes).expect("valid"));
    assert!(i8_sse < got, "i8 {i8_sse} vs f32 {got}");
}

#[test]
fn the_greedy_order_is_optimal_for_every_count() {
    // Energies non-increasing within each cluster, as PCA gives them.
    let energies = vec![vec![5.0, 1.0], vec![4.0, 3.0, 2.0], vec![0.5], vec![]];
    let order = budget::greedy_order(&energies);
    assert_eq!(order, vec![0, 1, 1, 1, 0, 2]);
    // Against every split of n components: the greedy prefix keeps the most.
    for n in 0..=order.len() {
        let greedy: f64 = {
            let mut next = [0; 4];
            order[..n]
                .iter()
                .map(|&c| {
                    next[c] += 1;
                    energies[c][next[c] - 1]
                })
                .sum()
        };
        let mut best = 0.0f64;
        for a in 0..=2 {
            for b in 0..=3 {
                for c in 0..=1 {
                    if a + b + c == n {
                        let kept = energies[0][..a].iter().sum::<f64>()
                            + energies[1][..b].iter().sum::<f64>()
                            + energies[2][..c].iter().sum::<f64>();
                        best = best.max(kept);
                    }
                }
            }
        }
        assert_eq!(greedy, best, "n = {n}");
    }
}

/// A trimmed pack whose weights its own (lower) maximum no longer allows gets exactly
/// the offending weights lowered to the bound; a pack within it is left as it is.
#[test]
fn clamping_to_the_lobe_bound_lowers_only_the_weights_over_it() {
    use meso_materials::spmm::{Residual, lobe_bound};
    let lamb = basis(BrdfModel::Lambertian, &[], DVec3::Z);
    // Broad at the measured directions, 20-odd times brighter towards the horizon.
    let ct = basis(
        BrdfModel::CookTorrance,
        &[("m", 0.3), ("f0", 0.05)],
        DVec3::Z,
    );
    let d = directions::bonn81();
    let table = d.len() * d.len() * 3;
    let pack = |w: f32| {
        SpmmMaterial::new(
            "clamp".into(),
            "test".into(),
            2,
            1,
            vec![Cluster {
                bases: vec![lamb, ct],
            }],
            vec![0, 0],
            SparseWeights {
                offsets: vec![0, 2, 4],
                basis: vec![0, 1, 0, 1],
                rgb: vec![[0.5; 3], [w, 0.001, w], [0.4; 3], [0.001; 3]],
            },
            Some(Residual {
                light_dirs: d.clone(),
                view_dirs: d.clone(),
                npca: 0,
                mean: vec![0.0; table],
                components: Vec::new(),
                coefficients: Vec::new(),
            }),
        )
        .expect("valid")
    };
    let over = pack(0.2);
    assert!(lobe_bound::check_lobes(&over).is_err());
    let (clamped, lowered) = budget::clamp_to_lobe_bound(&over).expect("clamped");
    assert_eq!(lowered, 1);
    assert_eq!(lobe_bound::check_lobes(&clamped), Ok(()));
    let (a, b) = (&over.weights().rgb, &clamped.weights().rgb);
    assert_eq!(
        (a[0], a[2], a[3]),
        (b[0], b[2], b[3]),
        "the others are kept"
    );
    // Channels over the cap are lowered to it, those under it kept.
    assert!(
        b[1][0] < 0.2 && b[1][0] == b[1][2] && b[1][1] == 0.001,
        "{:?}",
        b[1]
    );
    // Lowered no further than the fitter's margin below the bound.
    let peak = lobe_bound::hemisphere_peak(&ct).0;
    let ratio = f64::from(b[1][0]) * peak / lobe_bound::tabulated_maximum(&clamped);
    assert!(ratio > 0.9 * lobe_bound::HEMISPHERE_MULTIPLE, "{ratio}");
    let within = pack(0.005);
    let (same, none) = budget::clamp_to_lobe_bound(&within).expect("within");
    assert_eq!((same, none), (within, 0));
}
