//! The shading core every CPU mode calls: a material at a hit gives its response to
//! light (cosine included), a direction drawn from it and that direction's pdf, for
//! every material kind (analytic BRDFs, MERL tables, SPMM packs, `btf` tables,
//! mirrors). A new material kind is shaded here and nowhere else on the CPU.
//!
//! - analytic BRDFs: albedo f cos_i, the BRDF's own sampling;
//! - MERL tables: tint f cos_i (nearest cell, as the reference reader looks them
//!   up), the table's sampling;
//! - SPMM packs: the BTF, with the residual cut to `MOVING_NPCA` components while the
//!   camera moves, sampled from the texel's bases (`PackSampling`);
//! - `btf` materials: the interpolated table, sampled from its texel-mean lobe and a
//!   defensive share (`BtfTable::sample`);
//! - mirrors: a delta lobe (`ShadedMaterial::specular`): the caller follows the
//!   reflected ray, since no finite response or pdf describes it.

mod frame;
mod shader;

use std::f64::consts::PI;

use glam::{DVec2, DVec3};

use crate::geometry::SceneBvh;
use crate::scene::{Light, Material, Scene};
use meso_materials::spmm::defensive_pdf;
use shader::Shader;

pub use frame::{Shading, dpdu, power_heuristic, tangent_frame};

/// How SPMM packs draw directions over the hemisphere (ambient occlusion, environment
/// and material samples in MIS). Both are unbiased; they differ in noise.
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

/// A point on a light as a surface point at `p` sees it: the point, the unit
/// direction to it and its falloff (`1 / r^2` for a point light; `cos_l A / r^2` for
/// the uniform point `u` on an area light, the reciprocal of its solid-angle pdf).
#[derive(Clone, Copy, Debug)]
pub struct PointOnLight {
    pub q: DVec3,
    pub wi: DVec3,
    pub falloff: f64,
}

/// `light` seen from `p` (with the point `u` of an area light's parallelogram);
/// `None` behind a one-sided area light, which emits towards edge_u x edge_v.
pub fn point_on_light(light: &Light, u: DVec2, p: DVec3) -> Option<PointOnLight> {
    let (q, geometry) = match *light {
        Light::Point { position, .. } => (position, None),
        Light::Area {
            corner,
            edge_u,
            edge_v,
            ..
        } => (
            corner + edge_u * u.x + edge_v * u.y,
            Some(edge_u.cross(edge_v)),
        ),
    };
    let to = q - p;
    let d2 = to.length_squared();
    let wi = to / d2.sqrt();
    let falloff = match geometry {
        None => 1.0 / d2,
        Some(cross) => {
            let area = cross.length();
            let cos_l = -wi.dot(cross / area);
            if cos_l <= 0.0 {
                return None;
            }
            cos_l * area / d2
        }
    };
    Some(PointOnLight { q, wi, falloff })
}

/// A point on `light` (the point `u` of an area light) that `s` sees: its direction
/// and falloff, once the one shadow ray from `lift` (the point lifted off the surface)
/// through `bvh` found it unoccluded, counted in `shadow_rays`; `None` behind a
/// one-sided light, below the surface, or shadowed.
pub fn visible_light_point(
    bvh: &SceneBvh,
    light: &Light,
    u: DVec2,
    (s, lift): (&Shading, DVec3),
    shadow_rays: &mut u64,
) -> Option<(DVec3, f64)> {
    let PointOnLight { q, wi, falloff } = point_on_light(light, u, s.p)?;
    let cos_i = wi.dot(s.n);
    if cos_i.is_nan() || cos_i <= 0.0 {
        return None;
    }
    *shadow_rays += 1;
    let reach = (q - lift).length() * (1.0 - 1e-6);
    (!bvh.occluded(lift, wi, 0.0, reach)).then_some((wi, falloff))
}

/// The scene's materials as a render shades them: what each needs prepared, and how
/// packs are sampled. Indexed like `Scene::materials`.
pub struct Shaders {
    shaders: Vec<Shader>,
    sampling: PackSampling,
}

impl Shaders {
    /// Nothing prepared yet: packs prepare on first use (`make_resident_at`).
    pub fn new(materials: &[Material]) -> Self {
        Self {
            shaders: materials.iter().map(Shader::new).collect(),
            sampling: PackSampling::default(),
        }
    }

    pub fn set_pack_sampling(&mut self, sampling: PackSampling) {
        self.sampling = sampling;
    }

    /// Material `index` of `scene` as shaded now (`moving`: the camera is being
    /// dragged, and packs drop their later residual components).
    pub fn material<'a>(
        &'a self,
        scene: &'a Scene,
        index: usize,
        moving: bool,
    ) -> ShadedMaterial<'a> {
        ShadedMaterial {
            material: &scene.materials[index],
            shader: &self.shaders[index],
            sampling: self.sampling,
            moving,
        }
    }

    /// Material `index` became `after`, replacing `before` (`None`: unknown): a pack
    /// that keeps its residual keeps the prepared tables it had.
    pub fn edited(&mut self, index: usize, before: Option<&Material>, after: &Material) {
        self.shaders[index] = match before {
            Some(before) => self.shaders[index].after_edit(before, after),
            None => Shader::new(after),
        };
    }

    /// Whether the moving flag changes material `index`'s response.
    pub fn changes_when_moving(&self, index: usize) -> bool {
        self.shaders[index].changes_when_moving()
    }

    /// Prepares what shading material `index` at texture position `uv` needs (a
    /// pack's residual tables of the cluster there, a MERL table's sampling tables).
    pub fn make_resident_at(&self, materials: &[Material], index: usize, uv: DVec2) {
        self.shaders[index].make_resident_at(&materials[index], uv);
    }

    /// Prepares everything every material could need, reached or not.
    pub fn make_all_resident(&self, materials: &[Material]) {
        for (shader, material) in self.shaders.iter().zip(materials) {
            shader.make_all_resident(material);
        }
    }

    /// Bytes of prepared material data: held now, and once everything is prepared.
    pub fn bytes(&self, materials: &[Material]) -> (u64, u64) {
        let each = || self.shaders.iter().zip(materials);
        let resident = each().map(|(s, m)| s.resident_bytes(m)).sum::<usize>();
        let full = each().map(|(s, m)| s.full_bytes(m)).sum::<usize>();
        (resident as u64, full as u64)
    }
}

/// One material ready to shade: its response, its sampler and its pdf, in the
/// shading frame's local coordinates (`*_local`, z along the normal) or in world
/// space at a `Shading`.
/// The share of ambient directions drawn from a glossy material's lobe
/// (`ShadedMaterial::ambient_sample`); the rest are cosine-distributed.
pub const AMBIENT_LOBE_SHARE: f64 = 0.5;

#[derive(Clone, Copy)]
pub struct ShadedMaterial<'a> {
    material: &'a Material,
    shader: &'a Shader,
    sampling: PackSampling,
    moving: bool,
}

impl ShadedMaterial<'_> {
    /// A mirror's reflectance: light leaves only along the reflected direction, which
    /// the caller follows. `None` for every material with a finite response.
    pub fn specular(&self) -> Option<DVec3> {
        match self.material {
            Material::Mirror { reflectance } => Some(*reflectance),
            _ => None,
        }
    }

    /// Whether area lights are sampled by MIS of light and material samples: MERL
    /// tables, whose measured lobes can be far narrower than a light. Analytic BRDFs
    /// and packs keep the light samples alone (and their images' bits).
    pub fn mis_with_area_lights(&self) -> bool {
        matches!(self.material, Material::Merl { .. })
    }

    /// The response to light from local `li` seen from local `lo` at texture position
    /// `uv`, cosine included: albedo f cos_i, tint f cos_i, or the BTF (zero for a
    /// mirror, whose lobe is a delta).
    pub fn response_local(&self, uv: DVec2, li: DVec3, lo: DVec3) -> DVec3 {
        match (self.material, self.shader) {
            (Material::Brdf { brdf, albedo }, _) => *albedo * (brdf.eval(li, lo) * li.z.max(0.0)),
            (Material::Merl { brdf, tint }, _) => *tint * brdf.eval(li, lo) * li.z.max(0.0),
            (Material::Spmm { .. }, shader @ Shader::Spmm { still, moving, .. }) => {
                shader.prepared().map_or(DVec3::ZERO, |p| {
                    p.eval_uv(uv, li, lo, if self.moving { moving } else { still })
                })
            }
            (Material::Btf { table, uv_scale }, _) => table.eval_uv(uv, *uv_scale, li, lo),
            _ => DVec3::ZERO,
        }
    }

    /// The pdf with which `sample_local` draws local `li` for `lo` (0 where it never
    /// draws it).
    pub fn pdf_local(&self, uv: DVec2, li: DVec3, lo: DVec3) -> f64 {
        match (self.material, self.shader) {
            (Material::Brdf { brdf, .. }, _) => brdf.pdf(lo, li),
            (Material::Merl { brdf, .. }, _) => brdf.pdf(lo, li),
            (Material::Btf { table, .. }, _) => table.pdf(li, lo),
            (_, shader @ Shader::Spmm { still, .. }) if self.sampling == PackSampling::Bases => {
                shader
                    .prepared()
                    .map_or(0.0, |p| p.pdf_uv(uv, still.uv_scale, li, lo))
            }
            (_, Shader::Spmm { .. }) => defensive_pdf(li),
            _ => 0.0,
        }
    }

    /// A local direction drawn from the material for local `lo` with the pair `u`, and
    /// its solid-angle pdf (`None`: nothing drawn, as below a grazing view or for a
    /// mirror).
    pub fn sample_local(&self, uv: DVec2, lo: DVec3, u: DVec2) -> Option<(DVec3, f64)> {
        match (self.material, self.shader) {
            (Material::Brdf { brdf, .. }, _) => brdf.sample(lo, u).map(|b| (b.wi, b.pdf)),
            (Material::Merl { brdf, .. }, _) => brdf.sample(lo, u).map(|b| (b.wi, b.pdf)),
            (Material::Btf { table, .. }, _) => table.sample(lo, u),
            (_, shader @ Shader::Spmm { still, .. }) if self.sampling == PackSampling::Bases => {
                shader.prepared()?.sample_uv(uv, still.uv_scale, lo, u)
            }
            (_, shader @ Shader::Spmm { .. }) => Some(shader.hemisphere_sample(u)),
            _ => None,
        }
    }

    /// `response_local` for world directions at `s`.
    pub fn response(&self, s: &Shading, wi: DVec3, wo: DVec3) -> DVec3 {
        self.response_local(s.uv, s.to_local(wi), s.to_local(wo))
    }

    /// `pdf_local` for world directions at `s`.
    pub fn pdf(&self, s: &Shading, wi: DVec3, wo: DVec3) -> f64 {
        self.pdf_local(s.uv, s.to_local(wi), s.to_local(wo))
    }

    /// `sample_local` for world directions at `s`.
    pub fn sample(&self, s: &Shading, wo: DVec3, u: DVec2) -> Option<(DVec3, f64)> {
        self.sample_local(s.uv, s.to_local(wo), u)
            .map(|(local, pdf)| (s.to_world(local), pdf))
    }

    /// A world direction of the upper hemisphere at `s` for ambient occlusion and its
    /// weight 1 / pdf: cosine-distributed where the response carries cos_i and little
    /// else (Lambertian and Oren-Nayar BRDFs; written pi / cos, as it always was, to
    /// keep its bits); for glossy analytic BRDFs and MERL tables, whose lobes a cosine
    /// direction rarely meets (its estimate is heavy-tailed), one sample of the even
    /// mixture of cosine and material directions (`AMBIENT_LOBE_SHARE`: the first number
    /// picks the strategy and, rescaled, drives it), weighted by the mixture's pdf; the
    /// material's own sampling for packs and BTFs, whose response does not vanish with
    /// the cosine.
    pub fn ambient_sample(&self, s: &Shading, wo: DVec3, u: DVec2) -> Option<(DVec3, f64)> {
        match self.shader {
            Shader::Scene if self.glossy() => {
                let lo = s.to_local(wo);
                let local = if u.x < AMBIENT_LOBE_SHARE {
                    let u = DVec2::new(u.x / AMBIENT_LOBE_SHARE, u.y);
                    self.sample_local(s.uv, lo, u)?.0
                } else {
                    let u =
                        DVec2::new((u.x - AMBIENT_LOBE_SHARE) / (1.0 - AMBIENT_LOBE_SHARE), u.y);
                    self.shader.hemisphere_sample(u).0
                };
                if local.z <= 0.0 {
                    return None;
                }
                let pdf = AMBIENT_LOBE_SHARE * self.pdf_local(s.uv, local, lo)
                    + (1.0 - AMBIENT_LOBE_SHARE) * local.z / PI;
                (pdf > 0.0 && pdf.is_finite()).then(|| (s.to_world(local), 1.0 / pdf))
            }
            Shader::Scene => {
                let (local, _) = self.shader.hemisphere_sample(u);
                (local.z > 0.0).then(|| (s.to_world(local), PI / local.z))
            }
            Shader::Spmm { .. } | Shader::Table => match self.sample(s, wo, u) {
                Some((wi, pdf)) if wi.dot(s.n) > 0.0 => Some((wi, 1.0 / pdf)),
                _ => None,
            },
        }
    }

    /// Whether the material is a glossy analytic BRDF or a MERL table: a lobe that
    /// cosine directions sample poorly (`ambient_sample`).
    fn glossy(&self) -> bool {
        use meso_materials::brdf::BrdfModel;
        match self.material {
            Material::Brdf { brdf, .. } => {
                !matches!(brdf.model(), BrdfModel::Lambertian | BrdfModel::OrenNayar)
            }
            Material::Merl { .. } => true,
            _ => false,
        }
    }

    /// The colour the material reflects where it is the same everywhere: an analytic
    /// BRDF's albedo, a MERL table's albedo at normal view times its tint, a mirror's
    /// reflectance; `None` for packs and BTFs, whose colour varies per texel.
    pub fn uniform_albedo(&self) -> Option<DVec3> {
        match self.material {
            Material::Brdf { albedo, .. } => Some(*albedo),
            Material::Merl { brdf, tint } => Some(*tint * brdf.albedo_at_normal()),
            Material::Mirror { reflectance } => Some(*reflectance),
            Material::Spmm { .. } | Material::Btf { .. } => None,
        }
    }

    /// The colour the material reflects at `s`, for guiding a denoiser only: the
    /// uniform albedo, or a texel seen and lit along the normal: pi x BTF(n, n).
    pub fn albedo(&self, s: &Shading) -> DVec3 {
        self.uniform_albedo()
            .unwrap_or_else(|| self.response(s, s.n, s.n) * PI)
    }
}

#[cfg(test)]
mod tests;
