//! The low-frequency baseline: Sloan et al. 2003's bi-scale transfer in spherical
//! harmonics (order 5: 25 coefficients, one 25 x 25 matrix per vertex from global SH
//! lighting to local SH incident radiance), projected from the same visibility and
//! frames as the pixel-basis matrix: M_ab = sum over T's entries of value x
//! y_a(local direction) y_b(global direction). For the shared shading path, the local
//! SH radiance is integrated over each local cell (L*_m = sum_a c_a int_cell y_a).
//! Real SH with the usual orthonormal normalisation, theta from +z.

use std::f64::consts::PI;

use glam::DVec3;
use rayon::prelude::*;

use super::cubemap::CubeLayout;
use super::hemisphere::HemisphereGrid;
use super::transfer::{TransferMatrix, VertexFrames};

/// Real spherical harmonics y_0 .. y_{order^2 - 1} at unit `d` (index l(l+1)+m).
pub fn sh_basis(order: usize, d: DVec3, out: &mut [f64]) {
    let x = d.z.clamp(-1.0, 1.0);
    let phi = d.y.atan2(d.x);
    let s = (1.0 - x * x).max(0.0).sqrt();
    // Associated Legendre P_l^m(x) (with the Condon-Shortley phase) by recurrence.
    let mut p = vec![0.0f64; order * order];
    let at = |l: usize, m: usize| l * order + m;
    let mut pmm = 1.0;
    for m in 0..order {
        if m > 0 {
            pmm *= -((2 * m - 1) as f64) * s;
        }
        p[at(m, m)] = pmm;
        if m + 1 < order {
            p[at(m + 1, m)] = x * (2 * m + 1) as f64 * pmm;
        }
        for l in m + 2..order {
            p[at(l, m)] = ((2 * l - 1) as f64 * x * p[at(l - 1, m)]
                - (l + m - 1) as f64 * p[at(l - 2, m)])
                / (l - m) as f64;
        }
    }
    let factorial = |n: usize| (1..=n).map(|i| i as f64).product::<f64>();
    for l in 0..order {
        for m in 0..=l {
            let k = ((2 * l + 1) as f64 / (4.0 * PI) * factorial(l - m) / factorial(l + m)).sqrt();
            let c = l * (l + 1);
            if m == 0 {
                out[c] = k * p[at(l, 0)];
            } else {
                let v = std::f64::consts::SQRT_2 * k * p[at(l, m)];
                out[c + m] = v * (m as f64 * phi).cos();
                out[c - m] = v * (m as f64 * phi).sin();
            }
        }
    }
}

/// Per-vertex SH transfer matrices and what applies them to a cube-map lighting vector.
#[derive(Clone, Debug)]
pub struct ShTransfer {
    pub order: usize,
    /// Per vertex, [a][b] (local a, global b).
    matrices: Vec<f32>,
    /// Per cube pixel, y_b(d_k) x solid angle: the projection of L.
    projection: Vec<f32>,
    /// Per local cell, [m][a]: the integral of y_a over the cell.
    cell_integrals: Vec<f32>,
    cells: usize,
}

impl ShTransfer {
    pub fn build(
        t: &TransferMatrix,
        frames: &VertexFrames,
        cube: CubeLayout,
        local: HemisphereGrid,
        order: usize,
    ) -> Self {
        let nb = order * order;
        let mc = local.len();
        let global: Vec<Vec<f64>> = (0..cube.len())
            .map(|k| {
                let mut y = vec![0.0; nb];
                sh_basis(order, cube.centre(k), &mut y);
                y
            })
            .collect();
        let matrices: Vec<f32> = (0..frames.len())
            .into_par_iter()
            .flat_map_iter(|p| {
                let mut m = vec![0.0f64; nb * nb];
                let mut ya = vec![0.0; nb];
                for cell in 0..mc {
                    for (k, v) in t.row(p * mc + cell) {
                        sh_basis(order, frames.to_local(p, cube.centre(k)), &mut ya);
                        let g = &global[k];
                        for a in 0..nb {
                            let w = v as f64 * ya[a];
                            for b in 0..nb {
                                m[a * nb + b] += w * g[b];
                            }
                        }
                    }
                }
                m.into_iter().map(|x| x as f32)
            })
            .collect();
        let projection = (0..cube.len())
            .flat_map(|k| {
                let w = cube.solid_angle(k);
                global[k]
                    .iter()
                    .map(move |y| (y * w) as f32)
                    .collect::<Vec<_>>()
            })
            .collect();
        let strata = 8;
        let cell_integrals = (0..mc)
            .flat_map(|m| {
                let mut sum = vec![0.0f64; nb];
                let mut y = vec![0.0; nb];
                for d in local.strata(m, strata) {
                    sh_basis(order, d, &mut y);
                    sum.iter_mut().zip(&y).for_each(|(s, v)| *s += v);
                }
                let w = local.cell_solid_angle() / (strata * strata) as f64;
                sum.into_iter().map(move |s| (s * w) as f32)
            })
            .collect();
        Self {
            order,
            matrices,
            projection,
            cell_integrals,
            cells: mc,
        }
    }

    /// Global SH coefficients of a cube-map lighting vector (RGB).
    pub fn project(&self, light: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let nb = self.order * self.order;
        let mut c = vec![[0.0f32; 3]; nb];
        for (l, ys) in light.iter().zip(self.projection.chunks_exact(nb)) {
            for (cb, &y) in c.iter_mut().zip(ys) {
                for ch in 0..3 {
                    cb[ch] += y * l[ch];
                }
            }
        }
        c
    }

    /// L* per (vertex, cell), as the pixel-basis product gives it.
    pub fn apply(&self, light: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let nb = self.order * self.order;
        let g = self.project(light);
        let vertices = self.matrices.len() / (nb * nb);
        (0..vertices)
            .into_par_iter()
            .flat_map_iter(|p| {
                let m = &self.matrices[p * nb * nb..(p + 1) * nb * nb];
                let mut c = vec![[0.0f32; 3]; nb];
                for a in 0..nb {
                    for b in 0..nb {
                        for ch in 0..3 {
                            c[a][ch] += m[a * nb + b] * g[b][ch];
                        }
                    }
                }
                (0..self.cells).map(move |cell| {
                    let y = &self.cell_integrals[cell * nb..(cell + 1) * nb];
                    let mut out = [0.0f32; 3];
                    for a in 0..nb {
                        for ch in 0..3 {
                            out[ch] += y[a] * c[a][ch];
                        }
                    }
                    out
                })
            })
            .collect()
    }

    /// Bytes of the per-vertex matrices (the shared tables are a few kilobytes).
    pub fn bytes(&self) -> u64 {
        4 * self.matrices.len() as u64
    }

    /// Multiply-adds per lighting change and channel: projection, matrices, cells.
    pub fn flops(&self) -> u64 {
        let nb = (self.order * self.order) as u64;
        let vertices = self.matrices.len() as u64 / (nb * nb);
        2 * (self.projection.len() as u64 + vertices * (nb * nb + self.cells as u64 * nb))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::rng::SampleStream;

    /// Gauss-Legendre nodes and weights on [-1, 1] (Newton on P_n).
    fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
                let mut dp = 0.0;
                for _ in 0..100 {
                    let (mut p0, mut p1) = (1.0, x);
                    for k in 2..=n {
                        let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                        p0 = p1;
                        p1 = p2;
                    }
                    dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                    let dx = p1 / dp;
                    x -= dx;
                    if dx.abs() < 1e-15 {
                        break;
                    }
                }
                (x, 2.0 / ((1.0 - x * x) * dp * dp))
            })
            .collect()
    }

    #[test]
    fn a_band_limited_function_projects_and_reconstructs_exactly() {
        // f = sum_a c_a y_a with random c; projecting f by a quadrature exact for the
        // products of two order-5 harmonics (degree 8: 6 Gauss-Legendre nodes in z,
        // 12 equal steps in phi) returns c, and the reconstruction returns f.
        let order = 5;
        let nb = order * order;
        let rng = SampleStream::new(&[4]);
        let c: Vec<f64> = (0..nb).map(|a| rng.at(a as u64) - 0.5).collect();
        let f = |d: DVec3| {
            let mut y = vec![0.0; nb];
            sh_basis(order, d, &mut y);
            y.iter().zip(&c).map(|(y, c)| y * c).sum::<f64>()
        };
        let mut projected = vec![0.0; nb];
        let steps = 12;
        for (z, wz) in gauss_legendre(6) {
            for i in 0..steps {
                let phi = 2.0 * PI * i as f64 / steps as f64;
                let r = (1.0 - z * z).sqrt();
                let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                let mut y = vec![0.0; nb];
                sh_basis(order, d, &mut y);
                let w = wz * 2.0 * PI / steps as f64 * f(d);
                projected.iter_mut().zip(&y).for_each(|(p, y)| *p += w * y);
            }
        }
        for a in 0..nb {
            assert!(
                (projected[a] - c[a]).abs() < 1e-12,
                "{a}: {} vs {}",
                projected[a],
                c[a]
            );
        }
        for i in 0..100 {
            let d = crate::biscale::hemisphere::square_to_hemisphere(glam::DVec2::new(
                rng.at(1000 + 2 * i),
                rng.at(1001 + 2 * i),
            ));
            let mut y = vec![0.0; nb];
            sh_basis(order, d, &mut y);
            let back: f64 = y.iter().zip(&projected).map(|(y, c)| y * c).sum();
            assert!((back - f(d)).abs() < 1e-12);
        }
    }
}
