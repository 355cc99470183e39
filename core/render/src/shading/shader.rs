//! What a material needs prepared at render time: nothing for analytic BRDFs, MERL
//! tables and mirrors (their sampling tables are built on first use and shared), the
//! BTF for `btf` materials, and for SPMM packs the prepared evaluation data, made the
//! first time a ray shades the pack and reused across edits that keep its residual.

use std::f64::consts::PI;
use std::sync::{Arc, OnceLock};

use glam::{DVec2, DVec3};

use crate::scene::Material;
use meso_materials::brdf::warp;
use meso_materials::spmm::{
    EvalSettings, MOVING_NPCA, PrepareRequest, PreparedSpmm, SpmmMaterial, TexelFilter,
    defensive_pdf, defensive_sample,
};

/// What shading a material needs at render time.
pub(super) enum Shader {
    /// Analytic BRDFs, MERL tables and mirrors read the scene's material directly.
    Scene,
    /// A BTF read from the scene's material: sampled like a pack.
    Table,
    /// An SPMM pack, prepared for this render the first time a ray shades it (or
    /// before the first frame if a primary ray sees it: `SpmmMode::prepare`), with its
    /// settings when still and moving. Packs no ray reaches hold nothing.
    Spmm {
        material: Arc<SpmmMaterial>,
        request: PrepareRequest,
        prepared: OnceLock<Box<PreparedSpmm>>,
        still: EvalSettings,
        moving: EvalSettings,
    },
}

impl Shader {
    pub(super) fn new(material: &Material) -> Self {
        match material {
            Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            } => {
                let still = EvalSettings {
                    residual: *residual,
                    max_npca: *npca,
                    filter: TexelFilter::Nearest,
                    uv_scale: *uv_scale,
                };
                Shader::Spmm {
                    material: Arc::clone(material),
                    request: PrepareRequest {
                        used_clusters: None,
                        residual: *residual,
                        max_npca: *npca,
                    },
                    prepared: OnceLock::new(),
                    still,
                    moving: moving_settings(still),
                }
            }
            Material::Btf { .. } => Shader::Table,
            _ => Shader::Scene,
        }
    }

    /// The shader of `after`, which replaced `before` (shaded by `self`): an SPMM
    /// pack with the same residual reuses the prepared residual tables (if they were
    /// prepared; otherwise it stays unprepared until a ray reaches it).
    pub(super) fn after_edit(&self, before: &Material, after: &Material) -> Self {
        if let (
            Shader::Spmm { prepared, .. },
            Material::Spmm { material: old, .. },
            Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            },
        ) = (self, before, after)
            && let Material::Spmm {
                residual: old_residual,
                npca: old_npca,
                ..
            } = before
            && (old_residual, old_npca) == (residual, npca)
            && let Some(prepared) = prepared.get()
        {
            let still = EvalSettings {
                residual: *residual,
                max_npca: *npca,
                filter: TexelFilter::Nearest,
                uv_scale: *uv_scale,
            };
            let request = PrepareRequest {
                used_clusters: None,
                residual: *residual,
                max_npca: *npca,
            };
            let data = Box::new(material.prepare_after_edit(&request, old, prepared));
            return Shader::Spmm {
                material: Arc::clone(material),
                request,
                prepared: OnceLock::from(data),
                still,
                moving: moving_settings(still),
            };
        }
        Self::new(after)
    }

    /// True if moving changes this material's evaluation: it has a residual in use
    /// with more components than a moving camera keeps.
    pub(super) fn changes_when_moving(&self) -> bool {
        matches!(self, Shader::Spmm { material, request, still, .. }
            if still.residual
                && material.prepares_residual(request)
                && request.max_npca.min(material.npca()) > MOVING_NPCA)
    }

    /// The pack's evaluation data, prepared now if no ray needed it before (one
    /// thread prepares, others needing it wait; afterwards a read is one atomic load).
    pub(super) fn prepared(&self) -> Option<&PreparedSpmm> {
        match self {
            Shader::Spmm {
                material,
                request,
                prepared,
                ..
            } => Some(prepared.get_or_init(|| Box::new(material.prepare(request)))),
            Shader::Scene | Shader::Table => None,
        }
    }

    /// Prepares what shading `material` (this shader's) at texture position `uv` needs:
    /// the pack and the residual tables of the clusters there, or a MERL table's
    /// sampling tables (1.5 million lookups).
    pub(super) fn make_resident_at(&self, material: &Material, uv: DVec2) {
        match (self, material) {
            (Shader::Spmm { still, .. }, _) => {
                if let Some(p) = self.prepared() {
                    p.make_resident_at(uv, still);
                }
            }
            (_, Material::Merl { brdf, .. }) => {
                brdf.sampler();
            }
            _ => {}
        }
    }

    /// Prepares everything this material could need, reached or not.
    pub(super) fn make_all_resident(&self, material: &Material) {
        match (self, material) {
            (Shader::Spmm { .. }, _) => {
                if let Some(p) = self.prepared() {
                    p.make_all_resident();
                }
            }
            (_, Material::Merl { brdf, .. }) => {
                brdf.sampler();
            }
            _ => {}
        }
    }

    /// Bytes of prepared material data held now (a MERL table's sampling tables are
    /// shared by every render of the table, and counted by each).
    pub(super) fn resident_bytes(&self, material: &Material) -> usize {
        match (self, material) {
            (Shader::Spmm { prepared, .. }, _) => prepared.get().map_or(0, |p| p.bytes().total()),
            (_, Material::Merl { brdf, .. }) => brdf.sampler_if_built().map_or(0, |s| s.bytes()),
            _ => 0,
        }
    }

    /// Bytes this material holds once everything is prepared.
    pub(super) fn full_bytes(&self, material: &Material) -> usize {
        match (self, material) {
            (
                Shader::Spmm {
                    material, request, ..
                },
                _,
            ) => material.prepared_bytes(request).total(),
            (_, Material::Merl { .. }) => meso_materials::merl::MerlSampler::full_bytes(),
            _ => 0,
        }
    }

    /// A direction of the upper hemisphere (shading frame) for sampling light over it,
    /// and its pdf, without a view-dependent sampler. Analytic BRDFs use
    /// cosine-distributed directions: their response carries cos_i. A pack's BTF does
    /// not vanish with the shading cosine (its bases each have their own normal), and
    /// dividing it by a cosine pdf has infinite variance; packs sampled with
    /// `PackSampling::Defensive` get the defensive half-cosine, half-uniform mixture,
    /// whose pdf is at least 1 / 4 pi (by default they draw from their bases,
    /// `PreparedSpmm::sample_texel`, and `btf` tables from their lobe,
    /// `BtfTable::sample`).
    pub(super) fn hemisphere_sample(&self, u: DVec2) -> (DVec3, f64) {
        match self {
            Shader::Spmm { .. } | Shader::Table => {
                let local = defensive_sample(u);
                (local, defensive_pdf(local))
            }
            Shader::Scene => {
                let local = warp::cosine_hemisphere(u);
                (local, local.z / PI)
            }
        }
    }
}

/// A pack's settings while the camera moves: the residual's mean and at most
/// `MOVING_NPCA` components (docs/rendering.md, "The moving camera").
fn moving_settings(still: EvalSettings) -> EvalSettings {
    EvalSettings {
        max_npca: still.max_npca.min(MOVING_NPCA),
        ..still
    }
}
