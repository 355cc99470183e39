use std::sync::Arc;

use super::*;
use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use crate::spmm::testing::sample_material;
use crate::spmm::{TexelMask, WeightTarget};

/// Every stored part and the view are equal, and the residual is shared when it was.
fn same(a: &SpmmMaterial, b: &SpmmMaterial) {
    assert!(a.stores_same(b), "stored parts differ");
    assert_eq!(a.view(), b.view());
    assert_eq!(a.edited_clusters(), b.edited_clusters());
}

/// A brush-like edit: weight added to basis 1 of cluster 0 on a few texels.
fn stroke(m: &SpmmMaterial, at: usize) -> SpmmMaterial {
    let (w, h) = (m.width(), m.height());
    let mut s = vec![0.0f32; (w * h) as usize];
    for t in at..(at + 5).min(s.len()) {
        s[t] = 0.5;
    }
    let mask = TexelMask::from_strengths(w, h, s).expect("mask");
    m.with_weight_added(&WeightTarget::basis(0, 1).within(&mask), [0.2, 0.1, 0.05])
        .expect("stroke")
}

/// The edits the editor makes, each stepped forward from before and back from after.
#[test]
fn every_edit_kind_steps_both_ways_and_round_trips_its_bytes() {
    let m = sample_material(12, 9, 3, Some(2));
    let lambert = BasisFunction::new(
        AnalyticBrdf::new(BrdfModel::BlinnPhong, &[("n", 40.0)]).expect("valid"),
        glam::DVec3::Z,
    )
    .expect("basis");
    let mut view = BasisView::default();
    view.set_muted(1, 0, true);
    let edits: Vec<(&str, SpmmMaterial)> = vec![
        ("stroke", stroke(&m, 20)),
        (
            "cluster scale",
            m.with_weight_scale(&WeightTarget::cluster(1), [1.5, 1.2, 0.5])
                .expect("scale"),
        ),
        ("basis", m.with_basis(2, 1, lambert).expect("basis")),
        (
            "added basis",
            m.with_basis_added(0, lambert).expect("add").0,
        ),
        ("removed basis", m.with_basis_removed(1, 0).expect("remove")),
        ("residual off", m.with_cluster_residual_off(2).expect("off")),
        ("mute", m.with_view(view.clone()).expect("view")),
        ("unchanged", m.clone()),
    ];
    for (name, after) in edits {
        let d = m.delta_to(&after).expect(name);
        assert_eq!(d.is_empty(), name == "unchanged", "{name}");
        same(&m.stepped(&d, Step::Forward).expect(name), &after);
        same(&after.stepped(&d, Step::Back).expect(name), &m);
        let read = PackDelta::decode(&d.encode()).expect(name);
        assert_eq!(read, d, "{name}: bytes round trip");
        same(&m.stepped(&read, Step::Forward).expect(name), &after);
    }
}

#[test]
fn a_stroke_keeps_only_its_texels_and_shares_the_residual() {
    let m = sample_material(64, 64, 4, Some(3));
    let after = stroke(&m, 100);
    let d = m.delta_to(&after).expect("delta");
    assert!(d.changed_texels().len() <= 5 && !d.changed_texels().is_empty());
    assert!(
        d.bytes() < 2_000,
        "a 5-texel stroke keeps {} bytes",
        d.bytes()
    );
    let back = after.stepped(&d, Step::Back).expect("back");
    assert!(Arc::ptr_eq(
        back.shared_residual().expect("residual"),
        after.shared_residual().expect("residual")
    ));
}

#[test]
fn chained_deltas_replay_a_session() {
    let mut m = sample_material(16, 16, 2, Some(1));
    let start = m.clone();
    let mut deltas = Vec::new();
    for i in 0..20 {
        let next = stroke(&m, (i * 11) % 250);
        deltas.push(m.delta_to(&next).expect("delta"));
        m = next;
    }
    let mut replay = start.clone();
    for d in &deltas {
        replay = replay.stepped(d, Step::Forward).expect("forward");
    }
    same(&replay, &m);
    for d in deltas.iter().rev() {
        replay = replay.stepped(d, Step::Back).expect("back");
    }
    same(&replay, &start);
}

#[test]
fn a_delta_refuses_a_material_it_does_not_start_from() {
    let m = sample_material(12, 9, 3, Some(2));
    let d = m.delta_to(&stroke(&m, 20)).expect("delta");
    // Stepping forward twice: the texels no longer hold the starting weights.
    let once = m.stepped(&d, Step::Forward).expect("once");
    assert!(matches!(
        once.stepped(&d, Step::Forward),
        Err(DeltaError::Diverged(_))
    ));
    let other = sample_material(10, 9, 3, Some(2));
    assert!(matches!(
        other.stepped(&d, Step::Forward),
        Err(DeltaError::Mismatch(..))
    ));
    assert_eq!(m.delta_to(&other), Err(DeltaError::Unrelated));
}

#[test]
fn damaged_bytes_are_errors_at_every_cut_and_flip() {
    let m = sample_material(8, 8, 2, Some(1));
    let after = stroke(&m, 3)
        .with_cluster_residual_off(1)
        .expect("off")
        .with_basis_added(0, m.clusters()[1].bases[0])
        .expect("add")
        .0;
    let bytes = m.delta_to(&after).expect("delta").encode();
    for cut in 0..bytes.len() {
        assert!(PackDelta::decode(&bytes[..cut]).is_err(), "cut at {cut}");
    }
    // A flipped byte either fails to read, or reads as a delta that steps to an
    // error or to a valid material: never a panic.
    for i in (0..bytes.len()).step_by(7) {
        let mut b = bytes.clone();
        b[i] ^= 0x5a;
        if let Ok(d) = PackDelta::decode(&b) {
            let _ = m.stepped(&d, Step::Forward);
        }
    }
}
