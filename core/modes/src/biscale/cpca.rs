//! The clustered-PCA baseline (Sloan et al. 2003's compression, as Sun et al. compare
//! it): the rows of T (one local direction of one vertex, N environment pixels each)
//! are clustered by k-means (Euclidean, on the sparse rows against dense centres),
//! then each cluster keeps its mean and its leading principal components (subspace
//! iteration), each row its coefficients. Lossy: the report measures its error. Rows
//! that are entirely zero are kept exactly zero (no cluster).

use rayon::prelude::*;

use super::transfer::TransferMatrix;
use meso_materials::rng::SampleStream;

#[derive(Clone, Debug)]
pub struct Cpca {
    pub clusters: usize,
    pub components: usize,
    cols: usize,
    /// Per cluster, the mean then the components, each `cols` long.
    bases: Vec<f32>,
    /// Per row, its cluster (`u32::MAX`: a zero row).
    assignment: Vec<u32>,
    /// Per row, `components` coefficients.
    coefficients: Vec<f32>,
}

fn sparse_row(t: &TransferMatrix, j: usize) -> Vec<(usize, f32)> {
    t.row(j).collect()
}

fn orthonormalise(q: &mut [Vec<f64>]) {
    for i in 0..q.len() {
        for j in 0..i {
            let d: f64 = q[i].iter().zip(&q[j]).map(|(a, b)| a * b).sum();
            let (head, tail) = q.split_at_mut(i);
            tail[0]
                .iter_mut()
                .zip(&head[j])
                .for_each(|(a, b)| *a -= d * b);
        }
        let n: f64 = q[i].iter().map(|a| a * a).sum::<f64>().sqrt();
        if n > 1e-30 {
            q[i].iter_mut().for_each(|a| *a /= n);
        }
    }
}

impl Cpca {
    pub fn build(t: &TransferMatrix, clusters: usize, components: usize, seed: u64) -> Self {
        let n = t.cols;
        let rows: Vec<Vec<(usize, f32)>> = (0..t.rows).map(|j| sparse_row(t, j)).collect();
        let live: Vec<usize> = (0..t.rows).filter(|&j| !rows[j].is_empty()).collect();
        let kc = clusters.min(live.len()).max(1);
        // Initial centres: rows spread evenly over the nonzero rows.
        let mut centres: Vec<Vec<f64>> = (0..kc)
            .map(|c| {
                let mut v = vec![0.0; n];
                for &(k, x) in &rows[live[(c * live.len()) / kc]] {
                    v[k] = x as f64;
                }
                v
            })
            .collect();
        let mut assign = vec![0usize; t.rows];
        for _ in 0..10 {
            let norms: Vec<f64> = centres
                .iter()
                .map(|c| c.iter().map(|x| x * x).sum())
                .collect();
            let chosen: Vec<usize> = live
                .par_iter()
                .map(|&j| {
                    (0..kc)
                        .map(|c| {
                            let d: f64 =
                                rows[j].iter().map(|&(k, x)| x as f64 * centres[c][k]).sum();
                            (norms[c] - 2.0 * d, c)
                        })
                        .min_by(|a, b| a.0.total_cmp(&b.0))
                        .map_or(0, |m| m.1)
                })
                .collect();
            for (&j, &c) in live.iter().zip(&chosen) {
                assign[j] = c;
            }
            let mut sums = vec![vec![0.0f64; n]; kc];
            let mut counts = vec![0usize; kc];
            for &j in &live {
                counts[assign[j]] += 1;
                for &(k, x) in &rows[j] {
                    sums[assign[j]][k] += x as f64;
                }
            }
            for c in 0..kc {
                if counts[c] > 0 {
                    centres[c] = sums[c].iter().map(|s| s / counts[c] as f64).collect();
                }
            }
        }
        let members: Vec<Vec<usize>> = (0..kc)
            .map(|c| live.iter().copied().filter(|&j| assign[j] == c).collect())
            .collect();
        let rng = SampleStream::new(&[seed]);
        let per_cluster: Vec<Vec<Vec<f64>>> = (0..kc)
            .into_par_iter()
            .map(|c| {
                let mean = &centres[c];
                // Subspace iteration for the leading components of the centred rows.
                let mut q: Vec<Vec<f64>> = (0..components)
                    .map(|i| {
                        (0..n)
                            .map(|k| rng.at(((c * components + i) * n + k) as u64) - 0.5)
                            .collect()
                    })
                    .collect();
                orthonormalise(&mut q);
                for _ in 0..8 {
                    let mean_q: Vec<f64> = q
                        .iter()
                        .map(|v| v.iter().zip(mean).map(|(a, b)| a * b).sum())
                        .collect();
                    let mut z = vec![vec![0.0f64; n]; components];
                    let mut ysum = vec![0.0f64; components];
                    for &j in &members[c] {
                        let y: Vec<f64> = (0..components)
                            .map(|i| {
                                rows[j]
                                    .iter()
                                    .map(|&(k, x)| x as f64 * q[i][k])
                                    .sum::<f64>()
                                    - mean_q[i]
                            })
                            .collect();
                        for i in 0..components {
                            ysum[i] += y[i];
                            for &(k, x) in &rows[j] {
                                z[i][k] += x as f64 * y[i];
                            }
                        }
                    }
                    for i in 0..components {
                        z[i].iter_mut()
                            .zip(mean)
                            .for_each(|(a, m)| *a -= m * ysum[i]);
                    }
                    q = z;
                    orthonormalise(&mut q);
                }
                let mut out = vec![mean.clone()];
                out.extend(q);
                out
            })
            .collect();
        let mut assignment = vec![u32::MAX; t.rows];
        let mut coefficients = vec![0.0f32; t.rows * components];
        for &j in &live {
            let c = assign[j];
            assignment[j] = c as u32;
            let basis = &per_cluster[c];
            for i in 0..components {
                let q = &basis[1 + i];
                let d: f64 = rows[j].iter().map(|&(k, x)| x as f64 * q[k]).sum::<f64>()
                    - basis[0].iter().zip(q).map(|(a, b)| a * b).sum::<f64>();
                coefficients[j * components + i] = d as f32;
            }
        }
        Self {
            clusters: kc,
            components,
            cols: n,
            bases: per_cluster
                .into_iter()
                .flatten()
                .flatten()
                .map(|x| x as f32)
                .collect(),
            assignment,
            coefficients,
        }
    }

    /// L* per row: per cluster the mean's and components' products with L, then per
    /// row its mean product plus its coefficients times the component products.
    pub fn apply(&self, light: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let terms = 1 + self.components;
        let products: Vec<[f32; 3]> = (0..self.clusters * terms)
            .into_par_iter()
            .map(|i| {
                let v = &self.bases[i * self.cols..(i + 1) * self.cols];
                let mut acc = [0.0f32; 3];
                for (x, l) in v.iter().zip(light) {
                    for c in 0..3 {
                        acc[c] += x * l[c];
                    }
                }
                acc
            })
            .collect();
        self.assignment
            .par_iter()
            .enumerate()
            .map(|(j, &c)| {
                if c == u32::MAX {
                    return [0.0; 3];
                }
                let p = &products[c as usize * terms..(c as usize + 1) * terms];
                let mut out = p[0];
                for i in 0..self.components {
                    let a = self.coefficients[j * self.components + i];
                    for ch in 0..3 {
                        out[ch] += a * p[1 + i][ch];
                    }
                }
                out
            })
            .collect()
    }

    /// Bytes: cluster means and components, per-row coefficients and cluster index.
    pub fn bytes(&self) -> u64 {
        4 * (self.bases.len() + self.coefficients.len() + self.assignment.len()) as u64
    }

    /// Multiply-adds per lighting change and channel.
    pub fn flops(&self) -> u64 {
        2 * (self.bases.len() + self.coefficients.len()) as u64
    }
}
