//! Prepared data: equal to a fresh preparation after an edit, to the reference
//! evaluation, holding only what a render uses, laid out as the device reads it.

use glam::{DVec2, DVec3};

use super::{sample_material, with_half_residual};
use crate::brdf::warp::spherical;
use crate::rng::SampleStream;
use crate::spmm::{EvalSettings, PrepareRequest, SpmmMaterial, TexelFilter};

fn points(n: u64, texels: usize) -> Vec<(usize, DVec3, DVec3)> {
    (0..n)
        .map(|k| {
            let mut s = SampleStream::new(&[21, k]);
            let t = (s.next() * texels as f64) as usize;
            (
                t,
                spherical(s.next().max(0.05), 6.3 * s.next()),
                spherical(s.next().max(0.05), 6.3 * s.next()),
            )
        })
        .collect()
}

/// After a weight edit the residual tables are reused, after a residual edit
/// rebuilt: either way the data evaluates exactly as a fresh preparation.
#[test]
fn data_prepared_after_an_edit_equals_a_fresh_preparation() {
    use crate::spmm::WeightTarget;
    let m = sample_material(6, 5, 4, Some(3));
    let request = PrepareRequest {
        used_clusters: None,
        residual: true,
        max_npca: 2,
    };
    let before = m.prepare(&request);
    let scaled = m
        .with_weight_scale(&WeightTarget::basis(1, 0), [2.0, 0.5, 1.0])
        .expect("valid");
    let off = m.with_cluster_residual_off(2).expect("valid");
    for after in [&scaled, &off] {
        let reused = after.prepare_after_edit(&request, &m, &before);
        let fresh = after.prepare(&request);
        assert_eq!(reused.bytes(), fresh.bytes());
        for (t, wi, wo) in points(500, 30) {
            assert_eq!(reused.eval_texel(t, wi, wo), fresh.eval_texel(t, wi, wo));
            assert_eq!(
                reused.eval_texel(t, wi, wo),
                after.eval_texel(t, wi, wo, true, 2)
            );
        }
    }
    // The weight edit changed what the texels of cluster 1 show.
    let t = (0..30)
        .find(|&t| m.texel_cluster()[t] == 1 && m.texel_weights(t).any(|(j, _)| j == 0))
        .expect("a texel of cluster 1 weighs basis 0");
    let (wi, wo) = (DVec3::new(0.3, 0.1, 0.9).normalize(), DVec3::Z);
    assert_ne!(
        scaled
            .prepare_after_edit(&request, &m, &before)
            .eval_texel(t, wi, wo),
        before.eval_texel(t, wi, wo)
    );
}

/// Bit for bit, whatever the layout: 3 components (cells packed), 8 (cells padded
/// to whole cache lines, `cell_stride`), fewer kept than stored, none, or no
/// residual, in f32 and in half floats; on x86-64 with AVX (and F16C) this checks
/// the 4-wide cell sums too.
#[test]
fn prepared_evaluation_equals_the_reference() {
    let three = sample_material(6, 5, 4, Some(3));
    let eight = sample_material(6, 5, 4, Some(8));
    // Tables of half floats: 3 components packed, 8 padded to one line per cell.
    let (half_three, half_eight) = (with_half_residual(&three), with_half_residual(&eight));
    for (m, residual, max_npca) in [
        (&three, true, usize::MAX),
        (&three, true, 2),
        (&three, true, 0),
        (&three, false, usize::MAX),
        (&eight, true, usize::MAX),
        (&eight, true, 7),
        (&half_three, true, usize::MAX),
        (&half_three, true, 0),
        (&half_eight, true, usize::MAX),
        (&half_eight, true, 5),
    ] {
        let p = m.prepare(&PrepareRequest {
            used_clusters: None,
            residual,
            max_npca,
        });
        for (t, wi, wo) in points(500, 30) {
            assert_eq!(
                p.eval_texel(t, wi, wo),
                m.eval_texel(t, wi, wo, residual, max_npca),
                "{residual} {max_npca}"
            );
        }
        let s = EvalSettings {
            residual,
            max_npca,
            filter: TexelFilter::Bilinear,
            uv_scale: DVec2::new(2.0, 3.0),
        };
        let (wi, wo) = (spherical(0.7, 0.2), spherical(0.5, 2.2));
        for k in 0..100 {
            let uv = DVec2::new(0.013 * k as f64, 1.0 - 0.021 * k as f64);
            assert_eq!(p.eval_uv(uv, wi, wo, &s), m.eval_uv(uv, wi, wo, &s));
        }
    }
}

#[test]
fn only_used_clusters_and_kept_components_are_held() {
    let m = sample_material(6, 5, 4, Some(3));
    let (l, v, texels) = (5, 4, 30);
    let used = m.clusters_of_texels((0..texels).filter(|&t| m.texel_cluster()[t] == 1));
    assert_eq!(used, vec![false, true, false, false]);
    let full = m.prepare(&PrepareRequest {
        used_clusters: None,
        residual: true,
        max_npca: 3,
    });
    let part = m.prepare(&PrepareRequest {
        used_clusters: Some(used),
        residual: true,
        max_npca: 2,
    });
    assert_eq!((full.clusters_used(), part.clusters_used()), (4, 1));
    full.make_all_resident();
    part.make_all_resident();
    // Residual bytes: per used cluster L x V cells of (1 + k) RGB floats, the table
    // rounded up to whole 64-byte lines (k = 2: 180 floats take 12 lines of 16),
    // plus k coefficients per texel.
    assert_eq!(full.bytes().residual, (4 * l * v * 4 * 3 + texels * 3) * 4);
    assert_eq!(part.bytes().residual, (12 * 16 + texels * 2) * 4);
    let off = m.prepare(&PrepareRequest {
        used_clusters: None,
        residual: false,
        max_npca: 3,
    });
    assert_eq!(off.bytes().residual, 0);
    assert!(off.bytes().total() < part.bytes().total());
    // Half-float tables: k = 3, 12 halves a cell, 20 cells in 8 lines plus the
    // spare one, per cluster; the estimate says the same.
    let half = with_half_residual(&m);
    let request = PrepareRequest {
        used_clusters: None,
        residual: true,
        max_npca: 3,
    };
    let halved = half.prepare(&request);
    halved.make_all_resident();
    assert_eq!(halved.bytes().residual, 4 * 9 * 64 + texels * 3 * 4);
    assert_eq!(halved.bytes(), half.prepared_bytes(&request));
    // The estimate a render reports for materials it has not prepared.
    for (prepared, request) in [
        (&full, (None, true, 3)),
        (&part, (Some(m.clusters_of_texels([1usize, 5])), true, 2)),
        (&off, (None, false, 3)),
    ] {
        let request = PrepareRequest {
            used_clusters: request.0,
            residual: request.1,
            max_npca: request.2,
        };
        let fresh = m.prepare(&request);
        fresh.make_all_resident();
        assert_eq!(fresh.bytes(), m.prepared_bytes(&request));
        assert_eq!(
            m.prepared_bytes(&request).total() == prepared.bytes().total(),
            fresh.bytes().total() == prepared.bytes().total()
        );
    }
    // Texels of the used cluster evaluate exactly as the reference with N_PCA = 2.
    for (t, wi, wo) in points(300, texels) {
        if m.texel_cluster()[t] == 1 {
            assert_eq!(part.eval_texel(t, wi, wo), m.eval_texel(t, wi, wo, true, 2));
        }
    }
}

/// The parts a device uploads hold the cells packed, `[light][view][1 + k][3]`,
/// whatever padding the CPU's tables carry (8 components: padded to 32 floats).
#[test]
fn device_parts_hold_the_cells_unpadded() {
    let single = sample_material(6, 5, 4, Some(8));
    // Half-float tables reach the device as f32, unpadded, like f32 ones.
    for m in [&single, &with_half_residual(&single)] {
        device_parts_of(m);
    }
}

fn device_parts_of(m: &SpmmMaterial) {
    let r = m.residual().expect("residual");
    let (nl, nv, k) = (r.light_dirs.len(), r.view_dirs.len(), 8);
    let p = m.prepare(&PrepareRequest {
        used_clusters: None,
        residual: true,
        max_npca: k,
    });
    let parts = p.parts();
    let pr = parts.residual.expect("residual prepared");
    assert_eq!(pr.cells.len(), 4 * nl * nv * (1 + k) * 3);
    for c in 0..4 {
        let base = pr.cluster_offset[c].expect("every cluster prepared");
        for (l, v) in [(0, 0), (nl - 1, nv - 1), (1, 2)] {
            let start = base + (l * nv + v) * (1 + k) * 3;
            let cell: Vec<f32> = (start..start + (1 + k) * 3)
                .map(|i| pr.cells.value(i))
                .collect();
            let m0 = ((c * nl + l) * nv + v) * 3;
            assert_eq!(cell[..3], r.mean[m0..m0 + 3]);
            for kk in 0..k {
                let b = (((c * r.npca + kk) * nl + l) * nv + v) * 3;
                assert_eq!(cell[3 + 3 * kk..6 + 3 * kk], r.components[b..b + 3]);
            }
        }
    }
}

/// A cluster's residual tables are laid out when a texel of it is first evaluated:
/// the bytes grow by exactly that cluster's tables, and every value equals the
/// evaluation of data laid out up front.
#[test]
fn residual_tables_are_laid_out_per_cluster_when_first_reached() {
    let m = sample_material(6, 5, 4, Some(3));
    let (l, v, texels, k) = (5, 4, 30, 3);
    let request = PrepareRequest {
        used_clusters: None,
        residual: true,
        max_npca: k,
    };
    let eager = m.prepare(&request);
    eager.make_all_resident();
    let lazy = m.prepare(&request);
    let table = l * v * (1 + k) * 3 * 4;
    let coefficients = texels * k * 4;
    assert_eq!(lazy.bytes().residual, coefficients, "no table laid out yet");
    let mut reached = [false; 4];
    for (t, wi, wo) in points(400, texels) {
        let c = m.texel_cluster()[t] as usize;
        assert_eq!(
            lazy.eval_texel(t, wi, wo).to_array().map(f64::to_bits),
            eager.eval_texel(t, wi, wo).to_array().map(f64::to_bits)
        );
        reached[c] = true;
        let held = reached.iter().filter(|&&r| r).count();
        assert_eq!(lazy.bytes().residual, coefficients + held * table);
    }
    assert_eq!(
        lazy.bytes(),
        eager.bytes(),
        "every cluster reached in the end"
    );
    // Below the horizon nothing is evaluated, so nothing is laid out.
    let fresh = m.prepare(&request);
    fresh.eval_texel(0, DVec3::new(0.0, 0.6, -0.8), DVec3::Z);
    assert_eq!(fresh.bytes().residual, coefficients);
    // A uv look-up lays out the clusters of the texels the filter reads.
    let s = EvalSettings {
        residual: true,
        max_npca: k,
        filter: TexelFilter::Nearest,
        uv_scale: DVec2::ONE,
    };
    let uv = DVec2::new(0.5 / 6.0, 0.5 / 5.0);
    fresh.make_resident_at(uv, &s);
    assert_eq!(fresh.bytes().residual, coefficients + table);
    // The parts a device uploads hold every used cluster's tables, laid out.
    let parts = fresh.parts();
    let r = parts.residual.expect("residual prepared");
    assert_eq!(r.cells.len() * 4, 4 * table);
    assert_eq!(fresh.bytes(), eager.bytes());
}
