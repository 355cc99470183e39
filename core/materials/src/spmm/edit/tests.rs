use glam::DVec3;

use super::*;
use crate::brdf::{AnalyticBrdf, BrdfModel};
use crate::spmm::testing::sample_material;
use crate::spmm::{BasisView, TexelMask};

#[test]
fn replacing_a_basis_changes_only_that_cluster_and_marks_the_material_edited() {
    let m = sample_material(4, 4, 3, Some(2));
    let ward = BasisFunction::new(
        AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.05), ("ay", 0.4)]).expect("valid"),
        DVec3::new(0.1, 0.0, 1.0).normalize(),
    )
    .expect("unit normal");
    let e = m.with_basis(1, 0, ward).expect("valid edit");
    assert!(e.edited() && !m.edited());
    assert_eq!(e.clusters()[1].bases[0], ward);
    assert_eq!(e.clusters()[0], m.clusters()[0]);
    assert_eq!(e.clusters()[2], m.clusters()[2]);
    assert_eq!(e.weights(), m.weights());
    assert_eq!(e.residual(), m.residual());
    assert!(m.with_basis(3, 0, ward).is_err());
    assert!(m.with_basis(0, 99, ward).is_err());
}

#[test]
fn scaling_a_cluster_scales_its_mean_weight_and_nothing_else() {
    let m = sample_material(4, 4, 3, None);
    let before: Vec<[f64; 3]> = (0..3).map(|c| m.cluster_mean_weight(c)).collect();
    let e = m
        .with_cluster_weight_scale(2, [2.0, 0.5, 0.0])
        .expect("valid scale");
    let after = e.cluster_mean_weight(2);
    for k in 0..3 {
        let want = before[2][k] * [2.0, 0.5, 0.0][k];
        assert!(
            (after[k] - want).abs() <= 1e-6 * want.max(1e-6),
            "{after:?}"
        );
    }
    assert_eq!(e.cluster_mean_weight(0), before[0]);
    assert_eq!(e.cluster_mean_weight(1), before[1]);
    // Texels of other clusters keep their exact weights.
    for (t, &c) in m.texel_cluster().iter().enumerate() {
        if c != 2 {
            assert!(m.texel_weights(t).eq(e.texel_weights(t)));
        }
    }
    assert!(
        m.with_cluster_weight_scale(2, [f64::NAN, 1.0, 1.0])
            .is_err()
    );
    assert!(m.with_cluster_weight_scale(2, [-1.0, 1.0, 1.0]).is_err());
    assert!(m.with_cluster_weight_scale(7, [1.0; 3]).is_err());
    assert_eq!(m.cluster_texels(2).iter().filter(|&&b| b).count(), {
        m.texel_cluster().iter().filter(|&&c| c == 2).count()
    });
}

fn encode(m: &SpmmMaterial) -> Vec<u8> {
    crate::spmm::pack::encode_pack(m, crate::spmm::pack::ResidualPrecision::F32)
}

fn dirs() -> Vec<(DVec3, DVec3)> {
    let d = |t: f64, p: f64| crate::brdf::warp::spherical(t, p);
    vec![
        (d(0.3, 0.2), d(0.5, 3.0)),
        (d(1.1, 1.0), d(0.2, 4.0)),
        (d(0.7, 5.0), d(0.9, 5.5)),
    ]
}

#[test]
fn scaling_one_basis_changes_exactly_its_weights_and_2_then_half_restores_them() {
    let m = sample_material(6, 5, 3, Some(2));
    let (c, b) = (1, 2);
    let e = m
        .with_weight_scale(&WeightTarget::basis(c, b), [2.0, 3.0, 0.5])
        .expect("valid scale");
    assert!(e.edited());
    let mut scaled = 0;
    for (t, &tc) in m.texel_cluster().iter().enumerate() {
        for ((j0, w0), (j1, w1)) in m.texel_weights(t).zip(e.texel_weights(t)) {
            assert_eq!(j0, j1, "no entry moves or appears");
            if tc as usize == c && usize::from(j0) == b {
                scaled += 1;
                assert_eq!(w1, [w0[0] * 2.0, w0[1] * 3.0, w0[2] * 0.5]);
            } else {
                assert_eq!(w0.map(f32::to_bits), w1.map(f32::to_bits));
            }
        }
        assert_eq!(m.texel_weights(t).count(), e.texel_weights(t).count());
    }
    assert!(
        scaled > 0,
        "the sample material weighs basis {b} of cluster {c}"
    );
    let back = m
        .with_weight_scale(&WeightTarget::basis(c, b), [2.0; 3])
        .and_then(|x| x.with_weight_scale(&WeightTarget::basis(c, b), [0.5; 3]))
        .expect("valid");
    assert_eq!(back.weights(), m.weights());
    // The mean weight shown per basis follows the scale.
    let (before, after) = (m.basis_mean_weight(c, b), e.basis_mean_weight(c, b));
    assert!((after[0] - 2.0 * before[0]).abs() < 1e-6 && before[0] > 0.0);
    // A unit scale changes nothing: not even the edited flag or the pack's bytes.
    let same = m
        .with_weight_scale(&WeightTarget::basis(c, b), [1.0; 3])
        .expect("valid");
    assert!(!same.edited());
    assert_eq!(encode(&same), encode(&m));
    // Bad targets are named.
    let err = |t: WeightTarget| m.with_weight_scale(&t, [1.0; 3]).unwrap_err().to_string();
    assert!(err(WeightTarget::basis(1, 9)).contains("basis 9 of cluster 1"));
    assert!(err(WeightTarget::cluster(5)).contains("cluster 5"));
    let small = TexelMask::empty(2, 2);
    assert!(err(WeightTarget::cluster(0).within(&small)).contains("2x2"));
}

#[test]
fn a_masked_scale_changes_only_covered_texels_and_partial_strength_interpolates() {
    let m = sample_material(8, 8, 2, None);
    let mut mask = TexelMask::empty(8, 8);
    mask.stamp(
        glam::DVec2::new(0.5, 0.5),
        1.6,
        1.0,
        crate::spmm::Falloff::Linear,
    );
    // The disc wraps: it reaches the last column and row.
    assert!(mask.strength(7) > 0.0 && mask.strength(7 * 8) > 0.0);
    assert_eq!(mask.strength(0), 1.0, "full strength at the centre texel");
    let e = m
        .with_weight_scale(&WeightTarget::default().within(&mask), [3.0; 3])
        .expect("valid");
    let changed = m.changed_texels(&e).expect("same grid");
    for (t, &changed) in changed.iter().enumerate() {
        let s = f64::from(mask.strength(t));
        assert_eq!(changed, s > 0.0, "texel {t}");
        for ((_, w0), (_, w1)) in m.texel_weights(t).zip(e.texel_weights(t)) {
            let want = (f64::from(w0[0]) * (1.0 + s * 2.0)) as f32;
            assert_eq!(w1[0], want, "texel {t}");
        }
    }
}

#[test]
fn adding_weight_makes_entries_only_where_painted() {
    let m = sample_material(6, 6, 2, None);
    let (m2, j) = m
        .with_basis_added(
            0,
            BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
                .expect("unit"),
        )
        .expect("cluster 0 exists");
    assert_eq!(m2.weights(), m.weights(), "a new basis has no weight yet");
    let unchanged = m.changed_texels(&m2).expect("same grid");
    assert!(unchanged.iter().all(|c| !c), "so no texel looks different");
    let mut mask = TexelMask::empty(6, 6);
    for t in [0, 1, 7, 20] {
        mask.raise(t, 0.5);
    }
    let e = m2
        .with_weight_added(&WeightTarget::basis(0, j).within(&mask), [0.2, 0.4, 0.0])
        .expect("valid");
    for t in 0..36 {
        let want = mask.strength(t) > 0.0 && m.texel_cluster()[t] == 0;
        let before: Vec<_> = m.texel_weights(t).collect();
        let mut after: Vec<_> = e.texel_weights(t).collect();
        if want {
            assert_eq!(after.pop(), Some((j as u16, [0.1, 0.2, 0.0])), "texel {t}");
        }
        assert_eq!(after, before, "texel {t}: the other entries stay");
    }
    assert!(
        m.with_weight_added(&WeightTarget::cluster(0), [1.0; 3])
            .is_err(),
        "adding needs a basis"
    );
}

#[test]
fn mute_and_solo_change_the_view_but_never_the_pack() {
    let m = sample_material(5, 4, 2, Some(2));
    let (c, b) = (0, 1);
    let mut view = BasisView::default();
    view.set_muted(c, b, true);
    let muted = m.with_view(view).expect("flags name bases");
    assert!(!muted.edited() && muted.stores_same(&m) && muted != m);
    assert_eq!(encode(&muted), encode(&m));
    let mut view = BasisView::default();
    view.set_solo(c, b, true);
    let solo = m.with_view(view).expect("valid");
    assert_eq!(encode(&solo), encode(&m));
    let prepared = solo.prepare(&crate::spmm::PrepareRequest {
        used_clusters: None,
        residual: true,
        max_npca: usize::MAX,
    });
    for t in 0..20 {
        for (wi, wo) in dirs() {
            let parts = m.contributions(t, wi, wo, true, usize::MAX);
            let all = m.eval_texel(t, wi, wo, true, usize::MAX);
            let sum: DVec3 = parts.bases.iter().sum::<DVec3>() + parts.residual;
            assert!(
                (sum - all).abs().max_element() < 1e-9,
                "parts sum to the whole"
            );
            let in_c = parts.cluster == c;
            let want_muted = if in_c { all - parts.bases[b] } else { all };
            let got = muted.eval_texel(t, wi, wo, true, usize::MAX);
            assert!((got - want_muted).abs().max_element() < 1e-9, "texel {t}");
            let want_solo = if in_c { parts.bases[b] } else { all };
            let got = solo.eval_texel(t, wi, wo, true, usize::MAX);
            assert!((got - want_solo).abs().max_element() < 1e-9, "texel {t}");
            let got = prepared.eval_texel(t, wi, wo);
            assert!(
                (got - want_solo).abs().max_element() < 1e-6,
                "prepared texel {t}"
            );
        }
    }
    let mut bad = BasisView::default();
    bad.set_muted(1, 40, true);
    assert!(m.with_view(bad).is_err());
    // Applying the solo stores what the view showed: only basis b's weights in
    // cluster c, no residual there.
    let applied = solo.with_view_applied().expect("valid");
    assert!(applied.edited() && applied.view().is_empty());
    assert!(!applied.cluster_has_residual(c) && applied.cluster_has_residual(1));
    for t in 0..20 {
        for (wi, wo) in dirs() {
            let want = solo.eval_texel(t, wi, wo, true, usize::MAX);
            let got = applied.eval_texel(t, wi, wo, true, usize::MAX);
            assert!((got - want).abs().max_element() < 1e-6, "texel {t}");
        }
    }
}

#[test]
fn add_duplicate_and_remove_bases_round_trip_through_the_pack() {
    let m = sample_material(5, 5, 3, Some(1));
    let c = 2;
    let n = m.clusters()[c].bases.len();
    let (dup, j) = m.with_basis_duplicated(c, 0).expect("valid");
    assert_eq!(j, n);
    assert_eq!(dup.clusters()[c].bases[j], m.clusters()[c].bases[0]);
    let bytes = encode(&dup);
    let read = crate::spmm::pack::decode_pack(&bytes).expect("valid pack");
    assert_eq!(read.clusters(), dup.clusters());
    assert_eq!(read.weights(), dup.weights());
    assert!(read.edited());
    // Removing the copy gives back the original data.
    let back = dup.with_basis_removed(c, j).expect("valid");
    assert_eq!(back.clusters(), m.clusters());
    assert_eq!(back.weights(), m.weights());
    // Removing basis 0 drops its weights and renumbers the rest.
    let mut view = BasisView::default();
    view.set_muted(c, 2, true);
    let r = m
        .with_view(view)
        .and_then(|x| x.with_basis_removed(c, 0))
        .expect("valid");
    assert!(
        r.view().muted(c, 1) && !r.view().muted(c, 2),
        "flags follow the renumbering"
    );
    for t in 0..25 {
        let before: Vec<_> = m.texel_weights(t).collect();
        let after: Vec<_> = r.texel_weights(t).collect();
        if m.texel_cluster()[t] as usize == c {
            let want: Vec<_> = before
                .iter()
                .filter(|(j, _)| *j != 0)
                .map(|&(j, w)| (j - 1, w))
                .collect();
            assert_eq!(after, want, "texel {t}");
        } else {
            assert_eq!(after, before);
        }
    }
    let read = crate::spmm::pack::decode_pack(&encode(&r)).expect("valid pack");
    assert_eq!(read.weights(), r.weights());
    assert!(m.with_basis_removed(c, 99).is_err());
    let one = sample_material(2, 2, 1, None);
    let mut lone = one.clone();
    while lone.clusters()[0].bases.len() > 1 {
        lone = lone.with_basis_removed(0, 0).expect("valid");
    }
    assert!(
        lone.with_basis_removed(0, 0)
            .unwrap_err()
            .to_string()
            .contains("only basis")
    );
}

#[test]
fn switching_a_cluster_residual_off_keeps_the_others() {
    let m = sample_material(4, 4, 3, Some(2));
    assert!((0..3).all(|c| m.cluster_has_residual(c)));
    let e = m.with_cluster_residual_off(1).expect("valid");
    assert!(e.cluster_has_residual(0) && !e.cluster_has_residual(1) && e.cluster_has_residual(2));
    let changed = m.changed_texels(&e).expect("same grid");
    assert_eq!(changed, m.cluster_texels(1));
    assert!(m.with_cluster_residual_off(3).is_err());
    // A material without a residual has none to switch off.
    let plain = sample_material(4, 4, 2, None);
    assert!(!plain.cluster_has_residual(0));
    assert_eq!(plain.with_cluster_residual_off(0).expect("valid"), plain);
}
#[test]
fn only_clusters_whose_mixture_changed_are_marked_edited_and_the_marks_are_saved() {
    let m = sample_material(4, 4, 3, Some(2));
    assert!(m.edited_clusters().is_empty());
    // A basis scale in cluster 1 marks cluster 1 alone.
    let scaled = m
        .with_weight_scale(&WeightTarget::basis(1, 0), [2.0, 1.0, 1.0])
        .expect("valid");
    assert!(scaled.edited());
    assert_eq!(scaled.edited_clusters(), vec![1]);
    // A dictionary edit of cluster 2 adds it; the earlier mark stays.
    let basis = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    let added = scaled
        .with_basis_added(2, BasisFunction::new(basis, DVec3::Z).expect("valid"))
        .expect("valid")
        .0;
    assert_eq!(added.edited_clusters(), vec![1, 2]);
    // A residual switched off changes no mixture: edited, no cluster marked.
    let off = m.with_cluster_residual_off(0).expect("valid");
    assert!(off.edited() && off.edited_clusters().is_empty());
    // A unit scale changes nothing at all.
    let same = m
        .with_weight_scale(&WeightTarget::cluster(0), [1.0; 3])
        .expect("valid");
    assert!(!same.edited() && same.edited_clusters().is_empty());
    // The marks survive the pack; an edited pack without them marks every cluster.
    for e in [&added, &off] {
        let read = crate::spmm::pack::decode_pack(&encode(e)).expect("valid pack");
        assert_eq!(read.edited_clusters(), e.edited_clusters());
        assert!(read.stores_same(e));
    }
    let mut legacy = m.clone();
    legacy.mark_edited();
    assert_eq!(legacy.edited_clusters(), vec![0, 1, 2]);
    assert!(!legacy.stores_same(&added));
    // A bad list is refused naming the key and the item.
    let mut bad = encode(&added);
    let key = b"\"edited_clusters\":\"1,2\"";
    let at = bad
        .windows(key.len())
        .position(|w| w == key)
        .expect("the key is in the header");
    bad[at + key.len() - 2] = b'9';
    let err = crate::spmm::pack::decode_pack(&bad).unwrap_err();
    assert!(
        err.to_string().contains("edited_clusters") && err.to_string().contains("`9`"),
        "{err}"
    );
}
