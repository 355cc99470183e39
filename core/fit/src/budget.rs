//! Per-cluster N_PCA under a byte budget. The residual's components cost the same
//! bytes in every cluster (one L x V x 3 table each) but do not remove the same error:
//! a cluster of many texels with cast shadows gains far more from its tenth component
//! than a small flat cluster from its third. Given a pack fitted with enough
//! components per cluster, this keeps, over all clusters, the components that remove
//! the most squared table error until the file reaches the budget.
//!
//! A component's share of the squared error is exact in closed form: the fitter's
//! components are orthonormal and its coefficients are exact projections, so
//! dropping component k of cluster c adds `|b_k|^2 * sum_t coef_k(t)^2` over the
//! cluster's texels. PCA orders each cluster's components by that energy, so the
//! greedy choice (the best next component of any cluster, each cluster's kept
//! components a prefix) minimises the table error for every number of components.
//! The file stores only the kept components (docs/formats/spmm.md, "Per-cluster
//! N_PCA").

use super::FitError;
pub use meso_materials::spmm::components::with_component_counts;
use meso_materials::spmm::pack::{self, ResidualPrecision};
use meso_materials::spmm::{SpmmError, SpmmMaterial};

/// Why a pack cannot be brought under a budget.
#[derive(Debug, thiserror::Error)]
pub enum BudgetError {
    #[error("the pack has no residual: there are no components to choose")]
    NoResidual,
    #[error(
        "the pack is {bytes} bytes with no component at all, over the budget of {budget} bytes"
    )]
    TooSmall { bytes: usize, budget: u64 },
    #[error("the weights could not be brought within the lobe bound: {0}")]
    LobeBound(String),
    #[error("{0}")]
    Material(#[from] SpmmError),
}

impl From<BudgetError> for FitError {
    fn from(e: BudgetError) -> Self {
        match e {
            BudgetError::Material(m) => FitError::Material(m),
            other => FitError::Budget(other.to_string()),
        }
    }
}

/// A pack brought under a budget.
pub struct Trimmed {
    pub material: SpmmMaterial,
    /// Components kept per cluster.
    pub cluster_npca: Vec<usize>,
    /// Bytes of the pack file at the requested precision.
    pub bytes: usize,
    /// Squared table error (summed over texels, pairs, channels) the dropped
    /// components held: what trimming adds to the fit's squared error.
    pub dropped_energy: f64,
}

/// Per cluster, per component: the squared table error it removes,
/// `|b_k|^2 * sum over the cluster's texels of coef_k(t)^2`.
pub fn component_energies(m: &SpmmMaterial) -> Vec<Vec<f64>> {
    let Some(r) = m.residual() else {
        return vec![Vec::new(); m.clusters().len()];
    };
    let (k, d) = (r.npca, r.light_dirs.len() * r.view_dirs.len() * 3);
    let mut coef_sq = vec![vec![0.0f64; k]; m.clusters().len()];
    for (t, &c) in m.texel_cluster().iter().enumerate() {
        for (kk, slot) in coef_sq[c as usize].iter_mut().enumerate() {
            *slot += f64::from(r.coefficients[t * k + kk]).powi(2);
        }
    }
    coef_sq
        .iter()
        .enumerate()
        .map(|(c, sq)| {
            sq.iter()
                .enumerate()
                .map(|(kk, s)| {
                    let at = (c * k + kk) * d;
                    let norm_sq: f64 = r.components[at..at + d]
                        .iter()
                        .map(|&x| f64::from(x).powi(2))
                        .sum();
                    norm_sq * s
                })
                .collect()
        })
        .collect()
}

/// The greedy order: at each step the cluster whose next component removes the most
/// error (ties: the lower cluster); components that remove nothing are never chosen.
pub fn greedy_order(energies: &[Vec<f64>]) -> Vec<usize> {
    let mut next = vec![0usize; energies.len()];
    let mut order = Vec::new();
    loop {
        let best = energies
            .iter()
            .enumerate()
            .filter_map(|(c, e)| e.get(next[c]).map(|&v| (c, v)))
            .filter(|(_, v)| *v > 0.0)
            .fold(None, |best: Option<(usize, f64)>, (c, v)| match best {
                Some((_, bv)) if bv >= v => best,
                _ => Some((c, v)),
            });
        let Some((c, _)) = best else {
            return order;
        };
        order.push(c);
        next[c] += 1;
    }
}

/// The most components (in the greedy order) whose pack file stays within
/// `max_bytes` at `precision`.
pub fn trim_to_bytes(
    m: &SpmmMaterial,
    max_bytes: u64,
    precision: ResidualPrecision,
) -> Result<Trimmed, BudgetError> {
    if m.residual().is_none() {
        return Err(BudgetError::NoResidual);
    }
    let energies = component_energies(m);
    let order = greedy_order(&energies);
    let counts_at = |n: usize| {
        let mut counts = vec![0usize; energies.len()];
        for &c in &order[..n] {
            counts[c] += 1;
        }
        counts
    };
    let build = |n: usize| -> Result<(SpmmMaterial, usize), BudgetError> {
        let t = with_component_counts(m, &counts_at(n))?;
        let bytes = pack::encode_pack(&t, precision).len();
        Ok((t, bytes))
    };
    // The file grows with every component: bisect for the largest count that fits.
    let (mut best, bytes) = build(0)?;
    if bytes as u64 > max_bytes {
        return Err(BudgetError::TooSmall {
            bytes,
            budget: max_bytes,
        });
    }
    let (mut lo, mut hi, mut best_bytes) = (0usize, order.len(), bytes);
    while lo < hi {
        let mid = (lo + hi).div_ceil(2);
        let (t, bytes) = build(mid)?;
        if bytes as u64 <= max_bytes {
            (lo, best, best_bytes) = (mid, t, bytes);
        } else {
            hi = mid - 1;
        }
    }
    let cluster_npca = counts_at(lo);
    let dropped_energy = energies
        .iter()
        .zip(&cluster_npca)
        .map(|(e, &n)| e[n.min(e.len())..].iter().sum::<f64>())
        .sum();
    Ok(Trimmed {
        material: best,
        cluster_npca,
        bytes: best_bytes,
        dropped_energy,
    })
}

/// The first `npca` components of every cluster (an even split: what a fit with that
/// N_PCA keeps), for comparisons at equal bytes.
pub fn keep_first(
    m: &SpmmMaterial,
    npca: usize,
    precision: ResidualPrecision,
) -> Result<Trimmed, BudgetError> {
    if m.residual().is_none() {
        return Err(BudgetError::NoResidual);
    }
    let energies = component_energies(m);
    let cluster_npca: Vec<usize> = energies.iter().map(|e| npca.min(e.len())).collect();
    let material = with_component_counts(m, &cluster_npca)?;
    let dropped_energy = energies
        .iter()
        .map(|e| e[npca.min(e.len())..].iter().sum::<f64>())
        .sum();
    Ok(Trimmed {
        bytes: pack::encode_pack(&material, precision).len(),
        material,
        cluster_npca,
        dropped_energy,
    })
}

/// Lowers the weights a trimmed pack's lobe bound no longer allows. The bound
/// (spmm::lobe_bound) is relative to the pack's own largest tabulated value, and the
/// brightest BTF values (single grazing peaks) are what few components reproduce
/// last, so a trimmed pack's maximum may drop below what the fit's weight caps
/// assumed. Each weight is capped, as the fitter caps them, at 0.97 x the hemisphere
/// multiple x the pack's maximum over its basis's hemisphere peak, until the pack
/// passes (the residual is not refitted: `meso report fit` measures the cost).
/// Returns the pack and how many weight entries were lowered.
pub fn clamp_to_lobe_bound(m: &SpmmMaterial) -> Result<(SpmmMaterial, usize), BudgetError> {
    use meso_materials::spmm::lobe_bound;
    use rayon::prelude::*;
    let bases: Vec<&meso_materials::brdf::BasisFunction> =
        m.clusters().iter().flat_map(|c| &c.bases).collect();
    let peaks: Vec<f64> = bases
        .par_iter()
        .map(|b| lobe_bound::hemisphere_peak(b).0)
        .collect();
    let mut first = vec![0usize];
    for c in m.clusters() {
        first.push(first.last().copied().unwrap_or(0) + c.bases.len());
    }
    let mut current = m.clone();
    let mut lowered = vec![false; m.weights().basis.len()];
    let count = |lowered: &[bool]| lowered.iter().filter(|&&l| l).count();
    for _ in 0..8 {
        if lobe_bound::check_lobes(&current).is_ok() {
            return Ok((current, count(&lowered)));
        }
        let limit =
            lobe_bound::HEMISPHERE_MULTIPLE * 0.97 * lobe_bound::tabulated_maximum(&current);
        let mut weights = current.weights().clone();
        for (t, &c) in current.texel_cluster().iter().enumerate() {
            let range = weights.offsets[t] as usize..weights.offsets[t + 1] as usize;
            for e in range {
                let peak = peaks[first[c as usize] + usize::from(weights.basis[e])];
                if peak <= 0.0 {
                    continue;
                }
                let cap = (limit / peak) as f32;
                if weights.rgb[e].iter().any(|&x| x > cap) {
                    lowered[e] = true;
                    for x in weights.rgb[e].iter_mut() {
                        *x = x.min(cap);
                    }
                }
            }
        }
        let mut next = SpmmMaterial::new(
            current.name().to_string(),
            current.provenance().to_string(),
            current.width(),
            current.height(),
            current.clusters().to_vec(),
            current.texel_cluster().to_vec(),
            weights,
            current.residual().cloned(),
        )?;
        if current.edited() {
            next.mark_clusters_edited(current.edited_clusters());
        }
        current = next;
    }
    match lobe_bound::check_lobes(&current) {
        Ok(()) => Ok((current, count(&lowered))),
        Err(e) => Err(BudgetError::LobeBound(e.to_string())),
    }
}
