//! Which texels an edit changed: a renderer restarts only the pixels whose shading
//! reached one of them (a brush stroke touches a few texels, not the whole material).

use super::SpmmMaterial;

impl SpmmMaterial {
    /// Whether `other` would be written as the same pack: everything but the view
    /// (mute and solo are not stored, so they leave nothing unsaved).
    pub fn stores_same(&self, other: &SpmmMaterial) -> bool {
        self.name() == other.name()
            && self.provenance() == other.provenance()
            && self.edited() == other.edited()
            && self.edited_clusters() == other.edited_clusters()
            && (self.width(), self.height()) == (other.width(), other.height())
            && self.texel_cluster() == other.texel_cluster()
            && self.clusters() == other.clusters()
            && self.weights() == other.weights()
            && self.residual() == other.residual()
    }

    /// Per texel (row-major), whether `after` may evaluate differently from `self`
    /// there: its weights, a basis it weighs, its cluster's view flags or residual
    /// tables, or its residual coefficients differ. `None` when the two do not share a texel grid and
    /// cluster map (everything changed).
    pub fn changed_texels(&self, after: &SpmmMaterial) -> Option<Vec<bool>> {
        if (self.width(), self.height()) != (after.width(), after.height())
            || self.texel_cluster() != after.texel_cluster()
            || self.clusters().len() != after.clusters().len()
        {
            return None;
        }
        let clusters = self.clusters().len();
        let residual_shape = |m: &SpmmMaterial| {
            m.residual()
                .map(|r| (r.light_dirs.clone(), r.view_dirs.clone(), r.npca))
        };
        if residual_shape(self) != residual_shape(after) {
            return None;
        }
        let cluster_changed: Vec<bool> = (0..clusters)
            .map(|c| {
                self.view().of_cluster(c) != after.view().of_cluster(c)
                    || self.residual_tables_of(c) != after.residual_tables_of(c)
            })
            .collect();
        // A dictionary edit changes only the texels that weigh an edited basis: a
        // basis added with no weights changes nothing yet.
        let basis_changed: Vec<Vec<bool>> = (0..clusters)
            .map(|c| {
                let (old, new) = (&self.clusters()[c].bases, &after.clusters()[c].bases);
                (0..old.len().max(new.len()))
                    .map(|j| old.get(j) != new.get(j))
                    .collect()
            })
            .collect();
        let npca = self.npca();
        let coefficients = |m: &SpmmMaterial, t: usize| -> Option<Vec<f32>> {
            m.residual()
                .map(|r| r.coefficients[t * npca..(t + 1) * npca].to_vec())
        };
        Some(
            self.texel_cluster()
                .iter()
                .enumerate()
                .map(|(t, &c)| {
                    cluster_changed[c as usize]
                        || !self.texel_weights(t).eq(after.texel_weights(t))
                        || self
                            .texel_weights(t)
                            .any(|(j, _)| basis_changed[c as usize][usize::from(j)])
                        || coefficients(self, t) != coefficients(after, t)
                })
                .collect(),
        )
    }

    /// The cluster's residual mean and components (empty without a residual).
    fn residual_tables_of(&self, cluster: usize) -> (&[f32], &[f32]) {
        match self.residual() {
            Some(r) => {
                let table = r.light_dirs.len() * r.view_dirs.len() * 3;
                (
                    &r.mean[cluster * table..(cluster + 1) * table],
                    &r.components[cluster * r.npca * table..(cluster + 1) * r.npca * table],
                )
            }
            None => (&[], &[]),
        }
    }
}
