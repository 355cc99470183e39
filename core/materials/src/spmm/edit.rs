//! Edits a designer makes to an SPMM material (the material panel, the viewport brush
//! and `meso pack edit` all call these): replace, add, duplicate or remove a basis of a
//! cluster's dictionary; scale or paint the weights of one basis or of the whole
//! mixture, over a cluster or a texel mask; choose what the view shows (mute, solo) and
//! bake it; switch a cluster's residual off. Each edit returns a new validated material;
//! the original is untouched, so undo keeps the previous one. An edit that changes
//! the stored data marks the result edited; one that changes nothing (a unit scale)
//! returns an equal material, so its pack is byte-identical. Weight edits never add a
//! non-zero except where the designer paints weight in (`with_weight_added`).

use std::sync::Arc;

use glam::DVec3;

use super::texel_mask::TexelMask;
use super::view::BasisView;
use super::{Cluster, SparseWeights, SpmmError, SpmmMaterial};
use crate::brdf::BasisFunction;

/// Which weights a weight edit touches.
#[derive(Clone, Copy, Debug, Default)]
pub struct WeightTarget<'a> {
    /// Only texels of this cluster (`None`: every cluster).
    pub cluster: Option<usize>,
    /// Only this basis of the cluster's dictionary (`None`: the whole mixture).
    pub basis: Option<usize>,
    /// Per-texel strength (`None`: full strength everywhere): an edit by factor `s`
    /// applies `1 + m (s - 1)` at a texel of strength `m`.
    pub texels: Option<&'a TexelMask>,
}

impl<'a> WeightTarget<'a> {
    pub fn cluster(cluster: usize) -> Self {
        Self {
            cluster: Some(cluster),
            ..Self::default()
        }
    }
    pub fn basis(cluster: usize, basis: usize) -> Self {
        Self {
            cluster: Some(cluster),
            basis: Some(basis),
            texels: None,
        }
    }
    pub fn within(self, texels: &'a TexelMask) -> Self {
        Self {
            texels: Some(texels),
            ..self
        }
    }
}

/// Per basis of a texel's cluster, its weighted response, and the residual's.
#[derive(Clone, Debug, PartialEq)]
pub struct Contributions {
    pub cluster: usize,
    /// One entry per basis of the dictionary (zero where the texel has no weight).
    pub bases: Vec<DVec3>,
    pub residual: DVec3,
}

impl SpmmMaterial {
    fn cluster_error(&self, cluster: usize) -> SpmmError {
        SpmmError::Edit(format!(
            "cluster {cluster} does not exist (the material has {})",
            self.clusters().len()
        ))
    }

    fn check_basis(&self, cluster: usize, basis: usize) -> Result<(), SpmmError> {
        let dict = self
            .clusters()
            .get(cluster)
            .ok_or_else(|| self.cluster_error(cluster))?;
        if basis >= dict.bases.len() {
            return Err(SpmmError::Edit(format!(
                "basis {basis} of cluster {cluster} does not exist (it has {})",
                dict.bases.len()
            )));
        }
        Ok(())
    }

    fn check_target(&self, target: &WeightTarget) -> Result<(), SpmmError> {
        match (target.cluster, target.basis) {
            (Some(c), Some(b)) => self.check_basis(c, b)?,
            (Some(c), None) if c >= self.clusters().len() => return Err(self.cluster_error(c)),
            (None, Some(b)) => {
                return Err(SpmmError::Edit(format!(
                    "basis {b} was named without its cluster"
                )));
            }
            _ => {}
        }
        if let Some(m) = target.texels
            && (m.width(), m.height()) != (self.width(), self.height())
        {
            return Err(SpmmError::Edit(format!(
                "texel mask of {}x{} texels for a {}x{} material",
                m.width(),
                m.height(),
                self.width(),
                self.height()
            )));
        }
        Ok(())
    }

    /// The strength the target gives texel `t` (0: untouched).
    fn target_strength(&self, target: &WeightTarget, t: usize) -> f64 {
        if target
            .cluster
            .is_some_and(|c| self.texel_cluster()[t] as usize != c)
        {
            return 0.0;
        }
        target.texels.map_or(1.0, |m| f64::from(m.strength(t)))
    }

    /// The material with basis `index` of cluster `cluster` replaced.
    pub fn with_basis(
        &self,
        cluster: usize,
        index: usize,
        basis: BasisFunction,
    ) -> Result<Self, SpmmError> {
        self.check_basis(cluster, index)?;
        let mut clusters = self.clusters().to_vec();
        clusters[cluster].bases[index] = basis;
        self.rebuilt(clusters, self.weights().clone(), self.view().clone())
    }

    /// The material with `basis` appended to the cluster's dictionary, and its index.
    /// No texel weighs it yet: the material looks the same until it is painted or
    /// given weight (`with_weight_added`).
    pub fn with_basis_added(
        &self,
        cluster: usize,
        basis: BasisFunction,
    ) -> Result<(Self, usize), SpmmError> {
        let mut clusters = self.clusters().to_vec();
        let dict = clusters
            .get_mut(cluster)
            .ok_or_else(|| self.cluster_error(cluster))?;
        dict.bases.push(basis);
        let index = dict.bases.len() - 1;
        Ok((
            self.rebuilt(clusters, self.weights().clone(), self.view().clone())?,
            index,
        ))
    }

    /// A copy of basis `index` appended to the cluster's dictionary (with no weights,
    /// so the look is unchanged), and the copy's index: edit one, keep the other.
    pub fn with_basis_duplicated(
        &self,
        cluster: usize,
        index: usize,
    ) -> Result<(Self, usize), SpmmError> {
        self.check_basis(cluster, index)?;
        self.with_basis_added(cluster, self.clusters()[cluster].bases[index])
    }

    /// The material without basis `index` of `cluster` and without every weight on it;
    /// the later bases of the cluster move down by one. A cluster keeps at least one
    /// basis.
    pub fn with_basis_removed(&self, cluster: usize, index: usize) -> Result<Self, SpmmError> {
        self.check_basis(cluster, index)?;
        if self.clusters()[cluster].bases.len() == 1 {
            return Err(SpmmError::Edit(format!(
                "basis {index} is the only basis of cluster {cluster}; a cluster keeps at least one"
            )));
        }
        let mut clusters = self.clusters().to_vec();
        clusters[cluster].bases.remove(index);
        let index = index as u16;
        let weights = self.rebuilt_weights(|t, entries| {
            if self.texel_cluster()[t] as usize == cluster {
                entries.retain(|(j, _)| *j != index);
                for (j, _) in entries.iter_mut() {
                    if *j > index {
                        *j -= 1;
                    }
                }
            }
        });
        self.rebuilt(
            clusters,
            weights,
            self.view().without_basis(cluster, usize::from(index)),
        )
    }

    /// Per channel, the mean over the cluster's texels of their summed weights (0 for
    /// a cluster without texels).
    pub fn cluster_mean_weight(&self, cluster: usize) -> [f64; 3] {
        self.mean_weight(cluster, None)
    }

    /// Per channel, the mean over the cluster's texels of basis `basis`'s weight (a
    /// texel without an entry counts as 0).
    pub fn basis_mean_weight(&self, cluster: usize, basis: usize) -> [f64; 3] {
        self.mean_weight(cluster, Some(basis))
    }

    fn mean_weight(&self, cluster: usize, basis: Option<usize>) -> [f64; 3] {
        let mut sum = [0.0; 3];
        let mut n = 0usize;
        for (t, &c) in self.texel_cluster().iter().enumerate() {
            if c as usize == cluster {
                n += 1;
                for (j, w) in self.texel_weights(t) {
                    if basis.is_none_or(|b| usize::from(j) == b) {
                        for k in 0..3 {
                            sum[k] += f64::from(w[k]);
                        }
                    }
                }
            }
        }
        sum.map(|s| if n > 0 { s / n as f64 } else { 0.0 })
    }

    /// The material with every weight of the cluster's texels multiplied by `scale`
    /// (per channel, finite and non-negative).
    pub fn with_cluster_weight_scale(
        &self,
        cluster: usize,
        scale: [f64; 3],
    ) -> Result<Self, SpmmError> {
        self.with_weight_scale(&WeightTarget::cluster(cluster), scale)
    }

    /// The material with the target's weights multiplied per channel by `scale`
    /// (finite, non-negative), weakened by the mask's strength. Only existing entries
    /// change: no weight appears where there was none. Scaling by 2 then by 0.5 gives
    /// back the exact values (both are exact in binary floating point).
    pub fn with_weight_scale(
        &self,
        target: &WeightTarget,
        scale: [f64; 3],
    ) -> Result<Self, SpmmError> {
        self.check_target(target)?;
        if scale.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(SpmmError::Edit(format!(
                "weight scale {scale:?} must be finite and non-negative"
            )));
        }
        let mut weights = self.weights().clone();
        for t in 0..self.texel_cluster().len() {
            let m = self.target_strength(target, t);
            if m <= 0.0 {
                continue;
            }
            let factor = if m >= 1.0 {
                scale
            } else {
                scale.map(|s| 1.0 + m * (s - 1.0))
            };
            let range = weights.offsets[t] as usize..weights.offsets[t + 1] as usize;
            for i in range {
                if target
                    .basis
                    .is_none_or(|b| usize::from(weights.basis[i]) == b)
                {
                    let w = &mut weights.rgb[i];
                    for k in 0..3 {
                        w[k] = (f64::from(w[k]) * factor[k]) as f32;
                    }
                }
            }
        }
        self.rebuilt(self.clusters().to_vec(), weights, self.view().clone())
    }

    /// The material with `rgb` (finite; weakened by the mask's strength) added to the
    /// weight of the target's basis at each targeted texel, an entry made where the
    /// texel had none (painting a new basis in); a weight never drops below 0.
    pub fn with_weight_added(
        &self,
        target: &WeightTarget,
        rgb: [f64; 3],
    ) -> Result<Self, SpmmError> {
        self.check_target(target)?;
        let Some(basis) = target.basis else {
            return Err(SpmmError::Edit(
                "adding weight needs a cluster and a basis".into(),
            ));
        };
        if rgb.iter().any(|v| !v.is_finite()) {
            return Err(SpmmError::Edit(format!(
                "added weight {rgb:?} must be finite"
            )));
        }
        let basis = basis as u16;
        let weights = self.rebuilt_weights(|t, entries| {
            let m = self.target_strength(target, t);
            let add = rgb.map(|v| m * v);
            if m <= 0.0 || add == [0.0; 3] {
                return;
            }
            let slot = match entries.iter().position(|(j, _)| *j == basis) {
                Some(i) => i,
                None => {
                    entries.push((basis, [0.0; 3]));
                    entries.len() - 1
                }
            };
            let w = &mut entries[slot].1;
            for k in 0..3 {
                w[k] = (f64::from(w[k]) + add[k]).max(0.0) as f32;
            }
        });
        self.rebuilt(self.clusters().to_vec(), weights, self.view().clone())
    }

    /// The material showing `view` (mute and solo flags, which must name existing
    /// bases). The stored weights do not change and the material is not marked edited.
    pub fn with_view(&self, view: BasisView) -> Result<Self, SpmmError> {
        for (c, j) in view.flagged() {
            self.check_basis(c, j)?;
        }
        let mut m = self.clone();
        m.set_view(view);
        Ok(m)
    }

    /// The material as its view shows it, stored: the weights of hidden bases are
    /// removed (their dictionary entries stay, for painting back in), the residual of
    /// a cluster with a soloed basis is switched off, and the view is cleared.
    pub fn with_view_applied(&self) -> Result<Self, SpmmError> {
        let view = self.view().clone();
        if view.is_empty() {
            return Ok(self.clone());
        }
        let weights = self.rebuilt_weights(|t, entries| {
            let c = self.texel_cluster()[t] as usize;
            entries.retain(|(j, _)| view.shows(c, usize::from(*j)));
        });
        let mut m = self.rebuilt(self.clusters().to_vec(), weights, BasisView::default())?;
        for c in 0..self.clusters().len() {
            if !view.shows_residual(c) {
                m = m.with_cluster_residual_off(c)?;
            }
        }
        Ok(m)
    }

    /// Whether the cluster has a residual that adds something (a non-zero mean or
    /// component). It was fitted for the cluster's original mixture: after a
    /// dictionary or weight edit the editor says so and offers to switch it off.
    pub fn cluster_has_residual(&self, cluster: usize) -> bool {
        let Some(r) = self.residual() else {
            return false;
        };
        let table = r.light_dirs.len() * r.view_dirs.len() * 3;
        r.mean[cluster * table..(cluster + 1) * table]
            .iter()
            .chain(&r.components[cluster * r.npca * table..(cluster + 1) * r.npca * table])
            .any(|v| *v != 0.0)
    }

    /// The material with the cluster's residual mean and components set to zero (the
    /// other clusters keep theirs).
    pub fn with_cluster_residual_off(&self, cluster: usize) -> Result<Self, SpmmError> {
        if cluster >= self.clusters().len() {
            return Err(self.cluster_error(cluster));
        }
        let Some(mut r) = self.residual().cloned() else {
            return Ok(self.clone());
        };
        let table = r.light_dirs.len() * r.view_dirs.len() * 3;
        r.mean[cluster * table..(cluster + 1) * table].fill(0.0);
        r.components[cluster * r.npca * table..(cluster + 1) * r.npca * table].fill(0.0);
        self.rebuilt_with(
            self.clusters().to_vec(),
            self.weights().clone(),
            Some(Arc::new(r)),
            self.view().clone(),
        )
    }

    /// Texel `t`'s response split by part: each basis of its dictionary weighted by
    /// the texel's weight, and the residual (`residual` and `max_npca` as in
    /// `eval_texel`). The view is ignored: this is the stored material. The parts sum
    /// to `eval_texel` of a material without a view.
    pub fn contributions(
        &self,
        t: usize,
        wi: DVec3,
        wo: DVec3,
        residual: bool,
        max_npca: usize,
    ) -> Contributions {
        let c = self.texel_cluster()[t] as usize;
        let dict = &self.clusters()[c].bases;
        let mut bases = vec![DVec3::ZERO; dict.len()];
        let mut resid = DVec3::ZERO;
        if wi.z > 0.0 && wo.z > 0.0 {
            for (j, w) in self.texel_weights(t) {
                let j = usize::from(j);
                bases[j] = DVec3::new(w[0] as f64, w[1] as f64, w[2] as f64) * dict[j].eval(wi, wo);
            }
            if residual {
                let stored = BasisView::default();
                let total = self.eval_texel_in(&stored, t, wi, wo, true, max_npca);
                let basis_sum = self.eval_texel_in(&stored, t, wi, wo, false, max_npca);
                resid = total - basis_sum;
            }
        }
        Contributions {
            cluster: c,
            bases,
            residual: resid,
        }
    }

    /// Which texels (row-major) belong to `cluster`.
    pub fn cluster_texels(&self, cluster: usize) -> Vec<bool> {
        self.texel_cluster()
            .iter()
            .map(|&c| c as usize == cluster)
            .collect()
    }

    /// New weights from each texel's entries as changed by `edit` (given the texel
    /// and its (basis, rgb) entries, in stored order).
    fn rebuilt_weights(
        &self,
        mut edit: impl FnMut(usize, &mut Vec<(u16, [f32; 3])>),
    ) -> SparseWeights {
        let old = self.weights();
        let mut weights = SparseWeights {
            offsets: Vec::with_capacity(old.offsets.len()),
            basis: Vec::with_capacity(old.basis.len()),
            rgb: Vec::with_capacity(old.rgb.len()),
        };
        weights.offsets.push(0);
        let mut entries = Vec::new();
        for t in 0..self.texel_cluster().len() {
            entries.clear();
            entries.extend(self.texel_weights(t));
            edit(t, &mut entries);
            for &(j, w) in &entries {
                weights.basis.push(j);
                weights.rgb.push(w);
            }
            weights.offsets.push(weights.basis.len() as u32);
        }
        weights
    }

    fn rebuilt(
        &self,
        clusters: Vec<Cluster>,
        weights: SparseWeights,
        view: BasisView,
    ) -> Result<Self, SpmmError> {
        self.rebuilt_with(clusters, weights, self.shared_residual().cloned(), view)
    }

    /// A validated material with these parts; marked edited if any stored part
    /// differs from this one's, else as edited as this one.
    fn rebuilt_with(
        &self,
        clusters: Vec<Cluster>,
        weights: SparseWeights,
        residual: Option<Arc<super::Residual>>,
        view: BasisView,
    ) -> Result<Self, SpmmError> {
        let same_residual = match (&residual, self.shared_residual()) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b) || a == b,
            (None, None) => true,
            _ => false,
        };
        let changed = clusters != self.clusters() || &weights != self.weights() || !same_residual;
        let mixture_changed = self.clusters_with_new_mixture(&clusters, &weights);
        // The residual is shared, not copied, when an edit leaves it alone.
        let header = super::material::Header {
            name: self.name().to_string(),
            provenance: self.provenance().to_string(),
            edited: false,
            edited_clusters: vec![false; clusters.len()],
        };
        let mut m = self.with_parts(header, clusters, weights, residual, BasisView::default())?;
        if changed || self.edited() {
            m.mark_clusters_edited(
                (0..self.clusters().len())
                    .filter(|&c| self.cluster_edited(c) || mixture_changed[c]),
            );
        }
        m.set_view(view);
        Ok(m)
    }

    /// Per cluster, whether `clusters` and `weights` (same texel grid and cluster map)
    /// change its dictionary or the weights of one of its texels: the mixture its
    /// residual was fitted for. A residual switched off is not such a change.
    fn clusters_with_new_mixture(
        &self,
        clusters: &[Cluster],
        weights: &SparseWeights,
    ) -> Vec<bool> {
        let mut changed: Vec<bool> = (0..self.clusters().len())
            .map(|c| clusters.get(c) != Some(&self.clusters()[c]))
            .collect();
        let old = self.weights();
        for (t, &c) in self.texel_cluster().iter().enumerate() {
            let c = c as usize;
            if changed[c] {
                continue;
            }
            let (a, b) = (
                old.offsets[t] as usize..old.offsets[t + 1] as usize,
                weights.offsets[t] as usize..weights.offsets[t + 1] as usize,
            );
            changed[c] =
                old.basis[a.clone()] != weights.basis[b.clone()] || old.rgb[a] != weights.rgb[b];
        }
        changed
    }
}

#[cfg(test)]
mod tests;
