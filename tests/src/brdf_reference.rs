//! The BRDF dictionary against values computed independently from docs/brdf.md by
//! tests/reference/brdf_reference.py (40-digit mpmath, the formulas as written there,
//! angles and all). Directions are 17-digit decimals that both sides read identically.
//!
//! Tolerance: relative 1e-9 with an absolute floor (see `REL_TOL`, `ABS_FLOOR`).

use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};

// Meso evaluates in f64 with cancellation-free forms; the largest measured disagreement
// is 1.3e-12 over 1846 values. 1e-9 still catches any formula slip (a wrong constant, a
// missing cosine, a swapped roughness) while leaving room for the exponent-amplified
// rounding of cos_h^n at n = 1e5 (1e5 x 1e-16) and of Ward's and Beckmann's exponents
// deep in their tails at roughness 1e-4. The spec's wi.h (= wo.h for unit vectors) is
// read by the script as their mean, see `cos_d` there.
const REL_TOL: f64 = 1e-9;
/// Values below this are zero for any renderer; at retro-reflection with f0 = 0 the
/// Schlick factor (1 - wi.h)^5 is 0 for exact unit vectors and ~1e-160 for their
/// binary64 roundings, so only an absolute floor can compare them.
const ABS_FLOOR: f64 = 1e-100;

fn parse_params(s: &str) -> Vec<(String, f64)> {
    s.split(';')
        .filter(|kv| !kv.is_empty())
        .map(|kv| {
            let (k, v) = kv.split_once('=').expect("params are key=value");
            (k.to_string(), v.parse().expect("a number"))
        })
        .collect()
}

fn brdf(model: &str, params: &str) -> AnalyticBrdf {
    let params = parse_params(params);
    let named: Vec<(&str, f64)> = params.iter().map(|(k, v)| (k.as_str(), *v)).collect();
    AnalyticBrdf::new(
        BrdfModel::from_name(model).expect("a model of the spec"),
        &named,
    )
    .expect("reference parameters lie in range")
}

fn vec3(fields: &[&str]) -> DVec3 {
    let v: Vec<f64> = fields
        .iter()
        .map(|f| f.parse().expect("a number"))
        .collect();
    DVec3::new(v[0], v[1], v[2])
}

fn check(ours: f64, reference: f64, what: &str) -> Option<String> {
    let ok = (ours - reference).abs() <= REL_TOL * reference.abs() + ABS_FLOOR;
    (!ok || !ours.is_finite()).then(|| format!("{what}: ours {ours:e}, reference {reference:e}"))
}

#[test]
fn every_model_matches_the_independent_reference() {
    let csv = include_str!("../reference/brdf_values.csv");
    let mut failures = Vec::new();
    let mut rows = 0;
    let mut worst = 0.0f64;
    let mut per_model = std::collections::BTreeMap::<String, usize>::new();
    for (i, line) in csv.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 9, "brdf_values.csv line {}", i + 1);
        let b = brdf(f[0], f[1]);
        let (wi, wo) = (vec3(&f[2..5]), vec3(&f[5..8]));
        let reference: f64 = f[8].parse().expect("a number");
        let what = format!("line {} {} {{{}}} wi {wi} wo {wo}", i + 1, f[0], f[1]);
        let ours = b.eval(wi, wo);
        failures.extend(check(ours, reference, &what));
        if reference.abs() > ABS_FLOOR {
            worst = worst.max((ours - reference).abs() / reference.abs());
        }
        rows += 1;
        *per_model.entry(f[0].to_string()).or_default() += usize::from(reference > 0.0);
    }
    // tests/reference/brdf_reference.py writes 1846 rows; every model of the
    // dictionary must be among them.
    assert_eq!(rows, 1846, "the reference table lost or gained rows");
    for model in BrdfModel::ALL {
        assert!(
            per_model.contains_key(model.name()),
            "no reference values for {}",
            model.name()
        );
    }
    println!("{rows} reference values, largest relative error {worst:.2e}");
    // Each model has many non-zero reference values, so the table tests the formulas,
    // not just the horizon rule.
    for (model, nonzero) in &per_model {
        assert!(
            *nonzero >= 40,
            "{model}: only {nonzero} non-zero reference values"
        );
    }
    assert!(
        failures.is_empty(),
        "{} mismatches:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn basis_functions_match_the_independent_reference() {
    let csv = include_str!("../reference/brdf_basis_values.csv");
    let mut failures = Vec::new();
    let mut per_model = std::collections::BTreeMap::<String, usize>::new();
    for (i, line) in csv.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 12, "brdf_basis_values.csv line {}", i + 1);
        let basis =
            BasisFunction::new(brdf(f[0], f[1]), vec3(&f[2..5])).expect("unit upper normal");
        let (wi, wo) = (vec3(&f[5..8]), vec3(&f[8..11]));
        let reference: f64 = f[11].parse().expect("a number");
        let what = format!("line {} {} n {:?} wi {wi} wo {wo}", i + 1, f[0], &f[2..5]);
        failures.extend(check(basis.eval(wi, wo), reference, &what));
        *per_model.entry(f[0].to_string()).or_default() += 1;
    }
    // The script writes 120 rows for each of five models (600).
    let expect: std::collections::BTreeMap<String, usize> = [
        "ashikhmin_shirley",
        "cook_torrance",
        "lambertian",
        "oren_nayar",
        "ward",
    ]
    .into_iter()
    .map(|m| (m.to_string(), 120))
    .collect();
    assert_eq!(
        per_model, expect,
        "the basis reference table lost or gained rows"
    );
    assert!(
        failures.is_empty(),
        "{} mismatches:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
