//! Undo and redo under a memory budget. A step keeps what an edit changed, not the
//! state: the lights, ambient, environment and background as they were (small; maps
//! are shared `Arc`s), the materials as they were, except that an SPMM material
//! edited in place is kept as a `PackDelta` (a brush stroke's texels, a basis's
//! parameters) instead of a second copy of its weights. A step's delta is taken when
//! its group closes (one slider drag or one stroke is one step). When the steps
//! together hold more than the budget, the oldest are dropped, and the history says
//! how many.

use std::collections::VecDeque;
use std::sync::Arc;

use meso_materials::spmm::{PackDelta, SpmmMaterial, Step as Direction};
use meso_render::scene::Material;

use crate::document::Snapshot;

/// The default budget: 512 MiB (`MESO_UNDO_BUDGET_MB` or the studio's settings
/// change it).
pub const DEFAULT_BUDGET: usize = 512 << 20;

/// A material slot as a step keeps it.
#[derive(Clone, Debug)]
enum Kept {
    /// The material itself (anything that is not an SPMM pack edited in place).
    Whole(Material),
    /// An SPMM material given by its difference from the neighbouring state in the
    /// history, with its scene settings.
    Pack {
        delta: Arc<PackDelta>,
        uv_scale: glam::DVec2,
        residual: bool,
        npca: usize,
    },
}

/// One state in the history, relative to its neighbour.
#[derive(Clone, Debug)]
pub(crate) struct Step {
    /// The state with the materials taken out.
    rest: Snapshot,
    materials: Vec<Kept>,
    bytes: usize,
}

fn spmm_bytes(m: &SpmmMaterial) -> usize {
    let w = m.weights();
    let residual = m.residual().map_or(0, |r| {
        (r.mean.len() + r.components.len() + r.coefficients.len()) * 4
    });
    w.offsets.len() * 4 + w.basis.len() * 2 + w.rgb.len() * 12 + residual
}

impl Step {
    /// `state` kept relative to `neighbour` (the state the history holds next to it,
    /// the document's for the newest step): SPMM materials that differ only in
    /// place become deltas from `state` to `neighbour`.
    pub(crate) fn compact(state: Snapshot, neighbour: &Snapshot) -> Step {
        let mut bytes = std::mem::size_of::<Snapshot>() + state.lights.len() * 96;
        let materials = state
            .materials
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let kept = match (m, neighbour.materials.get(i)) {
                    (
                        Material::Spmm {
                            material,
                            uv_scale,
                            residual,
                            npca,
                        },
                        Some(Material::Spmm { material: next, .. }),
                    ) if !Arc::ptr_eq(material, next) => match material.delta_to(next) {
                        Ok(delta) => Kept::Pack {
                            delta: Arc::new(delta),
                            uv_scale: *uv_scale,
                            residual: *residual,
                            npca: *npca,
                        },
                        Err(_) => Kept::Whole(m.clone()),
                    },
                    _ => Kept::Whole(m.clone()),
                };
                bytes += match &kept {
                    Kept::Pack { delta, .. } => delta.bytes(),
                    // Shared with the neighbour: no copy of its own.
                    Kept::Whole(Material::Spmm { material, .. })
                        if !matches!(neighbour.materials.get(i),
                            Some(Material::Spmm { material: n, .. }) if Arc::ptr_eq(n, material)) =>
                    {
                        spmm_bytes(material)
                    }
                    _ => 64,
                };
                kept
            })
            .collect();
        let rest = Snapshot {
            materials: Vec::new(),
            ..state
        };
        Step {
            rest,
            materials,
            bytes,
        }
    }

    /// The state this step keeps, rebuilt from the neighbour it was compacted
    /// against (its deltas lead from the kept state to the neighbour: stepped back).
    pub(crate) fn expand(&self, next: &Snapshot) -> Snapshot {
        let materials = self
            .materials
            .iter()
            .enumerate()
            .map(|(i, k)| match k {
                Kept::Whole(m) => m.clone(),
                Kept::Pack {
                    delta,
                    uv_scale,
                    residual,
                    npca,
                } => {
                    let Some(Material::Spmm { material, .. }) = next.materials.get(i) else {
                        unreachable!("a pack delta's neighbour holds the pack")
                    };
                    let stepped = material
                        .stepped(delta, Direction::Back)
                        .expect("a delta steps the neighbour it was taken against");
                    Material::Spmm {
                        material: Arc::new(stepped),
                        uv_scale: *uv_scale,
                        residual: *residual,
                        npca: *npca,
                    }
                }
            })
            .collect();
        Snapshot {
            materials,
            ..self.rest.clone()
        }
    }
}

/// The undo and redo stacks with their budget.
#[derive(Debug)]
pub(crate) struct History {
    undo: VecDeque<Step>,
    redo: Vec<Step>,
    budget: usize,
    /// Oldest steps dropped to stay within the budget since the document opened.
    pub(crate) dropped: usize,
}

impl History {
    pub(crate) fn new(budget: usize) -> Self {
        Self {
            undo: VecDeque::new(),
            redo: Vec::new(),
            budget,
            dropped: 0,
        }
    }

    pub(crate) fn set_budget(&mut self, budget: usize) {
        self.budget = budget;
        self.trim();
    }

    pub(crate) fn budget(&self) -> usize {
        self.budget
    }

    /// Bytes the steps hold.
    pub(crate) fn bytes(&self) -> usize {
        self.undo.iter().chain(&self.redo).map(|s| s.bytes).sum()
    }

    pub(crate) fn undo_len(&self) -> usize {
        self.undo.len()
    }

    pub(crate) fn redo_len(&self) -> usize {
        self.redo.len()
    }

    /// The document took another way: what was undone cannot be redone.
    pub(crate) fn clear_redo(&mut self) {
        self.redo.clear();
    }

    /// A new step (the redo side is gone: the document took another way).
    pub(crate) fn push(&mut self, step: Step) {
        self.redo.clear();
        self.undo.push_back(step);
        self.trim();
    }

    pub(crate) fn pop_undo(&mut self) -> Option<Step> {
        self.undo.pop_back()
    }

    pub(crate) fn pop_redo(&mut self) -> Option<Step> {
        self.redo.pop()
    }

    pub(crate) fn push_undo_keeping_redo(&mut self, step: Step) {
        self.undo.push_back(step);
        self.trim();
    }

    pub(crate) fn push_redo(&mut self, step: Step) {
        self.redo.push(step);
        self.trim();
    }

    /// Drops the oldest undo steps while the history is over its budget; the newest
    /// undo step always stays.
    fn trim(&mut self) {
        let mut total = self.bytes();
        while total > self.budget && self.undo.len() > 1 {
            let s = self.undo.pop_front().expect("len > 1");
            total -= s.bytes;
            self.dropped += 1;
        }
    }
}
