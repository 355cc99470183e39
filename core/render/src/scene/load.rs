//! Reading a scene file: the TOML as written (`file.rs`), then each table checked
//! into the `Scene`'s values, one function per table, every error naming the file, the
//! line and the key (`Ctx`).

use std::cell::RefCell;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DMat3, DVec3};
use toml::Spanned;

use super::material_file::build_material;
use super::{
    Ambient, Background, Camera, Environment, Light, MAX_IMAGE_SIDE, Material, Problem,
    RenderSettings, Scene, TriangleMesh, extent_problem, file, mesh,
};
use crate::{Device, ModeKind};
use meso_materials::btf::table::{BtfTable, MemoryBound};
use meso_materials::image::{self, Image};
use meso_materials::rng::Sampler;

/// A scene that cannot be loaded: the file, the line (when known), the key, and why.
#[derive(Debug, thiserror::Error)]
#[error("`{}`{}{}: {message}", file.display(), line.map(|l| format!(" line {l}")).unwrap_or_default(), key.as_ref().map(|k| format!(", `{k}`")).unwrap_or_default())]
pub struct SceneError {
    pub file: PathBuf,
    pub line: Option<usize>,
    pub key: Option<String>,
    pub message: String,
}

pub(super) struct Ctx<'a> {
    pub file: &'a Path,
    pub text: &'a str,
    /// How much of a `btf` material's values may be held in memory (the scene's
    /// bound, then each file's share of it).
    pub btf_memory: MemoryBound,
    /// The `.btf` files opened so far (by canonical path): materials naming one file
    /// share its table.
    pub btf_opened: &'a BtfOpened,
}

/// `.btf` tables opened while loading one scene, by canonical path.
pub(super) type BtfOpened = RefCell<Vec<(PathBuf, Arc<BtfTable>)>>;

impl Ctx<'_> {
    pub fn line_of(&self, span: &Range<usize>) -> Option<usize> {
        (span.end > 0 && span.start <= self.text.len())
            .then(|| self.text[..span.start].matches('\n').count() + 1)
    }
    pub fn err<T>(
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
    pub fn problem<T>(
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
    pub fn finite3(&self, v: &Spanned<[f64; 3]>, key: &str) -> Result<DVec3, SceneError> {
        let d = DVec3::from_array(*v.get_ref());
        if d.is_finite() {
            Ok(d)
        } else {
            self.err(&v.span(), key, format!("{:?} is not finite", v.get_ref()))
        }
    }
    pub fn non_negative3(&self, v: &Spanned<[f64; 3]>, key: &str) -> Result<DVec3, SceneError> {
        let d = self.finite3(v, key)?;
        if d.min_element() >= 0.0 {
            Ok(d)
        } else {
            self.err(&v.span(), key, format!("{d} has a negative component"))
        }
    }
}

/// Reads and checks a scene file; referenced files are relative to it. The `btf`
/// materials hold at most `BtfTable`'s default bound of values in memory, together.
pub fn load_scene(path: &Path) -> Result<Scene, SceneError> {
    load_scene_within(path, MemoryBound::default())
}

/// `load_scene`, the `btf` materials holding at most `btf_memory` of their values in
/// memory together, an equal share each (a larger one is read from disk as it is
/// shaded; `meso render --max-memory`).
pub fn load_scene_within(path: &Path, btf_memory: MemoryBound) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|e| SceneError {
        file: path.to_path_buf(),
        line: None,
        key: None,
        message: format!("cannot read: {e}"),
    })?;
    let opened = BtfOpened::default();
    let ctx = Ctx {
        file: path,
        text: &text,
        btf_memory,
        btf_opened: &opened,
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
    let render = render_settings(ctx, &f.render)?;
    let camera = camera(ctx, &f.camera)?;
    let (material_names, materials) = materials(ctx, &f, folder)?;
    let named = MaterialNames {
        ctx,
        names: &material_names,
    };
    let mut meshes = obj_meshes(ctx, &f.meshes, &named, folder)?;
    meshes.extend(quads(ctx, &f.quads, &named)?);
    let lights = lights(ctx, &f.lights)?;
    let ambient = ambient(ctx, f.ambient.as_ref())?;
    let environment = environment(ctx, f.environment.as_ref(), folder)?;
    let background = background(ctx, f.background.as_ref(), folder)?;
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

/// `[render]`: image size, frames, seed, depth, light samples, mode, device, sampler.
fn render_settings(ctx: &Ctx, r: &file::RenderFile) -> Result<RenderSettings, SceneError> {
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
    Ok(RenderSettings {
        width: *r.width.get_ref(),
        height: *r.height.get_ref(),
        frames: *r.frames.get_ref(),
        seed: r.seed,
        max_specular_depth: *r.max_specular_depth.get_ref(),
        mode,
        device,
        sampler,
        light_samples: *r.light_samples.get_ref(),
    })
}

/// `[camera]`, checked by `Camera::problem`.
fn camera(ctx: &Ctx, c: &file::CameraFile) -> Result<Camera, SceneError> {
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
    Ok(camera)
}

/// `[materials.NAME]` in the file's (sorted) order: their names and materials.
fn materials(
    ctx: &Ctx,
    f: &file::SceneFile,
    folder: &Path,
) -> Result<(Vec<String>, Vec<Material>), SceneError> {
    // The bound is the scene's: its `btf` files share it equally (materials naming
    // one file share its table), so together they hold at most the bound whatever
    // their number (one smaller than its share is held whole and leaves the rest of
    // its share unused).
    let mut files: Vec<PathBuf> = f
        .materials
        .values()
        .filter(|m| m.get_ref().kind.get_ref() == "btf")
        .filter_map(|m| m.get_ref().path.as_ref())
        .map(|p| btf_key(&folder.join(p.get_ref())))
        .collect();
    files.sort();
    files.dedup();
    let btfs = files.len().max(1) as u64;
    let ctx = &Ctx {
        btf_memory: MemoryBound {
            max_bytes: ctx.btf_memory.max_bytes / btfs,
            ..ctx.btf_memory
        },
        ..*ctx
    };
    let mut material_names = Vec::new();
    let mut materials = Vec::new();
    for (name, m) in &f.materials {
        material_names.push(name.clone());
        materials.push(build_material(
            ctx,
            &format!("materials.{name}"),
            m,
            folder,
        )?);
    }
    Ok((material_names, materials))
}

/// The materials by name, for the meshes and quads that name one.
struct MaterialNames<'a> {
    ctx: &'a Ctx<'a>,
    names: &'a [String],
}

impl MaterialNames<'_> {
    /// The index of the material `s` names, or an error at `key`.
    fn index(&self, s: &Spanned<String>, key: &str) -> Result<usize, SceneError> {
        match self.names.iter().position(|n| n == s.get_ref()) {
            Some(i) => Ok(i),
            None => self.ctx.err(
                &s.span(),
                key,
                format!(
                    "no material named `{}` (defined: {})",
                    s.get_ref(),
                    self.names.join(", ")
                ),
            ),
        }
    }
}

/// `[[mesh]]`: OBJ files placed in the world.
fn obj_meshes(
    ctx: &Ctx,
    files: &[file::MeshFile],
    named: &MaterialNames,
    folder: &Path,
) -> Result<Vec<TriangleMesh>, SceneError> {
    let mut meshes = Vec::new();
    for (i, m) in files.iter().enumerate() {
        let key = |k: &str| format!("mesh[{i}].{k}");
        let material = named.index(&m.material, &key("material"))?;
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
    Ok(meshes)
}

/// `[[quad]]`: parallelograms.
fn quads(
    ctx: &Ctx,
    files: &[file::QuadFile],
    named: &MaterialNames,
) -> Result<Vec<TriangleMesh>, SceneError> {
    let mut meshes = Vec::new();
    for (i, q) in files.iter().enumerate() {
        let key = |k: &str| format!("quad[{i}].{k}");
        let material = named.index(&q.material, &key("material"))?;
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
    Ok(meshes)
}

/// `[[light]]`: point and area lights, checked by `Light::problem`.
fn lights(ctx: &Ctx, files: &[Spanned<file::LightFile>]) -> Result<Vec<Light>, SceneError> {
    let mut lights = Vec::new();
    for (i, l) in files.iter().enumerate() {
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
    Ok(lights)
}

/// `[ambient]`, checked by `Ambient::problem`.
fn ambient(ctx: &Ctx, a: Option<&file::AmbientFile>) -> Result<Option<Ambient>, SceneError> {
    Ok(match a {
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
    })
}

/// An environment or background map: read, and checked as a lat-long map.
fn read_map(
    ctx: &Ctx,
    path: &Spanned<PathBuf>,
    key: &str,
    folder: &Path,
) -> Result<Arc<Image>, SceneError> {
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
}

/// `[environment]`, checked by `Environment::problem`.
fn environment(
    ctx: &Ctx,
    e: Option<&file::EnvironmentFile>,
    folder: &Path,
) -> Result<Option<Environment>, SceneError> {
    Ok(match e {
        None => None,
        Some(e) => {
            let env = Environment {
                map: read_map(ctx, &e.path, "environment.path", folder)?,
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
    })
}

/// `[background]`: a colour, a map, or (absent) what the environment shows.
fn background(
    ctx: &Ctx,
    b: Option<&file::BackgroundFile>,
    folder: &Path,
) -> Result<Background, SceneError> {
    Ok(match b {
        None => Background::FromEnvironment,
        Some(b) => match &b.environment {
            Some(env) => {
                Background::Environment(read_map(ctx, env, "background.environment", folder)?)
            }
            None => Background::Color(ctx.non_negative3(&b.color, "background.color")?),
        },
    })
}

/// The key a `.btf` file is shared by: its canonical path, or the path as written
/// when it cannot be resolved (opening it then reports why).
pub(super) fn btf_key(path: &Path) -> PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
}
