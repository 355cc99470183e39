use std::path::Path;
use std::sync::atomic::AtomicBool;

use super::*;

fn run(text: &str) -> Btf {
    let setup = parse_recipe(text, Path::new("."), "test.toml").expect("valid recipe");
    synthesize(&setup, &AtomicBool::new(false), &|_, _| {}).expect("synthesis runs")
}

const FLAT: &str = r#"
version = 1
name = "flat"
width = 4
height = 3
direction_rings = [[0.0, 1], [40.0, 5], [75.0, 6]]
interreflection_samples = 8
[mesostructure]
kind = "flat"
[[region]]
name = "paper"
[[region.lobe]]
model = "lambertian"
weight = [0.8, 0.5, 0.2]
"#;

#[test]
fn flat_lambertian_is_albedo_over_pi_times_cos() {
    let btf = run(FLAT);
    assert_eq!(btf.light_dirs().len(), 12);
    for t in 0..btf.texels() {
        for (l, wi) in btf.light_dirs().iter().enumerate() {
            for v in 0..btf.view_dirs().len() {
                let got = btf.value(t, l, v);
                for (c, albedo) in [0.8, 0.5, 0.2].iter().enumerate() {
                    let want = albedo / std::f64::consts::PI * wi.z;
                    let err = (f64::from(got[c]) - want).abs();
                    assert!(
                        err <= 1e-6 * want,
                        "texel {t} light {l} view {v}: {} vs {want}",
                        got[c]
                    );
                }
            }
        }
    }
}

fn weave(depth: f64) -> String {
    format!(
        r#"
version = 1
name = "weave"
width = 8
height = 8
direction_rings = [[0.0, 1], [75.0, 8]]
detail = 4
supersample = 1
[mesostructure]
kind = "weave"
depth = {depth}
threads = 2
[[region]]
[[region.lobe]]
model = "lambertian"
weight = [0.7, 0.7, 0.7]
[[region]]
[[region.lobe]]
model = "lambertian"
weight = [0.7, 0.7, 0.7]
[[region]]
[[region.lobe]]
model = "lambertian"
weight = [0.7, 0.7, 0.7]
"#
    )
}

#[test]
fn a_tall_weave_shadows_grazing_light() {
    let flat = run(&weave(0.0));
    let tall = run(&weave(10.0));
    // Mean over texels, views and channels at light l.
    let mean_at = |b: &Btf, l: usize| {
        let mut s = 0.0;
        let mut n = 0.0;
        for t in 0..b.texels() {
            for v in 0..b.view_dirs().len() {
                s += f64::from(b.value(t, l, v)[0]);
                n += 1.0;
            }
        }
        s / n
    };
    let cos75 = 75f64.to_radians().cos();
    let flat_grazing = (1..9).map(|l| mean_at(&flat, l)).sum::<f64>() / 8.0;
    assert!((flat_grazing - 0.7 / std::f64::consts::PI * cos75).abs() < 1e-6);
    let tall_grazing = (1..9).map(|l| mean_at(&tall, l)).sum::<f64>() / 8.0;
    assert!(
        tall_grazing < 0.9 * flat_grazing,
        "grazing light: tall {tall_grazing} vs flat {flat_grazing}"
    );
    // Some texel is fully shadowed at grazing light while lit from above.
    let shadowed = (0..tall.texels())
        .any(|t| (1..9).any(|l| tall.value(t, l, 0)[0] == 0.0) && tall.value(t, 0, 0)[0] > 0.0);
    assert!(shadowed);
    // Masking: the tall weave's values vary with the view direction at a fixed light.
    let t = 5;
    let views: Vec<f32> = (0..9).map(|v| tall.value(t, 0, v)[0]).collect();
    assert!(
        views.iter().any(|x| (x - views[0]).abs() > 1e-3),
        "{views:?}"
    );
}

#[test]
fn interreflection_in_a_v_groove_matches_the_view_factor() {
    // An infinite Lambertian V-groove (albedo a, walls at 45 degrees, 2 texels deep,
    // one groove per 4-texel tile, constant along y) lit and seen from the zenith.
    // Every wall is lit with irradiance cos 45 and leaves radiance L = a cos 45 / pi;
    // a point P of one wall sees only the opposite wall (rays over the peaks leave
    // the slab), so one bounce adds a L F(P) to its BTF, with F(P) the 2D view
    // factor to the opposite wall: (|sin phi_top - sin phi_valley|) / 2, phi the
    // angles from P's normal to that wall's ends.
    let dir = tempfile::tempdir().expect("dir");
    let (detail, tile) = (4usize, 4usize);
    let n = tile * detail;
    let mut img = crate::image::Image::new(n as u32, detail as u32);
    for j in 0..detail {
        for i in 0..n {
            // Peak at sample 0, valley at sample 8: samples on the kinks, so the
            // bilinear surface is exactly the two planar walls.
            let h = (i as f32 - 8.0).abs() / 8.0;
            img.set(i as u32, j as u32, [h; 3]);
        }
    }
    crate::image::write_exr(&dir.path().join("v.exr"), &img).expect("write");
    let recipe = |samples: u32| {
        format!(
            r#"
version = 1
name = "v"
width = {tile}
height = 1
direction_rings = [[0.0, 1]]
detail = {detail}
supersample = 5
interreflection_samples = {samples}
[mesostructure]
kind = "image"
path = "v.exr"
depth = 2.0
[[region]]
[[region.lobe]]
model = "lambertian"
weight = [0.8, 0.8, 0.8]
"#
        )
    };
    let synth = |samples| {
        let setup = parse_recipe(&recipe(samples), dir.path(), "v").expect("recipe");
        synthesize(&setup, &AtomicBool::new(false), &|_, _| {}).expect("synthesis")
    };
    let (with, without) = (synth(256), synth(0));
    let a = 0.8;
    let cos45 = std::f64::consts::FRAC_1_SQRT_2;
    // The closed form at the synthesizer's sub-sample points (5 x 5 per texel, a
    // quarter sub-cell of the height grid off the centres), averaged per texel.
    let view_factor = |x: f64| {
        // Groove coordinate from its left peak (x = 0.125), mirrored onto the left
        // wall (0 at the peak, 2 at the valley): the groove is symmetric.
        let u = (x - 0.5 / detail as f64).rem_euclid(tile as f64);
        let u = if u > 2.0 { 4.0 - u } else { u };
        let p = DVec2::new(u, 2.0 - u);
        let normal = DVec2::new(1.0, 1.0).normalize();
        let sin_to = |q: DVec2| normal.perp_dot((q - p).normalize());
        let (valley, top) = (DVec2::new(2.0, 0.0), DVec2::new(4.0, 2.0));
        0.5 * (sin_to(top) - sin_to(valley)).abs()
    };
    let off = 0.25 / (5.0 * detail as f64);
    let (mut gains, mut closed) = (0.0, 0.0);
    for t in 0..tile {
        let expected = (0..5)
            .map(|k| view_factor(t as f64 + (k as f64 + 0.5) / 5.0 + off))
            .sum::<f64>()
            / 5.0
            * a
            * (a * cos45 / std::f64::consts::PI);
        let gain = f64::from(with.value(t, 0, 0)[0]) - f64::from(without.value(t, 0, 0)[0]);
        let direct = f64::from(without.value(t, 0, 0)[0]);
        assert!(
            (direct - a / std::f64::consts::PI * cos45).abs() < 1e-5,
            "texel {t}: direct {direct}"
        );
        eprintln!("texel {t}: bounce {gain:.5} closed form {expected:.5}");
        // 256 gathers at 25 points per texel: a binomial spread of about 2.5% of F.
        assert!(
            (gain - expected).abs() < 0.08 * expected,
            "texel {t}: one bounce adds {gain:.5}, the view factor gives {expected:.5}"
        );
        (gains, closed) = (gains + gain, closed + expected);
    }
    // Over the tile (6400 gathers per texel, 4 texels) the spread is about 1.3%.
    assert!(
        (gains - closed).abs() < 0.04 * closed,
        "the tile's bounce {gains:.5} against the view factor's {closed:.5}"
    );
}

#[test]
fn synthesis_is_the_same_bytes_on_1_and_2_threads() {
    // docs/fitting.md: independent of the thread count. A weave with inter-reflection
    // (the seeded gather rays) on pools of 1 and 2 threads, encoded as the file holds it.
    let text = weave(4.0).replace(
        "supersample = 1",
        "supersample = 2\ninterreflection_samples = 4",
    );
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        let btf = pool.install(|| run(&text));
        crate::btf::file::encode_btf(&btf, crate::btf::file::BtfPrecision::F32).expect("encode")
    };
    let one = on(1);
    assert!(one == on(2), "1 and 2 threads synthesize different BTFs");
}

#[test]
fn every_procedural_kind_builds_a_tileable_field() {
    for kind in [
        "kind = \"knit\"\ndepth = 2.0\ncolumns = 2\nrows = 3",
        "kind = \"leather\"\ndepth = 1.0\ncells = 5\ncrease = 0.3",
        "kind = \"ribs\"\ndepth = 2.0\nribs = 2\npile = 0.5",
        "kind = \"bumps\"\ndepth = 1.0\ncount = 3\nradius = 0.2",
    ] {
        let text = FLAT.replace("kind = \"flat\"", kind).replace(
            "[[region]]\nname = \"paper\"",
            "[[region]]\n[[region.lobe]]\nmodel = \"lambertian\"\nweight = [0.1, 0.1, 0.1]\n[[region]]\nname = \"paper\"",
        );
        let setup =
            parse_recipe(&text, Path::new("."), "t").unwrap_or_else(|e| panic!("{kind}: {e}"));
        let f = &setup.field;
        assert!(f.h_max > f.h_min, "{kind}: not flat");
        assert!(f.heights.iter().all(|h| h.is_finite()));
        // Tileable: the pattern's height and region at opposite edges of the tile
        // agree (approached from inside, 1e-9 from each edge), for the continuous
        // patterns (the Voronoi cells of leather, the bumps).
        let r: RecipeFile = toml::from_str(&text).expect("recipe");
        let count = match &r.mesostructure {
            Mesostructure::Leather { cells, .. } => *cells as usize,
            Mesostructure::Bumps { count, .. } => *count as usize,
            _ => 0,
        };
        let seeds = pattern_seeds(count, r.seed);
        let at = |u: f64, v: f64| procedural(&r.mesostructure, u, v, &seeds).expect("valid");
        if !(kind.contains("leather") || kind.contains("bumps")) {
            // Knit and ribs are piecewise: ribs' pile is a hash per cell of a 97 x 97
            // lattice and a knit stitch's legs stop at its column's edge (centre up to
            // 0.88, half-width 0.2), so their values jump at every cell or column edge
            // and the tile's edge is one of those; edge limits cannot tell a seam
            // from the pattern there.
            continue;
        }
        let e = 1e-9;
        for k in 0..97 {
            let s = (k as f64 + 0.5) / 97.0;
            for (a, b, edge) in [
                (at(e, s), at(1.0 - e, s), "left/right"),
                (at(s, e), at(s, 1.0 - e), "bottom/top"),
            ] {
                assert!(
                    (a.0 - b.0).abs() < 1e-6 && a.1 == b.1,
                    "{kind}: {edge} edges differ at {s}: {a:?} vs {b:?}"
                );
            }
        }
    }
}

#[test]
fn malformed_recipes_are_named() {
    let cases: Vec<(String, &[&str])> = vec![
        (FLAT.replace("width = 4", "widht = 4"), &["widht", "line"]),
        (
            FLAT.replace("width = 4", "width = 0"),
            &["width", "1..=4096"],
        ),
        (
            FLAT.replace("\"lambertian\"", "\"lambert\""),
            &["region 0", "lobe 0", "lambert"],
        ),
        (
            FLAT.replace("weight = [0.8, 0.5, 0.2]", "weight = [0.8, -0.5, 0.2]"),
            &["region 0 lobe 0", "weight"],
        ),
        (FLAT.replace("version = 1", "version = 2"), &["version 2"]),
        (
            FLAT.replace(
                "kind = \"flat\"",
                "kind = \"weave\"\ndepth = 1.0\nthreads = 2",
            ),
            &["uses region 1", "1 region"],
        ),
        (
            FLAT.replace(
                "kind = \"flat\"",
                "kind = \"weave\"\ndepth = -1.0\nthreads = 2",
            ),
            &["depth", "-1"],
        ),
        (
            FLAT.replace("kind = \"flat\"", "kind = \"flat\"\ndepht = 1.0"),
            &["depht"],
        ),
        (
            FLAT.replace(
                "direction_rings = [[0.0, 1], [40.0, 5], [75.0, 6]]",
                "directions = \"ubo\"",
            ),
            &["ubo", "bonn81"],
        ),
        (
            FLAT.replace("[75.0, 6]", "[95.0, 6]"),
            &["direction_rings", "95"],
        ),
        (
            FLAT.replace(
                "[[region.lobe]]\nmodel = \"lambertian\"",
                "[[region.lobe]]\nmodel = \"ward\"\nparams = { ax = 2.0, ay = 0.1 }",
            ),
            &["ax", "2"],
        ),
    ];
    for (text, needles) in cases {
        let err = parse_recipe(&text, Path::new("."), "t")
            .expect_err("must be refused")
            .to_string();
        for n in needles {
            assert!(err.contains(n), "`{err}` should mention `{n}`");
        }
    }
}

#[test]
fn image_height_fields_check_their_size() {
    let dir = tempfile::tempdir().expect("temp dir");
    let img = crate::image::Image::new(3, 3);
    crate::image::write_image(&dir.path().join("h.png"), &img, 0.0).expect("write");
    let text = FLAT.replace(
        "kind = \"flat\"",
        "kind = \"image\"\ndepth = 1.0\npath = \"h.png\"",
    );
    let err = parse_recipe(&text, dir.path(), "t")
        .expect_err("wrong size")
        .to_string();
    assert!(err.contains("3x3") && err.contains("16x12"), "{err}");
    let missing = text.replace("h.png", "nope.png");
    let err = parse_recipe(&missing, dir.path(), "t")
        .expect_err("missing")
        .to_string();
    assert!(err.contains("nope.png"), "{err}");
}

/// A flat (depth 0) surface of several regions: every texel must be a fixed mixture
/// of its regions' isotropic lobes, the same at every azimuth of a mirror pair. Sub-
/// sample points used to sit exactly on region-cell edges, so the direction's tiny
/// offset of the hit point chose the region (a texel read 1.69 or 0.60 at 75 degrees).
#[test]
fn a_flat_multi_region_texel_does_not_depend_on_the_azimuth() {
    let text = r#"
version = 1
name = "flat leather"
width = 8
height = 8
direction_rings = [[0.0, 1], [75.0, 12]]
detail = 4
supersample = 2
[mesostructure]
kind = "leather"
depth = 0.0
cells = 12
crease = 0.35
[[region]]
[[region.lobe]]
model = "cook_torrance"
params = { m = 0.22, f0 = 0.05 }
weight = [1.0, 1.0, 1.0]
[[region]]
[[region.lobe]]
model = "cook_torrance"
params = { m = 0.45, f0 = 0.04 }
weight = [0.6, 0.6, 0.6]
"#;
    let btf = run(text);
    let dirs = btf.light_dirs().to_vec();
    // Mirror pairs at 75 degrees: light k, view opposite (k + 6 of 12).
    for t in 0..btf.texels() {
        let values: Vec<f32> = (0..12)
            .map(|k| {
                let (l, v) = (1 + k, 1 + (k + 6) % 12);
                assert!((dirs[l].truncate() + dirs[v].truncate()).length() < 1e-9);
                btf.value(t, l, v)[0]
            })
            .collect();
        let (lo, hi) = values
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        assert!(hi - lo <= 1e-5 * hi, "texel {t}: {values:?}");
    }
}
