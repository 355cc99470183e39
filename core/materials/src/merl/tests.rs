//! Tests of the MERL module: the file layout and scales pinned by hand-built bytes,
//! every validation fault, the reference reader's indexing re-derived independently,
//! reciprocity and non-negativity of both lookups, tabulation (round trip, Lambertian
//! exactness), and the sampler (chi-square against its pdf, positivity, shape).

use std::f64::consts::{FRAC_1_PI, FRAC_PI_2, PI};

use glam::{DVec2, DVec3};

use super::sample::{PHI_BINS, Z_BINS};
use super::*;
use crate::brdf::chi2_tests::{SIGNIFICANCE, histogram, p_value};
use crate::brdf::{AnalyticBrdf, BrdfModel, warp};
use crate::rng::SampleStream;

/// A file's bytes built by hand, independently of `write_to`: the header, then per
/// channel `value(channel, cell)` for every cell.
fn file_bytes(dims: [i32; 3], value: impl Fn(usize, usize) -> f64) -> Vec<u8> {
    let mut out = Vec::with_capacity(FILE_BYTES as usize);
    for d in dims {
        out.extend_from_slice(&d.to_le_bytes());
    }
    for channel in 0..3 {
        for cell in 0..CELLS {
            out.extend_from_slice(&value(channel, cell).to_le_bytes());
        }
    }
    out
}

/// A table of replayable random values in [0, 3000), a quarter of the cells of each
/// channel without data when `holes` is set.
fn random_table(seed: u64, holes: bool) -> MerlBrdf {
    let stored = (0..CELLS as u64)
        .map(|cell| {
            let mut s = SampleStream::new(&[seed, cell]);
            [0, 1, 2].map(|_| {
                let v = 3000.0 * s.next();
                if holes && s.next() < 0.25 { -1.0 } else { v }
            })
        })
        .collect();
    MerlBrdf::from_stored(stored).expect("random values are finite")
}

/// A direction above the horizon; one in four is grazing (cos theta < 0.01).
fn random_upper(key: &[u64]) -> DVec3 {
    let mut s = SampleStream::new(key);
    let grazing = s.next() < 0.25;
    let z = if grazing { 0.01 * s.next() } else { s.next() };
    let z = z.max(1e-9);
    warp::spherical(z, 2.0 * PI * s.next())
}

fn tabulated(model: BrdfModel, params: &[(&str, f64)], albedo: DVec3) -> MerlBrdf {
    let brdf = AnalyticBrdf::new(model, params).expect("test parameters lie in range");
    tabulate(&brdf, albedo).expect("finite model and albedo")
}

#[test]
fn scales_are_pinned() {
    // A file whose stored values are all 1500 reads back as R = 1, G = 1.15, B = 1.66.
    let brdf = MerlBrdf::from_bytes(&file_bytes([90, 90, 180], |_, _| 1500.0)).expect("valid");
    let wi = warp::spherical(0.7, 0.3);
    let wo = warp::spherical(0.4, 2.0);
    let v = brdf.eval(wi, wo);
    for (got, want) in v.to_array().into_iter().zip([1.0, 1.15, 1.66]) {
        assert!((got - want).abs() < 1e-15, "{v} vs (1, 1.15, 1.66)");
    }
}

#[test]
fn channel_blocks_are_red_green_blue_in_file_order() {
    let brdf = MerlBrdf::from_bytes(&file_bytes([90, 90, 180], |channel, _| {
        1500.0 * (channel + 1) as f64
    }))
    .expect("valid");
    let v = brdf.eval(DVec3::Z, DVec3::Z);
    let want = [1.0, 2.0 * 1.15, 3.0 * 1.66];
    for (got, want) in v.to_array().into_iter().zip(want) {
        assert!((got - want).abs() < 1e-14 * want, "{v} vs {want:?}");
    }
}

#[test]
fn a_marked_cell_is_found_where_the_index_formula_puts_it() {
    // Hand-computed configurations: the half vector on the normal with wi at 45 deg
    // gives theta_d index 45; wi = wo at 0.3 rad gives theta_h index
    // floor(sqrt(0.3 / (pi/2)) * 90) = 39; phi_d 100.5 deg gives index 100, and
    // 250.5 deg folds to 70.5 deg, index 70.
    let at = |a: f64, p_deg: f64| {
        let p = p_deg.to_radians();
        let wi = DVec3::new(a.sin() * p.cos(), a.sin() * p.sin(), a.cos());
        (wi, DVec3::new(-wi.x, -wi.y, wi.z))
    };
    let b = 0.3f64;
    let tilted = DVec3::new(b.sin(), 0.0, b.cos());
    let cases = [
        (at(FRAC_PI_2 / 2.0 + 0.001, 0.0), cell_index(0, 45, 0)),
        ((tilted, tilted), cell_index(39, 0, 0)),
        (at(0.2, 100.5), cell_index(0, 11, 100)),
        (at(0.2, 250.5), cell_index(0, 11, 70)),
    ];
    for ((wi, wo), cell) in cases {
        // Mark the one cell: its stored value is 3000 in every channel, 0 elsewhere.
        let brdf = MerlBrdf::from_bytes(&file_bytes([90, 90, 180], |_, c| {
            if c == cell { 3000.0 } else { 0.0 }
        }))
        .expect("valid");
        assert_eq!(HalfDiff::from_directions(wi, wo).cell(), cell, "{wi} {wo}");
        let v = brdf.eval(wi, wo);
        assert!((v.x - 2.0).abs() < 1e-14, "cell {cell} not looked up: {v}");
    }
}

/// The reference reader's computation, re-derived from its description: the half
/// vector, `wi` rotated by -phi_h about the normal then by -theta_h about the
/// binormal, acos/atan2 of the result, and the three index maps.
fn reference_cell(wi: DVec3, wo: DVec3) -> (usize, [f64; 3]) {
    let h = (wi + wo).normalize();
    let theta_h = h.z.clamp(-1.0, 1.0).acos();
    let phi_h = h.y.atan2(h.x);
    let rot_z = |v: DVec3, a: f64| {
        DVec3::new(
            v.x * a.cos() - v.y * a.sin(),
            v.x * a.sin() + v.y * a.cos(),
            v.z,
        )
    };
    let rot_y = |v: DVec3, a: f64| {
        DVec3::new(
            v.x * a.cos() + v.z * a.sin(),
            v.y,
            -v.x * a.sin() + v.z * a.cos(),
        )
    };
    let diff = rot_y(rot_z(wi, -phi_h), -theta_h);
    let theta_d = diff.z.clamp(-1.0, 1.0).acos();
    let mut phi_d = diff.y.atan2(diff.x);
    if phi_d < 0.0 {
        phi_d += PI;
    }
    let continuous = [
        (theta_h / FRAC_PI_2 * 90.0 * 90.0).sqrt(),
        theta_d / FRAC_PI_2 * 90.0,
        phi_d / PI * 180.0,
    ];
    let th = (continuous[0] as usize).min(89);
    let td = (continuous[1] as usize).min(89);
    let pd = (continuous[2] as usize).min(179);
    (pd + td * 180 + th * 180 * 90, continuous)
}

#[test]
fn cells_agree_with_the_reference_computation() {
    let mut edge_cases = 0;
    for k in 0..200_000u64 {
        let (wi, wo) = (random_upper(&[1, k]), random_upper(&[2, k]));
        let (want, continuous) = reference_cell(wi, wo);
        let got = HalfDiff::from_directions(wi, wo).cell();
        if got != want {
            // Only where the reference's own rounding decides: within 1e-6 of an edge.
            let near_edge = continuous
                .iter()
                .any(|c| (c - c.round()).abs() < 1e-6 || *c < 1e-6);
            assert!(
                near_edge,
                "{wi} {wo}: cell {got}, reference {want} ({continuous:?})"
            );
            edge_cases += 1;
        }
    }
    assert!(edge_cases < 20, "{edge_cases} disagreements on bin edges");
}

#[test]
fn bin_centres_map_back_to_their_cells() {
    for cell in (0..CELLS).step_by(997) {
        let (th, td, pd) = cell_indices(cell);
        assert_eq!(cell_index(th, td, pd), cell);
        let centre = HalfDiff::bin_centre(th, td, pd);
        assert_eq!(centre.cell(), cell);
        let (wi, wo) = centre.to_directions(1.234);
        if wi.z > 0.0 && wo.z > 0.0 {
            assert_eq!(HalfDiff::from_directions(wi, wo).cell(), cell, "{centre:?}");
        }
    }
}

#[test]
fn lookups_are_reciprocal_and_never_negative() {
    let brdf = random_table(3, true);
    for k in 0..100_000u64 {
        let (wi, wo) = (random_upper(&[4, k]), random_upper(&[5, k]));
        let (a, b) = (brdf.eval(wi, wo), brdf.eval(wo, wi));
        assert_eq!(a, b, "nearest: {wi} {wo}");
        let (a, b) = (brdf.eval_trilinear(wi, wo), brdf.eval_trilinear(wo, wi));
        assert_eq!(a, b, "trilinear: {wi} {wo}");
        assert!(brdf.eval(wi, wo).min_element() >= 0.0);
        assert!(a.min_element() >= 0.0 && a.is_finite());
    }
    // Below the horizon, and cells without data, give 0.
    let down = DVec3::new(0.6, 0.0, -0.8);
    assert_eq!(brdf.eval(down, DVec3::Z), DVec3::ZERO);
    assert_eq!(brdf.eval(DVec3::Z, down), DVec3::ZERO);
    assert_eq!(brdf.eval_trilinear(down, DVec3::Z), DVec3::ZERO);
    assert_eq!(
        brdf.eval(DVec3::X, DVec3::Z),
        DVec3::ZERO,
        "cos = 0 is not above"
    );
    let hole = (0..CELLS)
        .find(|&c| brdf.stored()[c][1] < 0.0)
        .expect("a quarter of the cells have holes");
    let (th, td, pd) = cell_indices(hole);
    let hd = HalfDiff::bin_centre(th, td, pd);
    let (wi, wo) = hd.to_directions(0.0);
    if wi.z > 0.0 && wo.z > 0.0 {
        assert_eq!(brdf.eval(wi, wo).y, 0.0);
    }
    assert_eq!(brdf.cell_value(hole).y, 0.0);
}

#[test]
fn trilinear_agrees_with_nearest_at_bin_centres() {
    let brdf = random_table(6, false);
    let mut checked = 0;
    for cell in (0..CELLS).step_by(101) {
        let (th, td, pd) = cell_indices(cell);
        let phi_h = 2.0 * PI * SampleStream::new(&[7, cell as u64]).next();
        let (wi, wo) = HalfDiff::bin_centre(th, td, pd).to_directions(phi_h);
        if wi.z <= 0.0 || wo.z <= 0.0 {
            continue;
        }
        let (n, t) = (brdf.eval(wi, wo), brdf.eval_trilinear(wi, wo));
        // At a centre the seven other weights are rounding errors of the angles,
        // amplified at grazing theta_d; a wrong centre would be off by O(1).
        assert!(
            (n - t).abs().max_element() <= 1e-6 * n.max_element(),
            "cell {cell}: nearest {n}, trilinear {t}"
        );
        checked += 1;
    }
    assert!(checked > 5000, "only {checked} centres above the horizon");
    // Between centres it interpolates: halfway in phi_d between two cells is their mean.
    let (a, b) = (
        HalfDiff::bin_centre(10, 20, 30),
        HalfDiff::bin_centre(10, 20, 31),
    );
    let mid = HalfDiff {
        phi_d: 0.5 * (a.phi_d + b.phi_d),
        ..a
    };
    let (wi, wo) = mid.to_directions(0.0);
    let want = 0.5 * (brdf.cell_value(a.cell()) + brdf.cell_value(b.cell()));
    let got = brdf.eval_trilinear(wi, wo);
    assert!(
        (got - want).abs().max_element() < 1e-9 * want.max_element(),
        "{got} vs {want}"
    );
}

#[test]
fn tabulated_file_reads_back_cell_for_cell() {
    let brdf = tabulated(
        BrdfModel::CookTorrance,
        &[("m", 0.2), ("f0", 0.5)],
        DVec3::new(0.9, 0.6, 0.3),
    );
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("ct.binary");
    brdf.write(&path).expect("write");
    assert_eq!(std::fs::metadata(&path).expect("stat").len(), FILE_BYTES);
    let back = MerlBrdf::read(&path).expect("read back");
    for (cell, (a, b)) in brdf.stored().iter().zip(back.stored()).enumerate() {
        for c in 0..3 {
            assert_eq!(a[c].to_bits(), b[c].to_bits(), "cell {cell} channel {c}");
        }
    }
    assert_eq!(std::fs::read(&path).expect("read"), brdf.to_bytes());
    // The header is the MERL one.
    let bytes = brdf.to_bytes();
    assert_eq!(&bytes[..12], &file_bytes([90, 90, 180], |_, _| 0.0)[..12]);
    // Cells no pair above the horizon reaches hold no data; the others hold the model.
    let (wi, wo) = (warp::spherical(0.8, 0.0), warp::spherical(0.8, PI));
    let f = AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.2), ("f0", 0.5)])
        .expect("valid")
        .eval(wi, wo);
    let v = back.eval(wi, wo);
    assert!((v.x / 0.9 - f).abs() < 0.05 * f, "{v} vs {f}");
    assert!(back.no_data_cells() > 0);
}

#[test]
fn tabulated_lambertian_is_albedo_over_pi_at_every_direction() {
    let albedo = DVec3::new(0.8, 0.5, 0.2);
    let brdf = tabulated(BrdfModel::Lambertian, &[], albedo);
    let want = albedo * FRAC_1_PI;
    for k in 0..200_000u64 {
        let (wi, wo) = (random_upper(&[8, k]), random_upper(&[9, k]));
        for (name, v) in [
            ("nearest", brdf.eval(wi, wo)),
            ("trilinear", brdf.eval_trilinear(wi, wo)),
        ] {
            assert!(
                (v - want).abs().max_element() < 1e-12,
                "{name} at {wi} {wo}: {v} vs {want}"
            );
        }
    }
    let a = brdf.albedo_at_normal();
    assert!((a - albedo).abs().max_element() < 1e-9, "{a} vs {albedo}");
}

#[test]
fn tabulate_refuses_a_bad_albedo() {
    let brdf = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
    for albedo in [DVec3::new(0.5, -0.1, 0.5), DVec3::new(f64::NAN, 0.5, 0.5)] {
        let err = tabulate(&brdf, albedo).expect_err("bad albedo");
        assert!(matches!(err.fault, MerlFault::Albedo { .. }), "{err}");
        assert!(err.to_string().contains("albedo"), "{err}");
    }
}

#[test]
fn wrong_sizes_are_named_with_both_numbers() {
    let good = file_bytes([90, 90, 180], |_, _| 1.0);
    for len in [0, 5, 12, good.len() - 8, good.len() - 1] {
        let err = MerlBrdf::from_bytes(&good[..len]).expect_err("truncated");
        assert!(
            matches!(err.fault, MerlFault::Size { found } if found == len as u64),
            "{err}"
        );
        let msg = err.to_string();
        assert!(
            msg.contains("34992012") && msg.contains(&len.to_string()),
            "{msg}"
        );
    }
    let mut long = good.clone();
    long.push(0);
    assert!(matches!(
        MerlBrdf::from_bytes(&long).expect_err("too long").fault,
        MerlFault::Size { found: 34_992_013 }
    ));
    // Through the file system, the path is named too.
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("short.binary");
    std::fs::write(&path, &good[..1000]).expect("write");
    let msg = MerlBrdf::read(&path).expect_err("truncated").to_string();
    assert!(
        msg.contains("short.binary") && msg.contains("1000 bytes"),
        "{msg}"
    );
    let msg = MerlBrdf::read(&dir.path().join("missing.binary"))
        .expect_err("missing")
        .to_string();
    assert!(
        msg.contains("missing.binary") && msg.contains("cannot read"),
        "{msg}"
    );
}

#[test]
fn wrong_dimensions_are_named() {
    let mut bytes = file_bytes([90, 90, 180], |_, _| 1.0);
    bytes[8..12].copy_from_slice(&360i32.to_le_bytes());
    let err = MerlBrdf::from_bytes(&bytes).expect_err("wrong dims");
    assert!(
        matches!(
            err.fault,
            MerlFault::Dimensions {
                found: [90, 90, 360]
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("90, 90, 360"), "{err}");
    // A file of another resolution is named by its dimensions, not only its size,
    // also when read from disk (where only the header is read).
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("half.binary");
    std::fs::write(&path, &bytes[..1_000_012]).expect("write");
    let err = MerlBrdf::read(&path).expect_err("wrong dims");
    assert!(matches!(err.fault, MerlFault::Dimensions { .. }), "{err}");
}

#[test]
fn non_finite_values_name_channel_and_cell() {
    let cell = cell_index(12, 34, 56);
    for (channel, bad) in [(0, f64::NAN), (1, f64::INFINITY), (2, f64::NEG_INFINITY)] {
        let bytes = file_bytes([90, 90, 180], |c, k| {
            if (c, k) == (channel, cell) { bad } else { 2.0 }
        });
        let err = MerlBrdf::from_bytes(&bytes).expect_err("non-finite");
        assert!(
            matches!(err.fault, MerlFault::NonFinite { channel: ch, cell: ce, .. } if ch == channel && ce == cell),
            "{err}"
        );
        let msg = err.to_string();
        for needle in [
            CHANNELS[channel],
            &format!("cell {cell}"),
            "theta_h index 12",
            "theta_d index 34",
            "phi_d index 56",
            &format!("byte offset {}", 12 + (channel * CELLS + cell) * 8),
        ] {
            assert!(msg.contains(needle), "`{needle}` missing from: {msg}");
        }
    }
}

#[test]
fn a_table_without_data_is_refused() {
    let err = MerlBrdf::from_bytes(&file_bytes([90, 90, 180], |_, _| -1.0)).expect_err("no data");
    assert!(
        matches!(err.fault, MerlFault::NoData { channel: 0 }),
        "{err}"
    );
    assert!(err.to_string().contains("no data"), "{err}");
    // One channel without data is as unusable.
    let err = MerlBrdf::from_bytes(&file_bytes(
        [90, 90, 180],
        |c, _| if c == 2 { -1.0 } else { 1.0 },
    ))
    .expect_err("no blue");
    assert!(
        matches!(err.fault, MerlFault::NoData { channel: 2 }),
        "{err}"
    );
    assert!(err.to_string().contains("blue"), "{err}");
    // A single cell with data is enough.
    MerlBrdf::from_bytes(&file_bytes(
        [90, 90, 180],
        |_, k| if k == 77 { 0.0 } else { -1.0 },
    ))
    .expect("one measured cell");
    assert!(matches!(
        MerlBrdf::from_stored(vec![[1.0; 3]; 10])
            .expect_err("short")
            .fault,
        MerlFault::CellCount { found: 10 }
    ));
}

#[test]
fn a_failed_write_is_named_and_leaves_nothing() {
    let brdf = random_table(10, false);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("no/such/dir/out.binary");
    let err = brdf.write(&path).expect_err("no folder");
    assert!(matches!(err.fault, MerlFault::Write(_)), "{err}");
    assert!(err.to_string().contains("out.binary"), "{err}");
}

fn specular() -> MerlBrdf {
    tabulated(
        BrdfModel::CookTorrance,
        &[("m", 0.15), ("f0", 0.6)],
        DVec3::new(0.9, 0.7, 0.4),
    )
}

/// Chi-square bins over (cos theta_i, phi_i - phi_o), 40 x 48: their edges cut the
/// sampler's 64 x 128 cells, so the test sees where inside a cell samples land.
const CHI_Z: usize = 40;
const CHI_PHI: usize = 48;

fn chi_bin(wo: DVec3, wi: DVec3) -> usize {
    let z = ((wi.z * CHI_Z as f64) as usize).min(CHI_Z - 1);
    let phi = (wi.y.atan2(wi.x) - wo.y.atan2(wo.x)).rem_euclid(2.0 * PI);
    let p = ((phi / (2.0 * PI) * CHI_PHI as f64) as usize).min(CHI_PHI - 1);
    z * CHI_PHI + p
}

/// The integral of `pdf(wo, ·)` over every chi-square bin, exact for a density that
/// is constant on the sampler's cells (equal solid angle dz dphi): the pdf read at
/// each cell's centre (in world azimuth, through the public `pdf`) times the cell's
/// overlap with each bin. The adaptive quadrature of the analytic models' test
/// cannot integrate 8192 steps to the 1e-6 the acceptance check needs.
fn expected_per_bin(pdf: impl Fn(DVec3) -> f64, wo: DVec3) -> Vec<f64> {
    let phi_o = wo.y.atan2(wo.x);
    let mut out = vec![0.0; CHI_Z * CHI_PHI];
    let overlap = |a0: f64, a1: f64, b0: f64, b1: f64| (a1.min(b1) - a0.max(b0)).max(0.0);
    for row in 0..Z_BINS {
        let (z0, z1) = (row as f64 / Z_BINS as f64, (row + 1) as f64 / Z_BINS as f64);
        for col in 0..PHI_BINS {
            let dp = 2.0 * PI / PHI_BINS as f64;
            let (p0, p1) = (col as f64 * dp, (col + 1) as f64 * dp);
            let density = pdf(warp::spherical(0.5 * (z0 + z1), 0.5 * (p0 + p1) + phi_o));
            let bz = (z0 * CHI_Z as f64) as usize..((z1 * CHI_Z as f64).ceil() as usize).min(CHI_Z);
            for iz in bz {
                let oz = overlap(
                    z0,
                    z1,
                    iz as f64 / CHI_Z as f64,
                    (iz + 1) as f64 / CHI_Z as f64,
                );
                let bp = (p0 / (2.0 * PI) * CHI_PHI as f64) as usize
                    ..((p1 / (2.0 * PI) * CHI_PHI as f64).ceil() as usize).min(CHI_PHI);
                for ip in bp {
                    let dq = 2.0 * PI / CHI_PHI as f64;
                    let op = overlap(p0, p1, ip as f64 * dq, (ip + 1) as f64 * dq);
                    out[iz * CHI_PHI + ip] += density * oz * op;
                }
            }
        }
    }
    out
}

fn merl_p_value(brdf: &MerlBrdf, sample_wo: DVec3, wo: DVec3, seed: u64) -> Result<f64, String> {
    let (observed, accepted) = histogram(
        |u| brdf.sample(sample_wo, u).map(|s| s.wi),
        |wi| chi_bin(wo, wi),
        CHI_Z * CHI_PHI,
        seed,
    );
    let expected = expected_per_bin(|wi| brdf.pdf(wo, wi), wo);
    p_value(&observed, &expected, accepted, 1e-9)
}

#[test]
fn sampler_matches_its_pdf() {
    let views = [
        warp::spherical(1.0, 0.0),
        warp::spherical(0.6, 0.9),
        warp::spherical(0.05, 2.5),
        warp::spherical(0.001, -2.0),
    ];
    let brdfs = [specular(), random_table(16, true)];
    let tests = views.len() * brdfs.len();
    let threshold = 1.0 - (1.0 - SIGNIFICANCE).powf(1.0 / tests as f64);
    for (b, brdf) in brdfs.iter().enumerate() {
        for (v, &wo) in views.iter().enumerate() {
            let p = merl_p_value(brdf, wo, wo, 2000 + (10 * b + v) as u64)
                .unwrap_or_else(|e| panic!("table {b}, wo {wo}: {e}"));
            assert!(
                p >= threshold,
                "table {b}, wo {wo}: p-value {p:.3e} < {threshold:.3e}"
            );
        }
    }
}

#[test]
fn chi2_notices_a_sampler_turned_the_wrong_way() {
    // The test must be able to fail on this sampler's likely bug: wi drawn about the
    // wrong azimuth of wo (here mirrored), judged against the true pdf.
    let brdf = specular();
    let wo = warp::spherical(0.6, 0.9);
    let turned = DVec3::new(wo.x, -wo.y, wo.z);
    let p = merl_p_value(&brdf, turned, wo, 77).unwrap_or(0.0);
    assert!(p < 1e-6, "a mirrored sampler went unnoticed: p = {p}");
    // And on a sampler of the neighbouring band of theta_o (2 degrees off).
    let off = warp::spherical((wo.z.acos() + 2f64.to_radians()).cos(), 0.9);
    let p = merl_p_value(&brdf, off, wo, 78).unwrap_or(0.0);
    assert!(p < 1e-6, "a sampler 2 degrees off went unnoticed: p = {p}");
}

#[test]
fn samples_carry_their_pdf_and_follow_the_lobe() {
    let brdf = specular();
    let wo = warp::spherical(0.7, 1.1);
    let mirror = DVec3::new(-wo.x, -wo.y, wo.z);
    let (mut near, mut total) = (0, 0);
    for k in 0..20_000u64 {
        let u = SampleStream::new(&[11, k]).next_2d();
        let Some(s) = brdf.sample(wo, u) else {
            continue;
        };
        total += 1;
        assert!(s.wi.z > 0.0 && s.pdf > 0.0 && s.pdf.is_finite());
        let p = brdf.pdf(wo, s.wi);
        assert!(
            (p - s.pdf).abs() <= 1e-12 * p,
            "{} vs {p} at {}",
            s.pdf,
            s.wi
        );
        if s.wi.dot(mirror) > 20f64.to_radians().cos() {
            near += 1;
        }
    }
    // A lobe of roughness 0.15 puts most of its mass within 20 degrees of the mirror
    // direction; uniform sampling would put 6% there.
    assert!(
        near * 2 > total,
        "{near} of {total} samples near the mirror direction"
    );
    assert!(
        brdf.sample(DVec3::new(0.6, 0.0, -0.8), DVec2::splat(0.5))
            .is_none()
    );
    assert_eq!(brdf.pdf(wo, DVec3::new(0.0, 0.6, -0.8)), 0.0);
}

#[test]
fn pdf_is_positive_wherever_eval_is() {
    for brdf in [specular(), random_table(12, true)] {
        for k in 0..100_000u64 {
            let (wi, wo) = (random_upper(&[13, k]), random_upper(&[14, k]));
            if brdf.eval(wi, wo).max_element() > 0.0 {
                assert!(brdf.pdf(wo, wi) > 0.0, "pdf 0 at {wi} {wo}");
            }
        }
    }
}

#[test]
fn importance_sampled_albedo_matches_the_quadrature() {
    // The sampler's weights f cos / pdf integrate the table it was built from.
    let brdf = specular();
    let want = brdf.albedo_at_normal();
    let n = 200_000u64;
    let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
    for k in 0..n {
        if let Some(s) = brdf.sample(DVec3::Z, SampleStream::new(&[15, k]).next_2d()) {
            let w = brdf.eval(s.wi, DVec3::Z) * s.wi.z / s.pdf;
            sum += w;
            sum2 += w * w;
        }
    }
    let mean = sum / n as f64;
    let se = ((sum2 / n as f64 - mean * mean) / n as f64).max(DVec3::ZERO);
    let se = DVec3::new(se.x.sqrt(), se.y.sqrt(), se.z.sqrt());
    assert!(
        (mean - want).abs().cmple(5.0 * se + 1e-4 * want).all(),
        "MC {mean} +- {se} vs quadrature {want}"
    );
}
