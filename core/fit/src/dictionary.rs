//! Fitting a cluster's dictionary of basis functions rho_j (docs/brdf.md) to its
//! representatives (Wu et al. 2011 via Silva & Santos 2013, section 3; the seed used
//! IPOPT). Per representative, greedily: fit each of the seven models (parameters and
//! normal) to what the bases kept so far leave unexplained, take the best, refine all
//! kept bases jointly, and keep it only if it lowers the squared error by more than
//! `min_gain` of the representative's energy. Fits are Levenberg-Marquardt with
//! forward-difference Jacobians and variable projection (the non-negative weights are
//! solved exactly by NNLS at every step), on log coordinates for exponents and
//! roughnesses, clamped into the spec ranges, so every fitted basis is valid.

use glam::DVec3;
use nalgebra::{DMatrix, DVector};

use super::lasso::nnls_gram;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};

/// Largest tangent of the fitted normal's tilt (about 63 degrees).
const MAX_SLOPE: f64 = 2.0;

/// The direction pairs a fit compares values at.
#[derive(Clone, Debug, Default)]
pub struct Pairs {
    pub wi: Vec<DVec3>,
    pub wo: Vec<DVec3>,
}

impl Pairs {
    pub fn len(&self) -> usize {
        self.wi.len()
    }
    pub fn is_empty(&self) -> bool {
        self.wi.is_empty()
    }
}

/// Settings of the greedy representative fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DictionarySettings {
    /// Bases kept per representative at most.
    pub max_rounds: usize,
    /// A basis is kept only if it lowers the squared error by this fraction of the
    /// representative's energy.
    pub min_gain: f64,
    /// Levenberg-Marquardt iterations per fit.
    pub iterations: usize,
}

impl Default for DictionarySettings {
    fn default() -> Self {
        Self {
            max_rounds: 3,
            min_gain: 2e-3,
            iterations: 30,
        }
    }
}

/// One basis under fit: its model and unconstrained coordinates (parameters in the
/// transformed space of `bounds`, then the normal's two slopes).
#[derive(Clone, Debug, PartialEq)]
struct Candidate {
    model: BrdfModel,
    x: Vec<f64>,
}

/// Per coordinate: (lower, upper, is_log) with is_log meaning x = ln(p + offset).
fn bounds(model: BrdfModel) -> Vec<(f64, f64, Option<f64>)> {
    let mut b: Vec<(f64, f64, Option<f64>)> = model
        .param_specs()
        .iter()
        .map(|s| {
            if s.log_scale {
                let off = if s.min > 0.0 { 0.0 } else { 1.0 };
                ((s.min + off).ln(), (s.max + off).ln(), Some(off))
            } else {
                (s.min, s.max, None)
            }
        })
        .collect();
    b.push((-MAX_SLOPE, MAX_SLOPE, None));
    b.push((-MAX_SLOPE, MAX_SLOPE, None));
    b
}

impl Candidate {
    fn from_params(model: BrdfModel, params: &[f64]) -> Self {
        let b = bounds(model);
        let mut x: Vec<f64> = params
            .iter()
            .zip(&b)
            .map(|(&p, &(_, _, log))| match log {
                Some(off) => (p + off).ln(),
                None => p,
            })
            .collect();
        x.extend([0.0, 0.0]);
        Self { model, x }
    }

    fn clamp(&mut self) {
        for (v, (lo, hi, _)) in self.x.iter_mut().zip(bounds(self.model)) {
            *v = v.clamp(lo, hi);
        }
    }

    fn basis(&self) -> BasisFunction {
        let specs = self.model.param_specs();
        let b = bounds(self.model);
        let named: Vec<(&str, f64)> = specs
            .iter()
            .zip(&self.x)
            .zip(&b)
            .map(|((s, &x), &(lo, hi, log))| {
                let x = x.clamp(lo, hi);
                let p = match log {
                    Some(off) => x.exp() - off,
                    None => x,
                };
                (s.name, p.clamp(s.min, s.max))
            })
            .collect();
        let brdf = AnalyticBrdf::new(self.model, &named)
            .expect("coordinates are clamped into the spec ranges");
        let p = specs.len();
        let n = DVec3::new(-self.x[p], -self.x[p + 1], 1.0).normalize();
        BasisFunction::new(brdf, n).expect("a normalised normal with z > 0 is valid")
    }

    fn column(&self, pairs: &Pairs) -> Vec<f64> {
        let b = self.basis();
        pairs
            .wi
            .iter()
            .zip(&pairs.wo)
            .map(|(wi, wo)| b.eval(*wi, *wo))
            .collect()
    }
}

/// Starting points per model (natural parameters), tried before the local fit.
fn starts(model: BrdfModel) -> Vec<Vec<f64>> {
    match model {
        BrdfModel::Lambertian => vec![vec![]],
        BrdfModel::OrenNayar => vec![vec![0.1], vec![0.4], vec![0.8]],
        BrdfModel::BlinnPhong => [2.0, 10.0, 50.0, 300.0, 2000.0].map(|n| vec![n]).to_vec(),
        BrdfModel::Ward => [0.03, 0.1, 0.25, 0.5].map(|a| vec![a, a]).to_vec(),
        BrdfModel::CookTorrance => [0.05, 0.15, 0.35, 0.6].map(|m| vec![m, 0.5]).to_vec(),
        BrdfModel::Lafortune => [2.0, 10.0, 50.0, 300.0]
            .map(|n| vec![-1.0, -1.0, 1.0, n])
            .to_vec(),
        BrdfModel::AshikhminShirley => [5.0, 30.0, 200.0, 1500.0].map(|n| vec![n, n, 0.5]).to_vec(),
    }
}

/// Non-negative weights of `columns` for `y` and the squared error they leave.
fn project(columns: &[Vec<f64>], y: &[f64]) -> (Vec<f64>, f64) {
    let k = columns.len();
    let g = DMatrix::from_fn(k, k, |i, j| dot(&columns[i], &columns[j]));
    let b: Vec<f64> = columns.iter().map(|c| dot(c, y)).collect();
    let w = nnls_gram(&g, &b, &(0..k).collect::<Vec<_>>());
    let sse = residual(columns, &w, y).iter().map(|r| r * r).sum();
    (w, sse)
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn residual(columns: &[Vec<f64>], w: &[f64], y: &[f64]) -> Vec<f64> {
    let mut r = y.to_vec();
    for (c, &wk) in columns.iter().zip(w) {
        if wk != 0.0 {
            for (ri, ci) in r.iter_mut().zip(c) {
                *ri -= wk * ci;
            }
        }
    }
    r
}

/// Residual vector of a candidate set with its projected weights.
fn set_residual(set: &[Candidate], y: &[f64], pairs: &Pairs) -> (Vec<f64>, f64) {
    let cols: Vec<Vec<f64>> = set.iter().map(|c| c.column(pairs)).collect();
    let (w, sse) = project(&cols, y);
    (residual(&cols, &w, y), sse)
}

/// Levenberg-Marquardt over every coordinate of `set` jointly (variable projection
/// for the weights). Returns the final squared error.
fn refine(set: &mut [Candidate], y: &[f64], pairs: &Pairs, iterations: usize) -> f64 {
    let (mut r, mut sse) = set_residual(set, y, pairs);
    let n_coords: usize = set.iter().map(|c| c.x.len()).sum();
    if n_coords == 0 {
        return sse;
    }
    let mut lambda = 1e-3;
    let h = 1e-5;
    for _ in 0..iterations {
        // Forward-difference Jacobian of the residual.
        let mut jac = DMatrix::<f64>::zeros(r.len(), n_coords);
        let mut col = 0;
        for s in 0..set.len() {
            for k in 0..set[s].x.len() {
                let mut trial = set.to_vec();
                let (lo, hi, _) = bounds(trial[s].model)[k];
                // Step inwards at an upper bound so the difference stays inside.
                let step = if trial[s].x[k] + h > hi { -h } else { h };
                trial[s].x[k] = (trial[s].x[k] + step).clamp(lo, hi);
                let (rt, _) = set_residual(&trial, y, pairs);
                for (i, (a, b)) in rt.iter().zip(&r).enumerate() {
                    jac[(i, col)] = (a - b) / step;
                }
                col += 1;
            }
        }
        let jt = jac.transpose();
        let jtj = &jt * &jac;
        let g = &jt * DVector::from_column_slice(&r);
        let mut improved = false;
        for _try in 0..8 {
            let mut a = jtj.clone();
            for i in 0..n_coords {
                a[(i, i)] += lambda * (jtj[(i, i)] + 1e-12);
            }
            let Some(delta) = a.cholesky().map(|c| c.solve(&(-&g))) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = set.to_vec();
            let mut idx = 0;
            for c in trial.iter_mut() {
                for v in c.x.iter_mut() {
                    *v += delta[idx];
                    idx += 1;
                }
                c.clamp();
            }
            let (rt, st) = set_residual(&trial, y, pairs);
            if st < sse {
                let rel = (sse - st) / sse.max(1e-300);
                set.clone_from_slice(&trial);
                r = rt;
                sse = st;
                lambda = (lambda / 3.0).max(1e-9);
                improved = rel > 1e-7;
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    sse
}

/// The best single basis of `model` for the target `t` (non-negative scale), from
/// its starting points, refined.
fn fit_single(model: BrdfModel, t: &[f64], pairs: &Pairs, iterations: usize) -> (Candidate, f64) {
    let mut best: Option<(Candidate, f64)> = None;
    for p in starts(model) {
        let c = Candidate::from_params(model, &p);
        let (_, sse) = project(&[c.column(pairs)], t);
        if best.as_ref().is_none_or(|b| sse < b.1) {
            best = Some((c, sse));
        }
    }
    let (c, _) = best.expect("every model has a starting point");
    let mut set = [c];
    let sse = refine(&mut set, t, pairs, iterations);
    let [c] = set;
    (c, sse)
}

/// The best basis to add to `others` for `y`: every model is fitted alone to what
/// `others` leave, the three best are refined jointly with `others`, the lowest
/// squared error wins. Returns the refined set and its error.
fn best_addition(
    others: &[Candidate],
    y: &[f64],
    pairs: &Pairs,
    settings: &DictionarySettings,
) -> (Vec<Candidate>, f64) {
    let target = if others.is_empty() {
        y.to_vec()
    } else {
        set_residual(others, y, pairs).0
    };
    let mut singles: Vec<(Candidate, f64)> = BrdfModel::ALL
        .iter()
        .map(|&m| fit_single(m, &target, pairs, settings.iterations))
        .collect();
    singles.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut best: Option<(Vec<Candidate>, f64)> = None;
    for (c, _) in singles.into_iter().take(3) {
        let mut trial = others.to_vec();
        trial.push(c);
        let s = refine(&mut trial, y, pairs, settings.iterations);
        if best.as_ref().is_none_or(|b| s < b.1) {
            best = Some((trial, s));
        }
    }
    best.expect("seven models give candidates")
}

/// Keeps the bases of `set` with a positive projected weight.
fn prune(set: Vec<Candidate>, y: &[f64], pairs: &Pairs) -> Vec<Candidate> {
    let cols: Vec<Vec<f64>> = set.iter().map(|c| c.column(pairs)).collect();
    let (w, _) = project(&cols, y);
    set.into_iter()
        .zip(w)
        .filter(|(_, w)| *w > 0.0)
        .map(|(c, _)| c)
        .collect()
}

/// Fits the bases of one representative (mono values `y` at `pairs`): the greedy
/// selection with joint refinement described in the module header, then one pass
/// that re-chooses each kept basis given the others (a first greedy pick is often a
/// compromise lobe that a later pick makes unnecessary).
pub fn fit_representative(
    y: &[f64],
    pairs: &Pairs,
    settings: &DictionarySettings,
) -> Vec<BasisFunction> {
    let energy = dot(y, y);
    if energy <= 0.0 {
        return Vec::new();
    }
    let mut chosen: Vec<Candidate> = Vec::new();
    let mut sse = energy;
    for _round in 0..settings.max_rounds {
        let (trial, s) = best_addition(&chosen, y, pairs, settings);
        if sse - s > settings.min_gain * energy {
            chosen = prune(trial, y, pairs);
            sse = s;
        } else {
            break;
        }
    }
    if chosen.len() > 1 {
        for i in 0..chosen.len() {
            if i >= chosen.len() {
                break;
            }
            let mut others = chosen.clone();
            others.remove(i);
            let (trial, s) = best_addition(&others, y, pairs, settings);
            if s < sse * (1.0 - 1e-6) {
                chosen = prune(trial, y, pairs);
                sse = s;
            }
        }
    }
    chosen.iter().map(Candidate::basis).collect()
}

/// Whether two bases are the same function for a dictionary (same model, parameters
/// within 1e-3 relative, normals within 1e-3).
pub fn near_duplicate(a: &BasisFunction, b: &BasisFunction) -> bool {
    a.brdf().model() == b.brdf().model()
        && a.normal().distance(b.normal()) < 1e-3
        && a.brdf()
            .param_values()
            .iter()
            .zip(b.brdf().param_values())
            .all(|(x, y)| (x - y).abs() <= 1e-3 * x.abs().max(y.abs()).max(1e-6))
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::btf::directions;

    fn pairs() -> Pairs {
        let d = directions::rings(&[(0.0, 1), (20.0, 6), (40.0, 8), (60.0, 10), (75.0, 8)]);
        let mut p = Pairs::default();
        for wi in &d {
            for wo in &d {
                p.wi.push(*wi);
                p.wo.push(*wo);
            }
        }
        p
    }

    #[test]
    fn recovers_a_single_tilted_ward_lobe() {
        let p = pairs();
        let truth = BasisFunction::new(
            AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.2), ("ay", 0.12)]).expect("valid"),
            DVec3::new(0.15, -0.1, 1.0).normalize(),
        )
        .expect("valid");
        let y: Vec<f64> =
            p.wi.iter()
                .zip(&p.wo)
                .map(|(a, b)| 0.7 * truth.eval(*a, *b))
                .collect();
        let (c, sse) = fit_single(BrdfModel::Ward, &y, &p, 60);
        assert!(
            sse < 1e-8 * dot(&y, &y),
            "relative sse {}",
            sse / dot(&y, &y)
        );
        let got = c.basis();
        let v = got.brdf().param_values();
        assert!(
            (v[0] - 0.2).abs() < 1e-3 && (v[1] - 0.12).abs() < 1e-3,
            "{v:?}"
        );
        assert!(got.normal().distance(truth.normal().normalize()) < 1e-3);
    }

    #[test]
    fn a_diffuse_plus_specular_mixture_keeps_two_bases() {
        let p = pairs();
        let lamb = BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
            .expect("valid");
        let ct = BasisFunction::new(
            AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.25), ("f0", 0.6)]).expect("valid"),
            DVec3::Z,
        )
        .expect("valid");
        let y: Vec<f64> =
            p.wi.iter()
                .zip(&p.wo)
                .map(|(a, b)| 0.5 * lamb.eval(*a, *b) + 0.3 * ct.eval(*a, *b))
                .collect();
        let bases = fit_representative(&y, &p, &DictionarySettings::default());
        assert!((2..=3).contains(&bases.len()), "{bases:?}");
        let cols: Vec<Vec<f64>> = bases
            .iter()
            .map(|b| {
                p.wi.iter()
                    .zip(&p.wo)
                    .map(|(a, c)| b.eval(*a, *c))
                    .collect()
            })
            .collect();
        let (_, sse) = project(&cols, &y);
        assert!(
            sse < 1e-6 * dot(&y, &y),
            "relative sse {} {bases:?}",
            sse / dot(&y, &y)
        );
    }
}
