//! Shading in the spmm mode: the surface frame at a hit (interpolated normal, tangent
//! along +u as the SPMM convention needs), each material's response to light (albedo
//! f cos_i for analytic BRDFs, tint f cos_i for MERL tables (nearest cell, as the
//! reference reader looks them up), the BTF for SPMM packs, with the residual cut to
//! `MOVING_NPCA` components while the camera moves, and the interpolated table for
//! `btf` materials), and the
//! sampling that suits each material.

use std::f64::consts::PI;

use std::sync::{Arc, OnceLock};

use glam::{DVec2, DVec3};

use super::SpmmMode;
use meso_materials::brdf::warp;
use meso_materials::spmm::{
    EvalSettings, MOVING_NPCA, PrepareRequest, PreparedSpmm, SpmmMaterial, TexelFilter,
    defensive_pdf, defensive_sample,
};
use meso_render::geometry::Hit;
use meso_render::scene::{Material, Scene};

/// How the spmm mode draws directions over the hemisphere at SPMM packs (ambient
/// occlusion, environment and material samples in MIS). Both are unbiased; they
/// differ in noise.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PackSampling {
    /// From the texel's basis functions plus a defensive share
    /// (`PreparedSpmm::sample_texel`).
    #[default]
    Bases,
    /// The defensive half-cosine, half-uniform mixture alone: the sampling before
    /// the bases were drawn from.
    Defensive,
}

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
    /// and its pdf, where the material has no view-dependent sampler. Analytic BRDFs use
    /// cosine-distributed directions: their response carries cos_i. A BTF (a `btf`
    /// material's) does not vanish with the shading cosine (a pack's bases each have
    /// their own normal), and dividing it by a cosine pdf has infinite variance; it
    /// gets the defensive half-cosine, half-uniform mixture, whose pdf is at least
    /// 1 / 4 pi. Packs draw from their bases (`PreparedSpmm::sample_texel`).
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

/// A surface point ready to shade.
pub(crate) struct Shading {
    pub p: DVec3,
    /// Shading frame: tangent, bitangent, normal (facing the incoming ray).
    pub t: DVec3,
    pub b: DVec3,
    pub n: DVec3,
    pub uv: DVec2,
    pub material: usize,
}

impl Shading {
    pub fn to_local(&self, w: DVec3) -> DVec3 {
        DVec3::new(w.dot(self.t), w.dot(self.b), w.dot(self.n))
    }
    pub fn to_world(&self, l: DVec3) -> DVec3 {
        self.t * l.x + self.b * l.y + self.n * l.z
    }
}

/// A triangle's dp/du from its edges `e1`, `e2` and their UV differences `d1`, `d2`
/// (zero where the UVs are degenerate). Shared with the biscale mode's vertex frames.
pub(crate) fn dpdu(e1: DVec3, e2: DVec3, d1: DVec2, d2: DVec2) -> DVec3 {
    let det = d1.x * d2.y - d2.x * d1.y;
    if det.abs() > 1e-20 {
        (e1 * d2.y - e2 * d1.y) / det
    } else {
        DVec3::ZERO
    }
}

/// Tangent (along increasing u: `dpdu` made orthogonal to `n`; any perpendicular where
/// it vanishes) and bitangent n x t: the SPMM convention of the shading frame.
pub(crate) fn tangent_frame(n: DVec3, dpdu: DVec3) -> (DVec3, DVec3) {
    let t = (dpdu - n * n.dot(dpdu))
        .try_normalize()
        .unwrap_or_else(|| warp::orthonormal_basis(n).0);
    (t, n.cross(t))
}

/// The shading frame at `hit` for a ray along `dir`: interpolated normal turned to
/// the viewer, tangent along +u. Every mode that shades the scene's surfaces uses it,
/// so they converge to the same image.
pub(crate) fn shading_at(scene: &Scene, hit: &Hit, dir: DVec3) -> Shading {
    let mesh = &scene.meshes[hit.mesh];
    let [i0, i1, i2] = mesh.indices[hit.triangle].map(|i| i as usize);
    let w0 = 1.0 - hit.b1 - hit.b2;
    let (p0, p1, p2) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
    let p = p0 * w0 + p1 * hit.b1 + p2 * hit.b2;
    let mut ng = (p1 - p0).cross(p2 - p0).normalize_or(DVec3::Y);
    if ng.dot(dir) > 0.0 {
        ng = -ng;
    }
    let mut n = (mesh.normals[i0] * w0 + mesh.normals[i1] * hit.b1 + mesh.normals[i2] * hit.b2)
        .normalize_or(ng);
    // Normals facing away from the viewer are flipped to the side the ray came from.
    if n.dot(ng) < 0.0 {
        n = -n;
    }
    let (uv0, uv1, uv2) = (mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2]);
    let uv = uv0 * w0 + uv1 * hit.b1 + uv2 * hit.b2;
    let (t, b) = tangent_frame(n, dpdu(p1 - p0, p2 - p0, uv1 - uv0, uv2 - uv0));
    Shading {
        p,
        t,
        b,
        n,
        uv,
        material: mesh.material,
    }
}

impl SpmmMode {
    pub(super) fn shading(&self, hit: &Hit, dir: DVec3) -> Shading {
        shading_at(&self.scene, hit, dir)
    }

    /// The material's response to light from `wi` seen from `wo`, cosine included:
    /// albedo f cos_i for BRDFs, tint f cos_i for MERL tables, the BTF for SPMM packs
    /// and `btf` materials (world-space unit vectors).
    pub(super) fn response(&self, s: &Shading, wi: DVec3, wo: DVec3) -> DVec3 {
        let (li, lo) = (s.to_local(wi), s.to_local(wo));
        match (&self.scene.materials[s.material], &self.shaders[s.material]) {
            (Material::Brdf { brdf, albedo }, _) => *albedo * (brdf.eval(li, lo) * li.z.max(0.0)),
            (Material::Merl { brdf, tint }, _) => *tint * brdf.eval(li, lo) * li.z.max(0.0),
            (Material::Spmm { .. }, shader @ Shader::Spmm { still, moving, .. }) => {
                shader.prepared().map_or(DVec3::ZERO, |p| {
                    p.eval_uv(s.uv, li, lo, if self.moving { moving } else { still })
                })
            }
            (Material::Btf { table, uv_scale }, _) => table.eval_uv(s.uv, *uv_scale, li, lo),
            // `supports` refused every other material before the mode was made.
            _ => DVec3::ZERO,
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

/// The power heuristic's weight of a strategy with pdf `a` against one with pdf `b`.
pub(super) fn power_heuristic(a: f64, b: f64) -> f64 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

impl SpmmMode {
    /// The material's sampling pdf of world direction `wi` (0 where it never samples).
    pub(super) fn material_pdf(&self, s: &Shading, wi: DVec3, wo: DVec3) -> f64 {
        let (li, lo) = (s.to_local(wi), s.to_local(wo));
        match (&self.scene.materials[s.material], &self.shaders[s.material]) {
            (Material::Brdf { brdf, .. }, _) => brdf.pdf(lo, li),
            (Material::Merl { brdf, .. }, _) => brdf.pdf(lo, li),
            (_, shader @ Shader::Spmm { still, .. })
                if self.pack_sampling == PackSampling::Bases =>
            {
                shader
                    .prepared()
                    .map_or(0.0, |p| p.pdf_uv(s.uv, still.uv_scale, li, lo))
            }
            (_, Shader::Spmm { .. } | Shader::Table) => defensive_pdf(li),
            _ => 0.0,
        }
    }

    /// A direction drawn from the material for `wo`, with its pdf.
    pub(super) fn material_sample(
        &self,
        s: &Shading,
        wo: DVec3,
        u: glam::DVec2,
    ) -> Option<(DVec3, f64)> {
        match (&self.scene.materials[s.material], &self.shaders[s.material]) {
            (Material::Brdf { brdf, .. }, _) => brdf
                .sample(s.to_local(wo), u)
                .map(|b| (s.to_world(b.wi), b.pdf)),
            (Material::Merl { brdf, .. }, _) => brdf
                .sample(s.to_local(wo), u)
                .map(|b| (s.to_world(b.wi), b.pdf)),
            (_, shader @ Shader::Spmm { still, .. })
                if self.pack_sampling == PackSampling::Bases =>
            {
                shader
                    .prepared()?
                    .sample_uv(s.uv, still.uv_scale, s.to_local(wo), u)
                    .map(|(local, pdf)| (s.to_world(local), pdf))
            }
            (_, shader @ (Shader::Spmm { .. } | Shader::Table)) => {
                let (local, pdf) = shader.hemisphere_sample(u);
                Some((s.to_world(local), pdf))
            }
            _ => None,
        }
    }
}
