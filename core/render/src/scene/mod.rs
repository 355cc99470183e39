//! Scenes (docs/scenes.md): a TOML file read with serde and
//! `deny_unknown_fields`, checked into a `Scene` whose every value is valid: camera,
//! analytic / SPMM / mirror materials, OBJ meshes and quads in world space, point and
//! area lights, ambient occlusion, environment lighting, background, and the render
//! mode and device. Every error names the scene file, the line and the key (or the
//! referenced file and its own fault). Each rule lives in the type that owns the value
//! (`Camera::problem`, `Light::problem`, ...): the loader and edits both ask it.

mod environment;
mod file;
mod load;
mod material_file;
pub mod mesh;
#[cfg(any(test, feature = "testing"))]
pub mod test_scenes;
#[cfg(test)]
mod tests;

use std::path::PathBuf;
use std::sync::Arc;

use glam::{DVec2, DVec3};

use crate::{Device, ModeKind};
pub use environment::Environment;
pub use load::{SceneError, load_scene, load_scene_within};
pub use material_file::{MaterialTable, material_from_table};
pub use mesh::TriangleMesh;
use meso_materials::brdf::AnalyticBrdf;
use meso_materials::btf::table::BtfTable;
use meso_materials::image::Image;
use meso_materials::merl::MerlBrdf;
use meso_materials::rng::Sampler;
use meso_materials::spmm::SpmmMaterial;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    pub frames: u32,
    pub seed: u64,
    pub max_specular_depth: u32,
    pub mode: ModeKind,
    pub device: Device,
    /// How samples draw their numbers (`[render] sampler`, default Sobol).
    pub sampler: Sampler,
    /// Points drawn on each area light per frame and shading point in the spmm mode
    /// (`[render] light_samples`, 1..=`MAX_LIGHT_SAMPLES`, default 1), each weighted
    /// by its share; above `MANY_LIGHTS` lights, that many times the chosen lights.
    pub light_samples: u32,
}

/// The most light samples per frame a scene may ask for.
pub const MAX_LIGHT_SAMPLES: u32 = 64;

/// The scene's extent: every coordinate the tracer receives (placed vertices, quad
/// corners, lights, the camera) lies within +-1e7 m. The tracer stores triangles in
/// f32 (spacing 1 m at 1e7) and lifts secondary rays by 1e-5 of a point's magnitude
/// (100 m there): beyond it, the geometry it is given is no longer the geometry the
/// file describes, and far enough out (about 1e19) f32 products overflow to infinity
/// inside the BVH builder. Refused with the place named rather than rendered wrong.
pub const MAX_EXTENT_M: f64 = 1e7;

/// Why a point cannot be given to the tracer: not finite, or outside the extent.
pub fn extent_problem(p: DVec3) -> Option<String> {
    if !p.is_finite() {
        Some(format!("at {} is not finite", short(p)))
    } else if p.abs().max_element() > MAX_EXTENT_M {
        Some(format!(
            "at {} is outside the scene extent (every coordinate within +-{MAX_EXTENT_M:e} m, what f32 tracing resolves)",
            short(p)
        ))
    } else {
        None
    }
}

/// A point for messages: plain numbers where short, scientific notation where not.
fn short(p: DVec3) -> String {
    let one = |v: f64| {
        if v == 0.0 || (1e-3..1e7).contains(&v.abs()) {
            format!("{}", (v * 1e6).round() / 1e6)
        } else {
            format!("{v:.3e}")
        }
    };
    format!("[{}, {}, {}]", one(p.x), one(p.y), one(p.z))
}

/// The largest image side any mode renders.
pub const MAX_IMAGE_SIDE: u32 = 16384;

impl RenderSettings {
    /// Why an image of `width` x `height` cannot be rendered (the one size rule: scene
    /// files, command-line flags and resize edits all ask it).
    pub fn size_problem(width: u32, height: u32) -> Option<String> {
        let ok = |v: u32| (1..=MAX_IMAGE_SIDE).contains(&v);
        (!(ok(width) && ok(height)))
            .then(|| format!("image size {width}x{height} is outside 1..={MAX_IMAGE_SIDE}"))
    }

    /// Why `n` light samples per frame cannot be used (the one rule for the scene
    /// file, `--light-samples` and edits).
    pub fn light_samples_problem(n: u32) -> Option<String> {
        (!(1..=MAX_LIGHT_SAMPLES).contains(&n))
            .then(|| format!("{n} light samples is outside 1..={MAX_LIGHT_SAMPLES}"))
    }
}

/// A pinhole camera (right-handed, y up).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: DVec3,
    pub look_at: DVec3,
    pub up: DVec3,
    pub fov_y_deg: f64,
}

#[derive(Clone, Debug)]
pub enum Material {
    /// f_rgb = albedo * f(wi, wo).
    Brdf {
        brdf: AnalyticBrdf,
        albedo: DVec3,
    },
    Spmm {
        material: Arc<SpmmMaterial>,
        uv_scale: DVec2,
        residual: bool,
        npca: usize,
    },
    Mirror {
        reflectance: DVec3,
    },
    /// A measured isotropic BRDF (MERL table); f_rgb = tint * table(wi, wo).
    Merl {
        brdf: Arc<MerlBrdf>,
        tint: DVec3,
    },
    /// A BTF shaded directly (nearest texel, directions interpolated), tiled.
    Btf {
        table: Arc<BtfTable>,
        uv_scale: DVec2,
    },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Intensity in W/sr, 1/r^2 fall-off.
    Point { position: DVec3, intensity: DVec3 },
    /// One-sided parallelogram emitting `radiance` towards edge_u x edge_v.
    Area {
        corner: DVec3,
        edge_u: DVec3,
        edge_v: DVec3,
        radiance: DVec3,
    },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ambient {
    pub radiance: DVec3,
    /// Occluders farther than this are ignored; `f64::INFINITY` = none ignored.
    pub radius: f64,
}

#[derive(Clone, Debug)]
pub enum Background {
    /// No `[background]` table: rays that leave the scene see the `[environment]`
    /// (black without one).
    FromEnvironment,
    Color(DVec3),
    /// Lat-long image, +y up (the `[environment]` convention), seen but not lighting.
    Environment(Arc<Image>),
}

impl Background {
    /// Why this background is invalid (same rules as the scene file).
    pub fn problem(&self) -> Option<Problem> {
        match self {
            Background::FromEnvironment => None,
            Background::Color(c) => (!(c.is_finite() && c.min_element() >= 0.0))
                .then(|| Problem::new("color", format!("{c} must be finite and non-negative"))),
            Background::Environment(img) => {
                crate::environment::check_map(img).map(|m| Problem::new("environment", m))
            }
        }
    }
}

/// What is wrong with a value and under which key of its table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Problem {
    pub key: &'static str,
    pub message: String,
}

impl Problem {
    pub fn new(key: &'static str, message: impl Into<String>) -> Self {
        Self {
            key,
            message: message.into(),
        }
    }
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "`{}`: {}", self.key, self.message)
    }
}

#[derive(Clone, Debug)]
pub struct Scene {
    pub render: RenderSettings,
    pub camera: Camera,
    pub material_names: Vec<String>,
    pub materials: Vec<Material>,
    /// The file each material was read from (SPMM packs), for the editor's Save;
    /// shorter than `materials` or `None` where there is none.
    pub material_files: Vec<Option<PathBuf>>,
    pub meshes: Vec<TriangleMesh>,
    pub lights: Vec<Light>,
    pub ambient: Option<Ambient>,
    /// Distant lighting from a lat-long map (`[environment]`).
    pub environment: Option<Environment>,
    pub background: Background,
}

impl Scene {
    /// The name of material `index` as the scene file gives it, or `#index`.
    pub fn material_name(&self, index: usize) -> String {
        self.material_names
            .get(index)
            .cloned()
            .unwrap_or_else(|| format!("#{index}"))
    }
}

impl Material {
    /// The kind's name in scene files.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Material::Brdf { .. } => "brdf",
            Material::Spmm { .. } => "spmm",
            Material::Mirror { .. } => "mirror",
            Material::Merl { .. } => "merl",
            Material::Btf { .. } => "btf",
        }
    }
}

impl Camera {
    /// Why this camera cannot render, and the key at fault.
    pub fn problem(&self) -> Option<Problem> {
        let forward = self.look_at - self.position;
        for (key, v) in [("position", self.position), ("look_at", self.look_at)] {
            if let Some(p) = extent_problem(v) {
                return Some(Problem::new(key, p));
            }
        }
        if !self.up.is_finite() {
            return Some(Problem::new("up", format!("{} is not finite", self.up)));
        }
        if !(self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            Some(Problem::new(
                "fov_y_deg",
                format!("{} is outside (0, 180)", self.fov_y_deg),
            ))
        } else if forward.length() < 1e-9 {
            Some(Problem::new("look_at", "equals the camera position"))
        } else if forward.cross(self.up).length()
            < 1e-9 * forward.length() * self.up.length().max(1e-300)
        {
            Some(Problem::new(
                "up",
                "is zero or parallel to the viewing direction",
            ))
        } else {
            None
        }
    }
}

impl Light {
    /// The emitted quantity the light's contribution is linear in: intensity (point)
    /// or radiance (area).
    pub fn emission(&self) -> DVec3 {
        match *self {
            Light::Point { intensity, .. } => intensity,
            Light::Area { radiance, .. } => radiance,
        }
    }

    /// The same light with another emission.
    pub fn with_emission(mut self, e: DVec3) -> Self {
        match &mut self {
            Light::Point { intensity, .. } => *intensity = e,
            Light::Area { radiance, .. } => *radiance = e,
        }
        self
    }

    /// Why this light is invalid, and the key at fault.
    pub fn problem(&self) -> Option<Problem> {
        let (key, e) = match self {
            Light::Point { intensity, .. } => ("intensity", *intensity),
            Light::Area { radiance, .. } => ("radiance", *radiance),
        };
        if !(e.is_finite() && e.min_element() >= 0.0) {
            return Some(Problem::new(
                key,
                format!("{e} must be finite and non-negative"),
            ));
        }
        match *self {
            Light::Point { position, .. } => {
                extent_problem(position).map(|p| Problem::new("position", p))
            }
            Light::Area {
                corner,
                edge_u,
                edge_v,
                ..
            } => {
                for (key, v) in [
                    ("corner", corner),
                    ("edge_u", corner + edge_u),
                    ("edge_v", corner + edge_v),
                    ("edge_v", corner + edge_u + edge_v),
                ] {
                    if let Some(p) = extent_problem(v) {
                        return Some(Problem::new(key, format!("a corner {p}")));
                    }
                }
                (edge_u.cross(edge_v).length() <= 1e-12)
                    .then(|| Problem::new("edge_v", "the area light has zero area"))
            }
        }
    }

    /// The kind's name in scene files.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Light::Point { .. } => "point",
            Light::Area { .. } => "area",
        }
    }
}

impl Ambient {
    /// Why this ambient term is invalid, and the key at fault.
    pub fn problem(&self) -> Option<Problem> {
        if !(self.radiance.is_finite() && self.radiance.min_element() >= 0.0) {
            Some(Problem::new(
                "radiance",
                format!("{} must be finite and non-negative", self.radiance),
            ))
        } else if self.radius.is_nan() || self.radius <= 0.0 {
            Some(Problem::new(
                "radius",
                format!("{} must be positive (inf: no limit)", self.radius),
            ))
        } else {
            None
        }
    }
}
