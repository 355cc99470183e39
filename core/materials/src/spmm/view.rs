//! What the view shows of a material's bases: mute hides a basis, solo shows only the
//! soloed bases of its cluster (and hides that cluster's residual, which belongs to
//! the whole mixture). A view never changes the weights a pack stores until it is
//! applied (`SpmmMaterial::with_view_applied`), so a designer can look at each lobe
//! without losing anything.

use std::collections::BTreeSet;

/// A basis by (cluster, index in its dictionary).
pub type BasisId = (usize, usize);

/// Mute and solo flags, by (cluster, basis). Empty: every basis shows.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct BasisView {
    muted: BTreeSet<(usize, usize)>,
    solo: BTreeSet<(usize, usize)>,
}

impl BasisView {
    /// True when the view shows the material as stored.
    pub fn is_empty(&self) -> bool {
        self.muted.is_empty() && self.solo.is_empty()
    }

    /// The muted and the soloed (cluster, basis) pairs, in order.
    pub fn entries(&self) -> [Vec<BasisId>; 2] {
        [
            self.muted.iter().copied().collect(),
            self.solo.iter().copied().collect(),
        ]
    }

    pub fn muted(&self, cluster: usize, basis: usize) -> bool {
        self.muted.contains(&(cluster, basis))
    }

    pub fn soloed(&self, cluster: usize, basis: usize) -> bool {
        self.solo.contains(&(cluster, basis))
    }

    /// Some basis of `cluster` is soloed.
    pub fn cluster_has_solo(&self, cluster: usize) -> bool {
        self.solo
            .range((cluster, 0)..=(cluster, usize::MAX))
            .next()
            .is_some()
    }

    /// Whether basis `basis` of `cluster` contributes to the view.
    pub fn shows(&self, cluster: usize, basis: usize) -> bool {
        !self.muted(cluster, basis)
            && (!self.cluster_has_solo(cluster) || self.soloed(cluster, basis))
    }

    /// Whether the cluster's residual contributes (not while one of its bases is soloed).
    pub fn shows_residual(&self, cluster: usize) -> bool {
        !self.cluster_has_solo(cluster)
    }

    pub fn set_muted(&mut self, cluster: usize, basis: usize, on: bool) {
        set(&mut self.muted, (cluster, basis), on);
    }

    pub fn set_solo(&mut self, cluster: usize, basis: usize, on: bool) {
        set(&mut self.solo, (cluster, basis), on);
    }

    /// Every flagged (cluster, basis), muted or soloed.
    pub(super) fn flagged(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.muted.iter().chain(&self.solo).copied()
    }

    /// The view after basis `basis` of `cluster` left the dictionary: its flags go, the
    /// later bases of the cluster move down by one.
    pub(super) fn without_basis(&self, cluster: usize, basis: usize) -> Self {
        let shift = |set: &BTreeSet<(usize, usize)>| {
            set.iter()
                .filter(|&&k| k != (cluster, basis))
                .map(|&(c, j)| (c, if c == cluster && j > basis { j - 1 } else { j }))
                .collect()
        };
        Self {
            muted: shift(&self.muted),
            solo: shift(&self.solo),
        }
    }

    /// The flags that concern `cluster`, for comparing two views cluster by cluster.
    pub(super) fn of_cluster(&self, cluster: usize) -> (Vec<usize>, Vec<usize>) {
        let pick = |set: &BTreeSet<(usize, usize)>| {
            set.range((cluster, 0)..=(cluster, usize::MAX))
                .map(|&(_, j)| j)
                .collect()
        };
        (pick(&self.muted), pick(&self.solo))
    }
}

fn set(set: &mut BTreeSet<(usize, usize)>, key: (usize, usize), on: bool) {
    if on {
        set.insert(key);
    } else {
        set.remove(&key);
    }
}
