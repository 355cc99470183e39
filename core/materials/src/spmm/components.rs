//! Fewer residual components per cluster: what a byte budget (the fitter's
//! `budget`) or a pack file's per-cluster N_PCA leaves of a material.

use super::{Residual, SpmmError, SpmmMaterial};

/// Keeps the first `counts[c]` components of each cluster `c` (at most its N_PCA);
/// the in-memory N_PCA becomes the largest count, the rest of each cluster zero.
pub fn with_component_counts(
    m: &SpmmMaterial,
    counts: &[usize],
) -> Result<SpmmMaterial, SpmmError> {
    let Some(r) = m.residual() else {
        return Ok(m.clone());
    };
    let (k, d) = (r.npca, r.light_dirs.len() * r.view_dirs.len() * 3);
    let counts: Vec<usize> = counts.iter().map(|&n| n.min(k)).collect();
    let k2 = counts.iter().copied().max().unwrap_or(0);
    let n_clusters = m.clusters().len();
    let mut components = vec![0.0f32; n_clusters * k2 * d];
    for (c, &n) in counts.iter().enumerate() {
        components[c * k2 * d..(c * k2 + n) * d]
            .copy_from_slice(&r.components[c * k * d..(c * k + n) * d]);
    }
    let texels = m.texel_cluster().len();
    let mut coefficients = vec![0.0f32; texels * k2];
    for (t, &c) in m.texel_cluster().iter().enumerate() {
        let n = counts[c as usize];
        coefficients[t * k2..t * k2 + n].copy_from_slice(&r.coefficients[t * k..t * k + n]);
    }
    let mut out = SpmmMaterial::new(
        m.name().to_string(),
        m.provenance().to_string(),
        m.width(),
        m.height(),
        m.clusters().to_vec(),
        m.texel_cluster().to_vec(),
        m.weights().clone(),
        Some(Residual {
            light_dirs: r.light_dirs.clone(),
            view_dirs: r.view_dirs.clone(),
            npca: k2,
            mean: r.mean.clone(),
            components,
            coefficients,
        }),
    )?;
    if m.edited() {
        out.mark_clusters_edited(m.edited_clusters());
    }
    Ok(out)
}
