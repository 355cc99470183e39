//! Scenes (docs/scenes.md): a TOML file read with serde and
//! `deny_unknown_fields`, checked into a `Scene` whose every value is valid: camera,
//! analytic / SPMM / mirror materials, OBJ meshes and quads in world space, point and
//! area lights, ambient occlusion, environment lighting, background, and the render
//! mode and device. Every error names the scene file, the line and the key (or the
//! referenced file and its own fault). Each rule lives in the type that owns the value
//! (`Camera::problem`, `Light::problem`, ...): the loader and edits both ask it.

mod environment;
mod file;
pub mod mesh;
#[cfg(any(test, feature = "testing"))]
pub mod test_scenes;
#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DMat3, DVec2, DVec3};
use toml::Spanned;

use crate::{Device, ModeKind};
pub use environment::Environment;
pub use mesh::TriangleMesh;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::btf::{self, table::BtfTable};
use meso_materials::image::{self, Image};
use meso_materials::merl::{self, MerlBrdf};
use meso_materials::rng::Sampler;
use meso_materials::spmm::SpmmMaterial;
use meso_materials::spmm::pack;

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

/// A scene that cannot be loaded: the file, the line (when known), the key, and why.
#[derive(Debug, thiserror::Error)]
#[error("`{}`{}{}: {message}", file.display(), line.map(|l| format!(" line {l}")).unwrap_or_default(), key.as_ref().map(|k| format!(", `{k}`")).unwrap_or_default())]
pub struct SceneError {
    pub file: PathBuf,
    pub line: Option<usize>,
    pub key: Option<String>,
    pub message: String,
}

struct Ctx<'a> {
    file: &'a Path,
    text: &'a str,
}

impl Ctx<'_> {
    fn line_of(&self, span: &Range<usize>) -> Option<usize> {
        (span.end > 0 && span.start <= self.text.len())
            .then(|| self.text[..span.start].matches('\n').count() + 1)
    }
    fn err<T>(
        &self,
        span: &Range<usize>,
        key: impl Into<String>,
        message: impl Into<String>,
    ) -> Result<T, SceneError> {
        Err(SceneError {
            file: self.file.to_path_buf(),
            line: self.line_of(span),
            key: Some(key.into()),
            message: message.into(),
        })
    }
    /// A `Problem` of the value under table `table`, at the span of its key.
    fn problem<T>(
        &self,
        table: &str,
        problem: Problem,
        span_of: impl Fn(&str) -> Range<usize>,
    ) -> Result<T, SceneError> {
        self.err(
            &span_of(problem.key),
            format!("{table}.{}", problem.key),
            problem.message,
        )
    }
    fn finite3(&self, v: &Spanned<[f64; 3]>, key: &str) -> Result<DVec3, SceneError> {
        let d = DVec3::from_array(*v.get_ref());
        if d.is_finite() {
            Ok(d)
        } else {
            self.err(&v.span(), key, format!("{:?} is not finite", v.get_ref()))
        }
    }
    fn non_negative3(&self, v: &Spanned<[f64; 3]>, key: &str) -> Result<DVec3, SceneError> {
        let d = self.finite3(v, key)?;
        if d.min_element() >= 0.0 {
            Ok(d)
        } else {
            self.err(&v.span(), key, format!("{d} has a negative component"))
        }
    }
}

/// Reads and checks a scene file; referenced files are relative to it.
pub fn load_scene(path: &Path) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|e| SceneError {
        file: path.to_path_buf(),
        line: None,
        key: None,
        message: format!("cannot read: {e}"),
    })?;
    let ctx = Ctx {
        file: path,
        text: &text,
    };
    let parsed: file::SceneFile = toml::from_str(&text).map_err(|e| {
        let line = e.span().and_then(|s| ctx.line_of(&s));
        // toml names the key for unknown or missing fields but not for a wrong type:
        // take it from the offending line (`key = value`).
        let key = line
            .and_then(|l| text.lines().nth(l - 1))
            .and_then(|l| l.split_once('='))
            .map(|(k, _)| k.trim().to_string())
            .filter(|k| !k.is_empty() && !k.starts_with('['));
        SceneError {
            file: path.to_path_buf(),
            line,
            key,
            message: e.message().to_string(),
        }
    })?;
    let folder = path.parent().unwrap_or(Path::new("."));
    build(&ctx, parsed, folder)
}

fn build(ctx: &Ctx, f: file::SceneFile, folder: &Path) -> Result<Scene, SceneError> {
    if *f.version.get_ref() != 1 {
        return ctx.err(
            &f.version.span(),
            "version",
            format!("{}: only version 1 exists", f.version.get_ref()),
        );
    }
    let r = &f.render;
    if let Some(p) = RenderSettings::size_problem(*r.width.get_ref(), *r.height.get_ref()) {
        let span = if (1..=MAX_IMAGE_SIDE).contains(r.width.get_ref()) {
            r.height.span()
        } else {
            r.width.span()
        };
        return ctx.err(&span, "render.width/height", p);
    }
    if *r.frames.get_ref() == 0 {
        return ctx.err(&r.frames.span(), "render.frames", "must be at least 1");
    }
    if *r.max_specular_depth.get_ref() > 64 {
        return ctx.err(
            &r.max_specular_depth.span(),
            "render.max_specular_depth",
            "must be at most 64",
        );
    }
    if let Some(p) = RenderSettings::light_samples_problem(*r.light_samples.get_ref()) {
        return ctx.err(&r.light_samples.span(), "render.light_samples", p);
    }
    let mode = match &r.mode {
        None => ModeKind::default(),
        Some(m) => ModeKind::from_name(m.get_ref()).map_or_else(
            || {
                ctx.err(
                    &m.span(),
                    "render.mode",
                    format!("`{}`: modes are spmm, biscale, adaptive", m.get_ref()),
                )
            },
            Ok,
        )?,
    };
    let device = match &r.device {
        None => Device::default(),
        Some(d) => Device::from_name(d.get_ref()).map_or_else(
            || {
                ctx.err(
                    &d.span(),
                    "render.device",
                    format!("`{}`: devices are cpu, gpu", d.get_ref()),
                )
            },
            Ok,
        )?,
    };
    let sampler = match &r.sampler {
        None => Sampler::default(),
        Some(s) => Sampler::from_name(s.get_ref()).map_or_else(
            || {
                ctx.err(
                    &s.span(),
                    "render.sampler",
                    format!("`{}`: samplers are sobol, independent", s.get_ref()),
                )
            },
            Ok,
        )?,
    };
    let render = RenderSettings {
        width: *r.width.get_ref(),
        height: *r.height.get_ref(),
        frames: *r.frames.get_ref(),
        seed: r.seed,
        max_specular_depth: *r.max_specular_depth.get_ref(),
        mode,
        device,
        sampler,
        light_samples: *r.light_samples.get_ref(),
    };

    let c = &f.camera;
    let camera = Camera {
        position: DVec3::from_array(*c.position.get_ref()),
        look_at: DVec3::from_array(*c.look_at.get_ref()),
        up: DVec3::from_array(*c.up.get_ref()),
        fov_y_deg: *c.fov_y_deg.get_ref(),
    };
    if let Some(p) = camera.problem() {
        return ctx.problem("camera", p, |k| match k {
            "position" => c.position.span(),
            "look_at" => c.look_at.span(),
            "up" => c.up.span(),
            _ => c.fov_y_deg.span(),
        });
    }

    let mut material_names = Vec::new();
    let mut materials = Vec::new();
    let mut index_of: BTreeMap<String, usize> = BTreeMap::new();
    for (name, m) in &f.materials {
        index_of.insert(name.clone(), materials.len());
        material_names.push(name.clone());
        materials.push(build_material(
            ctx,
            &format!("materials.{name}"),
            m,
            folder,
        )?);
    }
    let material_ref = |s: &Spanned<String>, key: &str| -> Result<usize, SceneError> {
        match index_of.get(s.get_ref()) {
            Some(&i) => Ok(i),
            None => ctx.err(
                &s.span(),
                key,
                format!(
                    "no material named `{}` (defined: {})",
                    s.get_ref(),
                    material_names.join(", ")
                ),
            ),
        }
    };

    let mut meshes = Vec::new();
    for (i, m) in f.meshes.iter().enumerate() {
        let key = |k: &str| format!("mesh[{i}].{k}");
        let material = material_ref(&m.material, &key("material"))?;
        let scale = *m.scale.get_ref();
        if !(scale.is_finite() && scale > 0.0) {
            return ctx.err(
                &m.scale.span(),
                key("scale"),
                format!("{scale} must be positive and finite"),
            );
        }
        let axis = ctx.finite3(&m.rotate_axis, &key("rotate_axis"))?;
        let angle = *m.rotate_deg.get_ref();
        if !angle.is_finite() {
            return ctx.err(&m.rotate_deg.span(), key("rotate_deg"), "is not finite");
        }
        let Some(axis) = axis.try_normalize() else {
            return ctx.err(
                &m.rotate_axis.span(),
                key("rotate_axis"),
                "is the zero vector",
            );
        };
        let placement = mesh::Placement {
            scale,
            rotation: DMat3::from_axis_angle(axis, angle.to_radians()),
            translate: ctx.finite3(&m.translate, &key("translate"))?,
        };
        let path = folder.join(m.path.get_ref());
        let loaded = mesh::load_obj(&path, &placement, material).map_err(|e| SceneError {
            file: ctx.file.to_path_buf(),
            line: ctx.line_of(&m.path.span()),
            // A vertex outside the extent is the placement's fault as much as the file's.
            key: Some(match e {
                mesh::MeshError::Extent { .. } => format!("mesh[{i}] (scale, rotate, translate)"),
                _ => key("path"),
            }),
            message: e.to_string(),
        })?;
        meshes.push(loaded);
    }
    for (i, q) in f.quads.iter().enumerate() {
        let key = |k: &str| format!("quad[{i}].{k}");
        let material = material_ref(&q.material, &key("material"))?;
        let corner = ctx.finite3(&q.corner, &key("corner"))?;
        let (eu, ev) = (
            ctx.finite3(&q.edge_u, &key("edge_u"))?,
            ctx.finite3(&q.edge_v, &key("edge_v"))?,
        );
        if eu.cross(ev).length() <= 1e-12 {
            return ctx.err(
                &q.edge_v.span(),
                key("edge_v"),
                "the quad has zero area (edges parallel or zero)",
            );
        }
        for (k, p) in [
            ("corner", corner),
            ("edge_u", corner + eu),
            ("edge_v", corner + ev),
            ("edge_v", corner + eu + ev),
        ] {
            if let Some(problem) = extent_problem(p) {
                let span = if k == "corner" {
                    q.corner.span()
                } else {
                    q.edge_v.span()
                };
                return ctx.err(&span, key(k), format!("a corner {problem}"));
            }
        }
        meshes.push(mesh::quad(corner, eu, ev, material));
    }

    let mut lights = Vec::new();
    for (i, l) in f.lights.iter().enumerate() {
        let span = l.span();
        let l = l.get_ref();
        let key = |k: &str| format!("light[{i}].{k}");
        // Values are checked by `Light::problem` below.
        let need = |v: &Option<Spanned<[f64; 3]>>, k: &str| -> Result<DVec3, SceneError> {
            match v {
                Some(v) => Ok(DVec3::from_array(*v.get_ref())),
                None => ctx.err(
                    &span,
                    key(k),
                    format!("a {} light needs `{k}`", l.kind.get_ref()),
                ),
            }
        };
        let forbid = |v: bool, k: &str| -> Result<(), SceneError> {
            if v {
                ctx.err(
                    &span,
                    key(k),
                    format!("does not belong to a {} light", l.kind.get_ref()),
                )
            } else {
                Ok(())
            }
        };
        let light = match l.kind.get_ref().as_str() {
            "point" => {
                forbid(l.corner.is_some(), "corner")?;
                forbid(l.edge_u.is_some(), "edge_u")?;
                forbid(l.edge_v.is_some(), "edge_v")?;
                forbid(l.radiance.is_some(), "radiance")?;
                Light::Point {
                    position: need(&l.position, "position")?,
                    intensity: need(&l.intensity, "intensity")?,
                }
            }
            "area" => {
                forbid(l.position.is_some(), "position")?;
                forbid(l.intensity.is_some(), "intensity")?;
                Light::Area {
                    corner: need(&l.corner, "corner")?,
                    edge_u: need(&l.edge_u, "edge_u")?,
                    edge_v: need(&l.edge_v, "edge_v")?,
                    radiance: need(&l.radiance, "radiance")?,
                }
            }
            other => {
                return ctx.err(
                    &l.kind.span(),
                    key("kind"),
                    format!("`{other}`: lights are `point` or `area`"),
                );
            }
        };
        if let Some(p) = light.problem() {
            return ctx.problem(&format!("light[{i}]"), p, |k| {
                match k {
                    "position" => l.position.as_ref(),
                    "intensity" => l.intensity.as_ref(),
                    "corner" => l.corner.as_ref(),
                    "edge_u" => l.edge_u.as_ref(),
                    "edge_v" => l.edge_v.as_ref(),
                    _ => l.radiance.as_ref(),
                }
                .map_or(span.clone(), |v| v.span())
            });
        }
        lights.push(light);
    }

    let ambient = match &f.ambient {
        None => None,
        Some(a) => {
            let ambient = Ambient {
                radiance: DVec3::from_array(*a.radiance.get_ref()),
                radius: *a.radius.get_ref(),
            };
            if let Some(p) = ambient.problem() {
                return ctx.problem("ambient", p, |k| {
                    if k == "radius" {
                        a.radius.span()
                    } else {
                        a.radiance.span()
                    }
                });
            }
            Some(ambient)
        }
    };
    let read_map = |path: &Spanned<PathBuf>, key: &str| -> Result<Arc<Image>, SceneError> {
        let img = image::read_image(&folder.join(path.get_ref())).map_err(|e| SceneError {
            file: ctx.file.to_path_buf(),
            line: ctx.line_of(&path.span()),
            key: Some(key.into()),
            message: e.to_string(),
        })?;
        if let Some(p) = crate::environment::check_map(&img) {
            return ctx.err(
                &path.span(),
                key,
                format!("`{}`: {p}", path.get_ref().display()),
            );
        }
        Ok(Arc::new(img))
    };
    let environment = match &f.environment {
        None => None,
        Some(e) => {
            let env = Environment {
                map: read_map(&e.path, "environment.path")?,
                strength: *e.strength.get_ref(),
                rotate_y_deg: *e.rotate_y_deg.get_ref(),
                mis: e.mis,
            };
            if let Some(p) = env.problem() {
                return ctx.problem("environment", p, |k| match k {
                    "strength" => e.strength.span(),
                    "rotate_y_deg" => e.rotate_y_deg.span(),
                    _ => e.path.span(),
                });
            }
            Some(env)
        }
    };
    let background = match &f.background {
        None => Background::FromEnvironment,
        Some(b) => match &b.environment {
            Some(env) => Background::Environment(read_map(env, "background.environment")?),
            None => Background::Color(ctx.non_negative3(&b.color, "background.color")?),
        },
    };
    let material_files = f
        .materials
        .values()
        .map(|m| m.get_ref().pack.as_ref().map(|p| folder.join(p.get_ref())))
        .collect();
    Ok(Scene {
        render,
        camera,
        material_names,
        materials,
        material_files,
        meshes,
        lights,
        ambient,
        environment,
        background,
    })
}

/// A material table as scene files write it (`kind = "spmm"`, `pack = ...`), read
/// from another TOML file: regression manifests name their material substitutions in
/// this form, so every kind the scene loader knows is known there too.
#[derive(Debug, serde::Deserialize)]
#[serde(transparent)]
pub struct MaterialTable(Spanned<file::MaterialFile>);

impl MaterialTable {
    /// The `kind` as written.
    pub fn kind(&self) -> &str {
        self.0.get_ref().kind.get_ref()
    }
    /// True if the table sets `uv_scale` (an `spmm` substitution without it keeps the
    /// tiling of the material it replaces).
    pub fn sets_uv_scale(&self) -> bool {
        self.0.get_ref().uv_scale.is_some()
    }
    /// Byte range of the table in the file it was read from.
    pub fn span(&self) -> Range<usize> {
        self.0.span()
    }
}

/// Builds the material of `table`, read from `file` (whose text is `text`, for line
/// numbers) under the key `table_key`; paths in it are relative to `folder`. Errors
/// name `file`, the line and `table_key.field`, as scene errors do.
pub fn material_from_table(
    file: &Path,
    text: &str,
    table_key: &str,
    table: &MaterialTable,
    folder: &Path,
) -> Result<Material, SceneError> {
    build_material(&Ctx { file, text }, table_key, &table.0, folder)
}

/// `table`: the key of the material's table (`materials.cloth`), for errors.
fn build_material(
    ctx: &Ctx,
    table: &str,
    m: &Spanned<file::MaterialFile>,
    folder: &Path,
) -> Result<Material, SceneError> {
    let span = m.span();
    let m = m.get_ref();
    let key = |k: &str| format!("{table}.{k}");
    // Keys given, and the keys each kind accepts: one list, so a new key cannot be
    // forgotten in one kind's check.
    let given = [
        ("model", m.model.is_some()),
        ("params", m.params.is_some()),
        ("albedo", m.albedo.is_some()),
        ("pack", m.pack.is_some()),
        ("uv_scale", m.uv_scale.is_some()),
        ("residual", m.residual.is_some()),
        ("npca", m.npca.is_some()),
        ("reflectance", m.reflectance.is_some()),
        ("path", m.path.is_some()),
        ("tabulate", m.tabulate.is_some()),
        ("tint", m.tint.is_some()),
    ];
    let accepted: &[&str] = match m.kind.get_ref().as_str() {
        "brdf" => &["model", "params", "albedo"],
        "spmm" => &["pack", "uv_scale", "residual", "npca"],
        "mirror" => &["reflectance"],
        "merl" => &["path", "tabulate", "tint"],
        "btf" => &["path", "uv_scale"],
        _ => &[],
    };
    if !accepted.is_empty()
        && let Some((k, _)) = given
            .iter()
            .find(|(k, present)| *present && !accepted.contains(k))
    {
        return ctx.err(
            &span,
            key(k),
            format!("does not belong to a `{}` material", m.kind.get_ref()),
        );
    }
    match m.kind.get_ref().as_str() {
        "brdf" => {
            let Some(model) = &m.model else {
                return ctx.err(&span, key("model"), "a `brdf` material needs `model`");
            };
            let model_id = BrdfModel::from_name(model.get_ref())
                .or_else(|e| ctx.err(&model.span(), key("model"), e.to_string()))?;
            let empty = BTreeMap::new();
            let (params, pspan) = match &m.params {
                Some(p) => (p.get_ref(), p.span()),
                None => (&empty, span.clone()),
            };
            let named: Vec<(&str, f64)> = params.iter().map(|(k, v)| (k.as_str(), *v)).collect();
            let brdf = AnalyticBrdf::new(model_id, &named)
                .or_else(|e| ctx.err(&pspan, key("params"), e.to_string()))?;
            let albedo = match &m.albedo {
                Some(a) => ctx.non_negative3(a, &key("albedo"))?,
                None => DVec3::ONE,
            };
            Ok(Material::Brdf { brdf, albedo })
        }
        "spmm" => {
            let Some(pack_path) = &m.pack else {
                return ctx.err(&span, key("pack"), "an `spmm` material needs `pack`");
            };
            let material = pack::read_pack(&folder.join(pack_path.get_ref()))
                .or_else(|e| ctx.err(&pack_path.span(), key("pack"), e.to_string()))?;
            let uv_scale = uv_scale_of(ctx, &key("uv_scale"), m.uv_scale.as_ref())?;
            let npca = match &m.npca {
                Some(n) if *n.get_ref() as usize > material.npca() => {
                    return ctx.err(
                        &n.span(),
                        key("npca"),
                        format!(
                            "{} exceeds the pack's N_PCA {}",
                            n.get_ref(),
                            material.npca()
                        ),
                    );
                }
                Some(n) => *n.get_ref() as usize,
                None => material.npca(),
            };
            Ok(Material::Spmm {
                material: Arc::new(material),
                uv_scale,
                residual: m.residual.unwrap_or(true),
                npca,
            })
        }
        "mirror" => {
            let reflectance = match &m.reflectance {
                Some(r) => ctx.non_negative3(r, &key("reflectance"))?,
                None => {
                    return ctx.err(
                        &span,
                        key("reflectance"),
                        "a `mirror` material needs `reflectance`",
                    );
                }
            };
            Ok(Material::Mirror { reflectance })
        }
        "merl" => {
            let brdf = match (&m.path, &m.tabulate) {
                (Some(path), None) => MerlBrdf::read(&folder.join(path.get_ref()))
                    .or_else(|e| ctx.err(&path.span(), key("path"), e.to_string()))?,
                (None, Some(t)) => {
                    let span = t.span();
                    let t = t.get_ref();
                    let model = BrdfModel::from_name(&t.model)
                        .or_else(|e| ctx.err(&span, key("tabulate.model"), e.to_string()))?;
                    let named: Vec<(&str, f64)> =
                        t.params.iter().map(|(k, v)| (k.as_str(), *v)).collect();
                    let analytic = AnalyticBrdf::new(model, &named)
                        .or_else(|e| ctx.err(&span, key("tabulate.params"), e.to_string()))?;
                    let albedo = DVec3::from_array(t.albedo.unwrap_or([1.0; 3]));
                    merl::tabulate(&analytic, albedo)
                        .or_else(|e| ctx.err(&span, key("tabulate.albedo"), e.to_string()))?
                }
                _ => {
                    return ctx.err(
                        &span,
                        key("path"),
                        "a `merl` material needs exactly one of `path` and `tabulate`",
                    );
                }
            };
            let tint = match &m.tint {
                Some(t) => ctx.non_negative3(t, &key("tint"))?,
                None => DVec3::ONE,
            };
            Ok(Material::Merl {
                brdf: Arc::new(brdf),
                tint,
            })
        }
        "btf" => {
            let Some(path) = &m.path else {
                return ctx.err(&span, key("path"), "a `btf` material needs `path`");
            };
            let btf = btf::file::read_btf(&folder.join(path.get_ref()))
                .or_else(|e| ctx.err(&path.span(), key("path"), e.to_string()))?;
            let table = BtfTable::new(&btf).or_else(|e| {
                ctx.err(
                    &path.span(),
                    key("path"),
                    format!("`{}`: {e}", path.get_ref().display()),
                )
            })?;
            Ok(Material::Btf {
                table: Arc::new(table),
                uv_scale: uv_scale_of(ctx, &key("uv_scale"), m.uv_scale.as_ref())?,
            })
        }
        other => ctx.err(
            &m.kind.span(),
            key("kind"),
            format!("`{other}`: materials are `brdf`, `spmm`, `mirror`, `merl` or `btf`"),
        ),
    }
}

/// A material's texture tiling (`uv_scale`, default 1 x 1): positive and finite.
fn uv_scale_of(
    ctx: &Ctx,
    key: &str,
    given: Option<&Spanned<[f64; 2]>>,
) -> Result<DVec2, SceneError> {
    match given {
        Some(s) => {
            let v = DVec2::from_array(*s.get_ref());
            if !(v.is_finite() && v.min_element() > 0.0) {
                return ctx.err(
                    &s.span(),
                    key.to_string(),
                    format!("{v} must be positive and finite"),
                );
            }
            Ok(v)
        }
        None => Ok(DVec2::ONE),
    }
}
