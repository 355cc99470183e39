//! Edits a designer makes to an SPMM material (issue 7's material panel): replace one
//! basis function of a cluster's dictionary (model, parameters, normal), and scale the
//! weights of every texel of a cluster per RGB channel (shown as the cluster's mean
//! weight). Each edit returns a new validated material marked edited; the original is
//! untouched, so undo keeps the previous one.

use super::{SpmmError, SpmmMaterial};
use crate::brdf::BasisFunction;

impl SpmmMaterial {
    /// The material with basis `index` of cluster `cluster` replaced.
    pub fn with_basis(
        &self,
        cluster: usize,
        index: usize,
        basis: BasisFunction,
    ) -> Result<Self, SpmmError> {
        let mut clusters = self.clusters().to_vec();
        let count = clusters.len();
        let dict = clusters.get_mut(cluster).ok_or_else(|| {
            SpmmError::Edit(format!("cluster {cluster} of {count} does not exist"))
        })?;
        let bases = dict.bases.len();
        let slot = dict.bases.get_mut(index).ok_or_else(|| {
            SpmmError::Edit(format!(
                "basis {index} of cluster {cluster} does not exist (it has {bases})"
            ))
        })?;
        *slot = basis;
        self.rebuilt(clusters, self.weights().clone())
    }

    /// Per channel, the mean over the cluster's texels of their summed weights (0 for
    /// a cluster without texels).
    pub fn cluster_mean_weight(&self, cluster: usize) -> [f64; 3] {
        let mut sum = [0.0; 3];
        let mut n = 0usize;
        for (t, &c) in self.texel_cluster().iter().enumerate() {
            if c as usize == cluster {
                n += 1;
                for (_, w) in self.texel_weights(t) {
                    for k in 0..3 {
                        sum[k] += f64::from(w[k]);
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
        if cluster >= self.clusters().len() {
            return Err(SpmmError::Edit(format!(
                "cluster {cluster} of {} does not exist",
                self.clusters().len()
            )));
        }
        if scale.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(SpmmError::Edit(format!(
                "weight scale {scale:?} must be finite and non-negative"
            )));
        }
        let mut weights = self.weights().clone();
        for (t, &c) in self.texel_cluster().iter().enumerate() {
            if c as usize == cluster {
                let range = weights.offsets[t] as usize..weights.offsets[t + 1] as usize;
                for w in &mut weights.rgb[range] {
                    for k in 0..3 {
                        w[k] = (f64::from(w[k]) * scale[k]) as f32;
                    }
                }
            }
        }
        self.rebuilt(self.clusters().to_vec(), weights)
    }

    /// Which texels (row-major) belong to `cluster`.
    pub fn cluster_texels(&self, cluster: usize) -> Vec<bool> {
        self.texel_cluster()
            .iter()
            .map(|&c| c as usize == cluster)
            .collect()
    }

    fn rebuilt(
        &self,
        clusters: Vec<super::Cluster>,
        weights: super::SparseWeights,
    ) -> Result<Self, SpmmError> {
        let mut m = SpmmMaterial::new(
            self.name().to_string(),
            self.provenance().to_string(),
            self.width(),
            self.height(),
            clusters,
            self.texel_cluster().to_vec(),
            weights,
            self.residual().cloned(),
        )?;
        m.mark_edited();
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::spmm::tests::sample_material;

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
}
