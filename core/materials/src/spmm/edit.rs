//! Edits a designer makes to an SPMM material (the material panel, the viewport brush
//! and `meso pack edit` all call these): replace, add, duplicate or remove a basis of a
//! cluster's dictionary; scale or paint the weights of one basis or of the whole
//! mixture, over a cluster or a texel mask; choose what the view shows (mute, solo) and
//! bake it; switch a cluster's residual off. Each edit returns a new validated material;
//! the original is untouched, so undo keeps the previous one. An edit that changes
//! the stored data marks the result edited; one that changes nothing (a unit scale)
//! returns an equal material, so its pack is byte-identical. Weight edits never add a
//! non-zero except where the designer paints weight in (`with_weight_added`).

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
            Some(r),
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
        self.rebuilt_with(clusters, weights, self.residual().cloned(), view)
    }

    /// A validated material with these parts; marked edited if any stored part
    /// differs from this one's, else as edited as this one.
    fn rebuilt_with(
        &self,
        clusters: Vec<Cluster>,
        weights: SparseWeights,
        residual: Option<super::Residual>,
        view: BasisView,
    ) -> Result<Self, SpmmError> {
        let changed = clusters != self.clusters()
            || &weights != self.weights()
            || residual.as_ref() != self.residual();
        let mixture_changed = self.clusters_with_new_mixture(&clusters, &weights);
        let mut m = SpmmMaterial::new(
            self.name().to_string(),
            self.provenance().to_string(),
            self.width(),
            self.height(),
            clusters,
            self.texel_cluster().to_vec(),
            weights,
            residual,
        )?;
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
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::spmm::testing::sample_material;
    use crate::spmm::{BasisView, TexelMask};

    #[test]
    fn replacing_a_basis_changes_only_that_cluster_and_marks_the_material_edited() {
        let m = sample_material(4, 4, 3, Some(2));
        let ward = BasisFunction::new(
            AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.05), ("ay", 0.4)]).expect("valid"),
            DVec3::new(0.1, 0.0, 1.0).normalize(),
        )
        .expect("unit normal");
        let e = m.with_basis(1, 0, ward).expect("valid edit");
        assert!(e.edited() && !m.edited());
        assert_eq!(e.clusters()[1].bases[0], ward);
        assert_eq!(e.clusters()[0], m.clusters()[0]);
        assert_eq!(e.clusters()[2], m.clusters()[2]);
        assert_eq!(e.weights(), m.weights());
        assert_eq!(e.residual(), m.residual());
        assert!(m.with_basis(3, 0, ward).is_err());
        assert!(m.with_basis(0, 99, ward).is_err());
    }

    #[test]
    fn scaling_a_cluster_scales_its_mean_weight_and_nothing_else() {
        let m = sample_material(4, 4, 3, None);
        let before: Vec<[f64; 3]> = (0..3).map(|c| m.cluster_mean_weight(c)).collect();
        let e = m
            .with_cluster_weight_scale(2, [2.0, 0.5, 0.0])
            .expect("valid scale");
        let after = e.cluster_mean_weight(2);
        for k in 0..3 {
            let want = before[2][k] * [2.0, 0.5, 0.0][k];
            assert!(
                (after[k] - want).abs() <= 1e-6 * want.max(1e-6),
                "{after:?}"
            );
        }
        assert_eq!(e.cluster_mean_weight(0), before[0]);
        assert_eq!(e.cluster_mean_weight(1), before[1]);
        // Texels of other clusters keep their exact weights.
        for (t, &c) in m.texel_cluster().iter().enumerate() {
            if c != 2 {
                assert!(m.texel_weights(t).eq(e.texel_weights(t)));
            }
        }
        assert!(
            m.with_cluster_weight_scale(2, [f64::NAN, 1.0, 1.0])
                .is_err()
        );
        assert!(m.with_cluster_weight_scale(2, [-1.0, 1.0, 1.0]).is_err());
        assert!(m.with_cluster_weight_scale(7, [1.0; 3]).is_err());
        assert_eq!(m.cluster_texels(2).iter().filter(|&&b| b).count(), {
            m.texel_cluster().iter().filter(|&&c| c == 2).count()
        });
    }

    fn encode(m: &SpmmMaterial) -> Vec<u8> {
        crate::spmm::pack::encode_pack(m, crate::spmm::pack::ResidualPrecision::F32)
    }

    fn dirs() -> Vec<(DVec3, DVec3)> {
        let d = |t: f64, p: f64| crate::brdf::warp::spherical(t, p);
        vec![
            (d(0.3, 0.2), d(0.5, 3.0)),
            (d(1.1, 1.0), d(0.2, 4.0)),
            (d(0.7, 5.0), d(0.9, 5.5)),
        ]
    }

    #[test]
    fn scaling_one_basis_changes_exactly_its_weights_and_2_then_half_restores_them() {
        let m = sample_material(6, 5, 3, Some(2));
        let (c, b) = (1, 2);
        let e = m
            .with_weight_scale(&WeightTarget::basis(c, b), [2.0, 3.0, 0.5])
            .expect("valid scale");
        assert!(e.edited());
        let mut scaled = 0;
        for (t, &tc) in m.texel_cluster().iter().enumerate() {
            for ((j0, w0), (j1, w1)) in m.texel_weights(t).zip(e.texel_weights(t)) {
                assert_eq!(j0, j1, "no entry moves or appears");
                if tc as usize == c && usize::from(j0) == b {
                    scaled += 1;
                    assert_eq!(w1, [w0[0] * 2.0, w0[1] * 3.0, w0[2] * 0.5]);
                } else {
                    assert_eq!(w0.map(f32::to_bits), w1.map(f32::to_bits));
                }
            }
            assert_eq!(m.texel_weights(t).count(), e.texel_weights(t).count());
        }
        assert!(
            scaled > 0,
            "the sample material weighs basis {b} of cluster {c}"
        );
        let back = m
            .with_weight_scale(&WeightTarget::basis(c, b), [2.0; 3])
            .and_then(|x| x.with_weight_scale(&WeightTarget::basis(c, b), [0.5; 3]))
            .expect("valid");
        assert_eq!(back.weights(), m.weights());
        // The mean weight shown per basis follows the scale.
        let (before, after) = (m.basis_mean_weight(c, b), e.basis_mean_weight(c, b));
        assert!((after[0] - 2.0 * before[0]).abs() < 1e-6 && before[0] > 0.0);
        // A unit scale changes nothing: not even the edited flag or the pack's bytes.
        let same = m
            .with_weight_scale(&WeightTarget::basis(c, b), [1.0; 3])
            .expect("valid");
        assert!(!same.edited());
        assert_eq!(encode(&same), encode(&m));
        // Bad targets are named.
        let err = |t: WeightTarget| m.with_weight_scale(&t, [1.0; 3]).unwrap_err().to_string();
        assert!(err(WeightTarget::basis(1, 9)).contains("basis 9 of cluster 1"));
        assert!(err(WeightTarget::cluster(5)).contains("cluster 5"));
        let small = TexelMask::empty(2, 2);
        assert!(err(WeightTarget::cluster(0).within(&small)).contains("2x2"));
    }

    #[test]
    fn a_masked_scale_changes_only_covered_texels_and_partial_strength_interpolates() {
        let m = sample_material(8, 8, 2, None);
        let mut mask = TexelMask::empty(8, 8);
        mask.stamp(
            glam::DVec2::new(0.5, 0.5),
            1.6,
            1.0,
            crate::spmm::Falloff::Linear,
        );
        // The disc wraps: it reaches the last column and row.
        assert!(mask.strength(7) > 0.0 && mask.strength(7 * 8) > 0.0);
        assert_eq!(mask.strength(0), 1.0, "full strength at the centre texel");
        let e = m
            .with_weight_scale(&WeightTarget::default().within(&mask), [3.0; 3])
            .expect("valid");
        let changed = m.changed_texels(&e).expect("same grid");
        for (t, &changed) in changed.iter().enumerate() {
            let s = f64::from(mask.strength(t));
            assert_eq!(changed, s > 0.0, "texel {t}");
            for ((_, w0), (_, w1)) in m.texel_weights(t).zip(e.texel_weights(t)) {
                let want = (f64::from(w0[0]) * (1.0 + s * 2.0)) as f32;
                assert_eq!(w1[0], want, "texel {t}");
            }
        }
    }

    #[test]
    fn adding_weight_makes_entries_only_where_painted() {
        let m = sample_material(6, 6, 2, None);
        let (m2, j) = m
            .with_basis_added(
                0,
                BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
                    .expect("unit"),
            )
            .expect("cluster 0 exists");
        assert_eq!(m2.weights(), m.weights(), "a new basis has no weight yet");
        let unchanged = m.changed_texels(&m2).expect("same grid");
        assert!(unchanged.iter().all(|c| !c), "so no texel looks different");
        let mut mask = TexelMask::empty(6, 6);
        for t in [0, 1, 7, 20] {
            mask.raise(t, 0.5);
        }
        let e = m2
            .with_weight_added(&WeightTarget::basis(0, j).within(&mask), [0.2, 0.4, 0.0])
            .expect("valid");
        for t in 0..36 {
            let want = mask.strength(t) > 0.0 && m.texel_cluster()[t] == 0;
            let before: Vec<_> = m.texel_weights(t).collect();
            let mut after: Vec<_> = e.texel_weights(t).collect();
            if want {
                assert_eq!(after.pop(), Some((j as u16, [0.1, 0.2, 0.0])), "texel {t}");
            }
            assert_eq!(after, before, "texel {t}: the other entries stay");
        }
        assert!(
            m.with_weight_added(&WeightTarget::cluster(0), [1.0; 3])
                .is_err(),
            "adding needs a basis"
        );
    }

    #[test]
    fn mute_and_solo_change_the_view_but_never_the_pack() {
        let m = sample_material(5, 4, 2, Some(2));
        let (c, b) = (0, 1);
        let mut view = BasisView::default();
        view.set_muted(c, b, true);
        let muted = m.with_view(view).expect("flags name bases");
        assert!(!muted.edited() && muted.stores_same(&m) && muted != m);
        assert_eq!(encode(&muted), encode(&m));
        let mut view = BasisView::default();
        view.set_solo(c, b, true);
        let solo = m.with_view(view).expect("valid");
        assert_eq!(encode(&solo), encode(&m));
        let prepared = solo.prepare(&crate::spmm::PrepareRequest {
            used_clusters: None,
            residual: true,
            max_npca: usize::MAX,
        });
        for t in 0..20 {
            for (wi, wo) in dirs() {
                let parts = m.contributions(t, wi, wo, true, usize::MAX);
                let all = m.eval_texel(t, wi, wo, true, usize::MAX);
                let sum: DVec3 = parts.bases.iter().sum::<DVec3>() + parts.residual;
                assert!(
                    (sum - all).abs().max_element() < 1e-9,
                    "parts sum to the whole"
                );
                let in_c = parts.cluster == c;
                let want_muted = if in_c { all - parts.bases[b] } else { all };
                let got = muted.eval_texel(t, wi, wo, true, usize::MAX);
                assert!((got - want_muted).abs().max_element() < 1e-9, "texel {t}");
                let want_solo = if in_c { parts.bases[b] } else { all };
                let got = solo.eval_texel(t, wi, wo, true, usize::MAX);
                assert!((got - want_solo).abs().max_element() < 1e-9, "texel {t}");
                let got = prepared.eval_texel(t, wi, wo);
                assert!(
                    (got - want_solo).abs().max_element() < 1e-6,
                    "prepared texel {t}"
                );
            }
        }
        let mut bad = BasisView::default();
        bad.set_muted(1, 40, true);
        assert!(m.with_view(bad).is_err());
        // Applying the solo stores what the view showed: only basis b's weights in
        // cluster c, no residual there.
        let applied = solo.with_view_applied().expect("valid");
        assert!(applied.edited() && applied.view().is_empty());
        assert!(!applied.cluster_has_residual(c) && applied.cluster_has_residual(1));
        for t in 0..20 {
            for (wi, wo) in dirs() {
                let want = solo.eval_texel(t, wi, wo, true, usize::MAX);
                let got = applied.eval_texel(t, wi, wo, true, usize::MAX);
                assert!((got - want).abs().max_element() < 1e-6, "texel {t}");
            }
        }
    }

    #[test]
    fn add_duplicate_and_remove_bases_round_trip_through_the_pack() {
        let m = sample_material(5, 5, 3, Some(1));
        let c = 2;
        let n = m.clusters()[c].bases.len();
        let (dup, j) = m.with_basis_duplicated(c, 0).expect("valid");
        assert_eq!(j, n);
        assert_eq!(dup.clusters()[c].bases[j], m.clusters()[c].bases[0]);
        let bytes = encode(&dup);
        let read = crate::spmm::pack::decode_pack(&bytes).expect("valid pack");
        assert_eq!(read.clusters(), dup.clusters());
        assert_eq!(read.weights(), dup.weights());
        assert!(read.edited());
        // Removing the copy gives back the original data.
        let back = dup.with_basis_removed(c, j).expect("valid");
        assert_eq!(back.clusters(), m.clusters());
        assert_eq!(back.weights(), m.weights());
        // Removing basis 0 drops its weights and renumbers the rest.
        let mut view = BasisView::default();
        view.set_muted(c, 2, true);
        let r = m
            .with_view(view)
            .and_then(|x| x.with_basis_removed(c, 0))
            .expect("valid");
        assert!(
            r.view().muted(c, 1) && !r.view().muted(c, 2),
            "flags follow the renumbering"
        );
        for t in 0..25 {
            let before: Vec<_> = m.texel_weights(t).collect();
            let after: Vec<_> = r.texel_weights(t).collect();
            if m.texel_cluster()[t] as usize == c {
                let want: Vec<_> = before
                    .iter()
                    .filter(|(j, _)| *j != 0)
                    .map(|&(j, w)| (j - 1, w))
                    .collect();
                assert_eq!(after, want, "texel {t}");
            } else {
                assert_eq!(after, before);
            }
        }
        let read = crate::spmm::pack::decode_pack(&encode(&r)).expect("valid pack");
        assert_eq!(read.weights(), r.weights());
        assert!(m.with_basis_removed(c, 99).is_err());
        let one = sample_material(2, 2, 1, None);
        let mut lone = one.clone();
        while lone.clusters()[0].bases.len() > 1 {
            lone = lone.with_basis_removed(0, 0).expect("valid");
        }
        assert!(
            lone.with_basis_removed(0, 0)
                .unwrap_err()
                .to_string()
                .contains("only basis")
        );
    }

    #[test]
    fn switching_a_cluster_residual_off_keeps_the_others() {
        let m = sample_material(4, 4, 3, Some(2));
        assert!((0..3).all(|c| m.cluster_has_residual(c)));
        let e = m.with_cluster_residual_off(1).expect("valid");
        assert!(
            e.cluster_has_residual(0) && !e.cluster_has_residual(1) && e.cluster_has_residual(2)
        );
        let changed = m.changed_texels(&e).expect("same grid");
        assert_eq!(changed, m.cluster_texels(1));
        assert!(m.with_cluster_residual_off(3).is_err());
        // A material without a residual has none to switch off.
        let plain = sample_material(4, 4, 2, None);
        assert!(!plain.cluster_has_residual(0));
        assert_eq!(plain.with_cluster_residual_off(0).expect("valid"), plain);
    }
    #[test]
    fn only_clusters_whose_mixture_changed_are_marked_edited_and_the_marks_are_saved() {
        let m = sample_material(4, 4, 3, Some(2));
        assert!(m.edited_clusters().is_empty());
        // A basis scale in cluster 1 marks cluster 1 alone.
        let scaled = m
            .with_weight_scale(&WeightTarget::basis(1, 0), [2.0, 1.0, 1.0])
            .expect("valid");
        assert!(scaled.edited());
        assert_eq!(scaled.edited_clusters(), vec![1]);
        // A dictionary edit of cluster 2 adds it; the earlier mark stays.
        let basis = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
        let added = scaled
            .with_basis_added(2, BasisFunction::new(basis, DVec3::Z).expect("valid"))
            .expect("valid")
            .0;
        assert_eq!(added.edited_clusters(), vec![1, 2]);
        // A residual switched off changes no mixture: edited, no cluster marked.
        let off = m.with_cluster_residual_off(0).expect("valid");
        assert!(off.edited() && off.edited_clusters().is_empty());
        // A unit scale changes nothing at all.
        let same = m
            .with_weight_scale(&WeightTarget::cluster(0), [1.0; 3])
            .expect("valid");
        assert!(!same.edited() && same.edited_clusters().is_empty());
        // The marks survive the pack; an edited pack without them marks every cluster.
        for e in [&added, &off] {
            let read = crate::spmm::pack::decode_pack(&encode(e)).expect("valid pack");
            assert_eq!(read.edited_clusters(), e.edited_clusters());
            assert!(read.stores_same(e));
        }
        let mut legacy = m.clone();
        legacy.mark_edited();
        assert_eq!(legacy.edited_clusters(), vec![0, 1, 2]);
        assert!(!legacy.stores_same(&added));
        // A bad list is refused naming the key and the item.
        let mut bad = encode(&added);
        let key = b"\"edited_clusters\":\"1,2\"";
        let at = bad
            .windows(key.len())
            .position(|w| w == key)
            .expect("the key is in the header");
        bad[at + key.len() - 2] = b'9';
        let err = crate::spmm::pack::decode_pack(&bad).unwrap_err();
        assert!(
            err.to_string().contains("edited_clusters") && err.to_string().contains("`9`"),
            "{err}"
        );
    }
}
