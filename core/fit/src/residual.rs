//! The per-cluster residual of the SPMM (Silva & Santos 2013 eq. 3): the mean of the
//! cluster's texels' residual BTF values (BTF minus basis sum) plus a truncated PCA
//! of their deviations, with per-texel coefficients. The principal components come
//! from the eigen-decomposition of the texel-by-texel Gram matrix (nalgebra's
//! symmetric eigen solver; the cluster has far fewer texels than table entries),
//! re-orthonormalised, so the coefficients are exact projections and the error left
//! by the first k components is known in closed form.

use nalgebra::{DMatrix, SymmetricEigen};

/// A cluster's residual model and what it leaves unexplained.
#[derive(Clone, Debug, PartialEq)]
pub struct ClusterResidual {
    /// Mean residual, one value per table entry (`d`).
    pub mean: Vec<f64>,
    /// Up to `npca` orthonormal components, each `d` values.
    pub components: Vec<Vec<f64>>,
    /// Per member texel (in the order given), its coefficient on each component.
    pub coefficients: Vec<Vec<f64>>,
    /// Variance captured by each component (squared singular value).
    pub energy: Vec<f64>,
    /// Squared error of the basis sum alone (residual not used).
    pub sse_without: f64,
    /// Squared error left with the mean and the first k components, k = 0 ..= K.
    pub sse_with: Vec<f64>,
}

impl ClusterResidual {
    /// Fraction of the deviation energy (after the mean) each component retains.
    pub fn retained(&self) -> Vec<f64> {
        let total = self.sse_with[0];
        self.energy
            .iter()
            .map(|e| if total > 0.0 { e / total } else { 0.0 })
            .collect()
    }
}

/// Fits the residual of one cluster: `rows` holds, per member texel, its `d`
/// residual values (BTF minus basis sum) row after row.
///
/// The Gram matrix, the components and the coefficients are each one matrix product
/// over the centred data (a product per component, each through a fresh transposed
/// copy, had cost most of the stage: up to 160 s of a fit); the transposed products
/// read the data's columns in place (`tr_mul`), so no transposed copy is made.
pub fn fit_cluster_residual(rows: &[f64], d: usize, npca: usize) -> ClusterResidual {
    let n = rows.len() / d;
    fit_columns(DMatrix::from_fn(d, n, |j, t| rows[t * d + j]), npca)
}

/// `fit_cluster_residual` of a `d x n` matrix with one texel's residual per column,
/// centred in place: the matrix is the only copy of the data (the fitter's memory
/// budget counts one), its transpose is never formed.
pub fn fit_columns(mut xc: DMatrix<f64>, npca: usize) -> ClusterResidual {
    let (d, n) = xc.shape();
    let sse_without: f64 = xc.norm_squared();
    let mut mean = vec![0.0; d];
    for t in 0..n {
        for (m, x) in mean.iter_mut().zip(xc.column(t).iter()) {
            *m += x;
        }
    }
    for m in mean.iter_mut() {
        *m /= n.max(1) as f64;
    }
    for t in 0..n {
        for (x, m) in xc.column_mut(t).iter_mut().zip(&mean) {
            *x -= m;
        }
    }
    let total: f64 = xc.norm_squared();
    let mut components: Vec<Vec<f64>> = Vec::new();
    if npca > 0 && n > 0 && total > 0.0 {
        let eig = SymmetricEigen::new(xc.tr_mul(&xc));
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let top = eig.eigenvalues[order[0]].max(0.0);
        // The eigenpairs worth a component, largest first.
        let usable: Vec<usize> = order
            .into_iter()
            .take_while(|&i| {
                let lambda = eig.eigenvalues[i];
                lambda > 1e-13 * top && lambda > 0.0
            })
            .collect();
        // Candidates in batches of `npca` (a candidate left with no norm after
        // re-orthonormalisation is skipped, and the next one takes its place).
        for batch in usable.chunks(npca) {
            if components.len() >= npca {
                break;
            }
            let u = DMatrix::from_fn(n, batch.len(), |t, c| {
                eig.eigenvectors[(t, batch[c])] / eig.eigenvalues[batch[c]].sqrt()
            });
            let v_batch = &xc * &u;
            for c in 0..batch.len() {
                if components.len() >= npca {
                    break;
                }
                let mut v: Vec<f64> = v_batch.column(c).iter().copied().collect();
                // Modified Gram-Schmidt against the kept components (twice, for round-off).
                for _ in 0..2 {
                    for kept in &components {
                        let p: f64 = v.iter().zip(kept).map(|(a, b)| a * b).sum();
                        for (a, b) in v.iter_mut().zip(kept) {
                            *a -= p * b;
                        }
                    }
                }
                let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
                if norm < 1e-6 {
                    continue;
                }
                for a in v.iter_mut() {
                    *a /= norm;
                }
                components.push(v);
            }
        }
    }
    // coefficients (n x K) = xc^T [b_1 .. b_K], one product.
    let basis = DMatrix::from_fn(d, components.len(), |j, k| components[k][j]);
    let coef = xc.tr_mul(&basis);
    let coefficients: Vec<Vec<f64>> = (0..n)
        .map(|t| (0..components.len()).map(|k| coef[(t, k)]).collect())
        .collect();
    let mut energy = Vec::new();
    let mut sse_with = vec![total];
    for k in 0..components.len() {
        let captured: f64 = coefficients.iter().map(|c| c[k] * c[k]).sum();
        energy.push(captured);
        let prev = *sse_with.last().expect("starts with the total");
        sse_with.push((prev - captured).max(0.0));
    }
    ClusterResidual {
        mean,
        components,
        coefficients,
        energy,
        sse_without,
        sse_with,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::rng::SampleStream;

    fn data(n: usize, d: usize) -> Vec<f64> {
        (0..n * d)
            .map(|i| SampleStream::new(&[3, i as u64]).at(0) - 0.5 + (i % d) as f64 * 0.01)
            .collect()
    }

    #[test]
    fn full_rank_is_exact_and_error_falls_monotonically() {
        let (n, d) = (12, 40);
        let rows = data(n, d);
        let r = fit_cluster_residual(&rows, d, 64);
        // Centred data of 12 rows has rank 11.
        assert_eq!(r.components.len(), n - 1);
        for t in 0..n {
            for j in 0..d {
                let rec: f64 = r.mean[j]
                    + r.components
                        .iter()
                        .zip(&r.coefficients[t])
                        .map(|(c, k)| k * c[j])
                        .sum::<f64>();
                assert!((rec - rows[t * d + j]).abs() < 1e-9, "texel {t} entry {j}");
            }
        }
        for w in r.sse_with.windows(2) {
            assert!(w[1] <= w[0]);
        }
        // Nothing is left at full rank but the round-off of subtracting each component's
        // energy from the total (the eigen solver's order of sums decides its sign).
        assert!(r.sse_with.last().copied().unwrap_or(1.0) <= 1e-12 * r.sse_with[0]);
        assert!(r.sse_with[0] < r.sse_without);
        // Energies are sorted and the closed form agrees with a direct reconstruction.
        assert!(r.energy.windows(2).all(|w| w[1] <= w[0] * (1.0 + 1e-12)));
        let k = 3;
        let direct: f64 = (0..n)
            .map(|t| {
                (0..d)
                    .map(|j| {
                        let rec: f64 = r.mean[j]
                            + (0..k)
                                .map(|c| r.coefficients[t][c] * r.components[c][j])
                                .sum::<f64>();
                        (rec - rows[t * d + j]).powi(2)
                    })
                    .sum::<f64>()
            })
            .sum();
        assert!((direct - r.sse_with[k]).abs() < 1e-9 * r.sse_with[0]);
        let retained: f64 = r.retained().iter().sum();
        assert!((retained - 1.0).abs() < 1e-9);
    }
}
