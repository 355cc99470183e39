//! Per-texel sparse non-negative weights (the alpha_j(t) of Silva & Santos 2013 eq. 1).
//! The support is chosen on the non-negative lasso path (the l1 criterion of the
//! stagewise lasso of Zhao and Yu 2007 that Wu et al. 2011 use): penalties
//! lambda_k = lambda_max 0.8^k, each solved by warm-started coordinate descent on
//! unit-norm columns, until the support would exceed `max_bases`. The weights of the
//! chosen support are then refitted per RGB channel without penalty by Lawson-Hanson
//! non-negative least squares, which removes the lasso's shrinkage. Everything works
//! on the Gram matrix G = A^T A and A^T y, so a texel costs O(D^2), not O(pairs).

use nalgebra::{DMatrix, DVector};

/// Non-negative least squares min ||A w - y||^2, w >= 0, in Gram form (`g` = A^T A,
/// `b` = A^T y), restricted to the columns in `cols`, by the active-set method of
/// Lawson and Hanson (1974). Returns one weight per entry of `cols`.
pub fn nnls_gram(g: &DMatrix<f64>, b: &[f64], cols: &[usize]) -> Vec<f64> {
    let n = cols.len();
    let mut w = vec![0.0; n];
    let mut passive = vec![false; n];
    let scale = cols
        .iter()
        .map(|&j| g[(j, j)])
        .fold(0.0, f64::max)
        .max(1e-300);
    let tol = 1e-12 * scale;
    let grad = |w: &[f64], k: usize| {
        let j = cols[k];
        b[j] - (0..n).map(|m| g[(j, cols[m])] * w[m]).sum::<f64>()
    };
    for _outer in 0..3 * n + 3 {
        let pick = (0..n)
            .filter(|&k| !passive[k])
            .map(|k| (k, grad(&w, k)))
            .filter(|&(_, gr)| gr > tol * b.iter().map(|x| x.abs()).fold(1.0, f64::max))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let Some((k, _)) = pick else { break };
        passive[k] = true;
        for _inner in 0..3 * n + 3 {
            let set: Vec<usize> = (0..n).filter(|&k| passive[k]).collect();
            let z = solve_subset(g, b, cols, &set);
            if set.iter().zip(&z).all(|(_, &v)| v > 0.0) {
                for (&k, &v) in set.iter().zip(&z) {
                    w[k] = v;
                }
                break;
            }
            // Step towards z until the first weight reaches zero, then drop the zeros.
            let mut alpha = 1.0f64;
            for (&k, &v) in set.iter().zip(&z) {
                if v <= 0.0 {
                    alpha = alpha.min(w[k] / (w[k] - v).max(1e-300));
                }
            }
            for (&k, &v) in set.iter().zip(&z) {
                w[k] += alpha * (v - w[k]);
                if w[k] <= 1e-14 * (1.0 + v.abs()) {
                    passive[k] = false;
                    w[k] = 0.0;
                }
            }
            if !(0..n).any(|k| passive[k]) {
                break;
            }
        }
    }
    w
}

/// Unconstrained least squares on a subset of columns, with a tiny ridge so a
/// singular subset (two identical columns) still gives a finite answer.
fn solve_subset(g: &DMatrix<f64>, b: &[f64], cols: &[usize], set: &[usize]) -> Vec<f64> {
    let m = set.len();
    let mut a = DMatrix::<f64>::zeros(m, m);
    let mut rhs = DVector::<f64>::zeros(m);
    let mut trace = 0.0;
    for (r, &kr) in set.iter().enumerate() {
        rhs[r] = b[cols[kr]];
        for (c, &kc) in set.iter().enumerate() {
            a[(r, c)] = g[(cols[kr], cols[kc])];
        }
        trace += a[(r, r)];
    }
    for r in 0..m {
        a[(r, r)] += 1e-13 * trace / m as f64 + 1e-300;
    }
    match a.clone().cholesky() {
        Some(ch) => ch.solve(&rhs).iter().copied().collect(),
        None => a
            .lu()
            .solve(&rhs)
            .map(|v| v.iter().copied().collect())
            .unwrap_or_else(|| vec![0.0; m]),
    }
}

/// The support (column indices, ascending) of the sparsest point on the non-negative
/// lasso path of `min 1/2 ||A u - y||^2 + lambda ||u||_1, u >= 0` that still has at most
/// `max_bases` columns, for the summed channel `b` = A^T (r + g + b).
pub fn lasso_support(g: &DMatrix<f64>, b: &[f64], max_bases: usize) -> Vec<usize> {
    let d = b.len();
    let norm: Vec<f64> = (0..d).map(|j| g[(j, j)].max(0.0).sqrt()).collect();
    let usable: Vec<usize> = (0..d).filter(|&j| norm[j] > 1e-300).collect();
    let bn: Vec<f64> = (0..d)
        .map(|j| {
            if norm[j] > 1e-300 {
                b[j] / norm[j]
            } else {
                0.0
            }
        })
        .collect();
    let gn = |i: usize, j: usize| g[(i, j)] / (norm[i] * norm[j]);
    let lambda_max = usable.iter().map(|&j| bn[j]).fold(0.0, f64::max);
    if lambda_max <= 0.0 || max_bases == 0 {
        return Vec::new();
    }
    let mut u = vec![0.0; d];
    let mut best: Vec<usize> = Vec::new();
    let mut lambda = lambda_max;
    for _step in 0..80 {
        lambda *= 0.8;
        // Coordinate descent to convergence at this penalty (warm start).
        for _sweep in 0..500 {
            let mut change: f64 = 0.0;
            for &j in &usable {
                let r = bn[j]
                    - usable
                        .iter()
                        .filter(|&&k| k != j)
                        .map(|&k| gn(j, k) * u[k])
                        .sum::<f64>();
                let new = (r - lambda).max(0.0);
                change = change.max((new - u[j]).abs());
                u[j] = new;
            }
            if change <= 1e-10 * lambda_max {
                break;
            }
        }
        let support: Vec<usize> = usable.iter().copied().filter(|&j| u[j] > 0.0).collect();
        if support.len() > max_bases {
            break;
        }
        best = support;
        if lambda < 1e-7 * lambda_max {
            break;
        }
    }
    best
}

/// `nnls_gram` with upper bounds: `0 <= w[k] <= caps[k]` (the lobe bound's weight
/// caps). Active set on the upper bounds: solve without them, fix the weight most over
/// its cap (by ratio) at the cap, move its contribution to the right-hand side and
/// solve the rest again, until none is over. Always feasible; exact when at most one
/// cap binds, close otherwise (a fixed weight is not released again).
pub fn bounded_nnls_gram(g: &DMatrix<f64>, b: &[f64], cols: &[usize], caps: &[f64]) -> Vec<f64> {
    let n = cols.len();
    let mut fixed: Vec<Option<f64>> = vec![None; n];
    loop {
        let free: Vec<usize> = (0..n).filter(|&k| fixed[k].is_none()).collect();
        let mut rhs = b.to_vec();
        for (k, f) in fixed.iter().enumerate() {
            if let Some(v) = f {
                for (j, r) in rhs.iter_mut().enumerate() {
                    *r -= g[(j, cols[k])] * v;
                }
            }
        }
        let free_cols: Vec<usize> = free.iter().map(|&k| cols[k]).collect();
        let w_free = nnls_gram(g, &rhs, &free_cols);
        let worst = free
            .iter()
            .zip(&w_free)
            .filter(|&(&k, &w)| w > caps[k])
            .map(|(&k, &w)| (k, w / caps[k].max(1e-300)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((k, _)) => fixed[k] = Some(caps[k].max(0.0)),
            None => {
                let mut w = vec![0.0; n];
                for (&k, &v) in free.iter().zip(&w_free) {
                    w[k] = v;
                }
                for (k, f) in fixed.iter().enumerate() {
                    if let Some(v) = f {
                        w[k] = *v;
                    }
                }
                return w;
            }
        }
    }
}

/// Sparse RGB weights of one texel: (column, weight per channel), columns ascending,
/// entries with all three channels zero dropped. `b` holds A^T y per channel; `caps`
/// bounds each column's weight in every channel (infinite: no bound).
pub fn texel_weights(
    g: &DMatrix<f64>,
    b: &[[f64; 3]],
    max_bases: usize,
    caps: &[f64],
) -> Vec<(usize, [f64; 3])> {
    let summed: Vec<f64> = b.iter().map(|c| c[0] + c[1] + c[2]).collect();
    let support = lasso_support(g, &summed, max_bases);
    if support.is_empty() {
        return Vec::new();
    }
    let mut w = vec![[0.0; 3]; support.len()];
    for ch in 0..3 {
        let bc: Vec<f64> = b.iter().map(|c| c[ch]).collect();
        let sc: Vec<f64> = support.iter().map(|&j| caps[j]).collect();
        for (k, v) in bounded_nnls_gram(g, &bc, &support, &sc)
            .into_iter()
            .enumerate()
        {
            w[k][ch] = v;
        }
    }
    support
        .into_iter()
        .zip(w)
        .filter(|(_, w)| w.iter().any(|&x| x > 0.0))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::rng::SampleStream;

    fn random_matrix(rows: usize, cols: usize, seed: u64) -> DMatrix<f64> {
        DMatrix::from_fn(rows, cols, |r, c| {
            SampleStream::new(&[seed, r as u64, c as u64]).at(0)
        })
    }

    #[test]
    fn nnls_matches_brute_force_over_supports() {
        for seed in 0..20 {
            let a = random_matrix(30, 5, seed);
            let y = DVector::from_fn(30, |r, _| {
                SampleStream::new(&[seed, 99, r as u64]).at(0) - 0.3
            });
            let g = a.transpose() * &a;
            let b: Vec<f64> = (a.transpose() * &y).iter().copied().collect();
            let w = nnls_gram(&g, &b, &[0, 1, 2, 3, 4]);
            assert!(w.iter().all(|&x| x >= 0.0));
            let cost = |w: &[f64]| (&a * DVector::from_column_slice(w) - &y).norm_squared();
            // Best over every support with an unconstrained solve that stays feasible.
            let mut best = cost(&[0.0; 5]);
            for mask in 1u32..32 {
                let set: Vec<usize> = (0..5).filter(|k| mask & (1 << k) != 0).collect();
                let z = solve_subset(&g, &b, &[0, 1, 2, 3, 4], &set);
                if z.iter().all(|&v| v >= 0.0) {
                    let mut full = [0.0; 5];
                    for (&k, &v) in set.iter().zip(&z) {
                        full[k] = v;
                    }
                    best = best.min(cost(&full));
                }
            }
            assert!(
                cost(&w) <= best * (1.0 + 1e-9) + 1e-12,
                "seed {seed}: {} vs {best}",
                cost(&w)
            );
        }
    }

    #[test]
    fn lasso_recovers_a_sparse_non_negative_mixture() {
        let a = random_matrix(200, 12, 5);
        let truth = [
            (2usize, [0.5, 0.2, 0.1]),
            (7, [0.3, 0.3, 0.6]),
            (9, [0.0, 0.4, 0.2]),
        ];
        let mut b = vec![[0.0; 3]; 12];
        let g = a.transpose() * &a;
        for ch in 0..3 {
            let mut y = DVector::<f64>::zeros(200);
            for &(j, w) in &truth {
                y += a.column(j) * w[ch];
            }
            let aty = a.transpose() * y;
            for j in 0..12 {
                b[j][ch] = aty[j];
            }
        }
        let w = texel_weights(&g, &b, 9, &[f64::INFINITY; 12]);
        let cols: Vec<usize> = w.iter().map(|e| e.0).collect();
        assert_eq!(cols, [2, 7, 9]);
        for ((_, got), (_, want)) in w.iter().zip(&truth) {
            for ch in 0..3 {
                assert!((got[ch] - want[ch]).abs() < 1e-6, "{got:?} vs {want:?}");
            }
        }
        // A budget of one basis keeps the strongest.
        assert_eq!(texel_weights(&g, &b, 1, &[f64::INFINITY; 12]).len(), 1);
    }

    #[test]
    fn bounded_nnls_keeps_the_caps_and_is_plain_nnls_when_they_are_loose() {
        for seed in 0..20 {
            let a = random_matrix(30, 4, seed + 100);
            let y = DVector::from_fn(30, |r, _| SampleStream::new(&[seed, 7, r as u64]).at(0));
            let g = a.transpose() * &a;
            let b: Vec<f64> = (a.transpose() * &y).iter().copied().collect();
            let cols = [0, 1, 2, 3];
            let free = nnls_gram(&g, &b, &cols);
            let loose = bounded_nnls_gram(&g, &b, &cols, &[f64::INFINITY; 4]);
            assert_eq!(free, loose);
            // Caps at half the free solution's weights bind: every weight within them.
            let caps: Vec<f64> = free.iter().map(|w| 0.5 * w + 0.01).collect();
            let w = bounded_nnls_gram(&g, &b, &cols, &caps);
            for k in 0..4 {
                assert!(
                    w[k] >= 0.0 && w[k] <= caps[k],
                    "seed {seed}: {w:?} vs {caps:?}"
                );
            }
            // With one column the answer is the clamp of the free one, exactly.
            let one = bounded_nnls_gram(&g, &b, &[2], &[0.3]);
            let free_one = nnls_gram(&g, &b, &[2]);
            assert_eq!(one, vec![free_one[0].min(0.3)]);
            // The weights not at their caps are the best non-negative ones given those
            // at their caps: no worse than the clamped free solution there.
            let cost = |w: &[f64]| (&a * DVector::from_column_slice(w) - &y).norm_squared();
            let other: Vec<f64> = (0..4)
                .map(|k| {
                    if w[k] == caps[k] {
                        caps[k]
                    } else {
                        free[k].min(caps[k])
                    }
                })
                .collect();
            assert!(
                cost(&w) <= cost(&other) * (1.0 + 1e-9) + 1e-12,
                "seed {seed}"
            );
        }
    }
}
