//! Scripted sessions (`meso-studio SCENE --run SCRIPT.toml`): a list of `[[edit]]`
//! tables, each with one key — `pack = "OPTIONS"` (the pack-edit language of `meso
//! pack edit`, applied to the edited pack as one edit), `scene = "COMMAND"` (a light,
//! the ambient term, the environment, the background, a material's parameter, the
//! camera; docs/app.md lists the commands) or `wait_ms = N`. Each edit becomes a
//! `SceneEdit` the caller applies as the panels do (undo step, journal, renderer).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{DVec2, DVec3};
use meso_materials::brdf::AnalyticBrdf;
use meso_render::SceneEdit;
use meso_render::scene::{Ambient, Background, Light, Material};

use crate::document::Document;
use crate::pack_edits::PackEdits;

/// One scripted edit.
#[derive(Clone, Debug)]
pub enum ScriptEdit {
    Pack(Box<PackEdits>),
    Scene(String),
    Wait(Duration),
}

/// A script as read: its edits and the folder relative paths in it start from.
#[derive(Clone, Debug)]
pub struct Script {
    pub path: PathBuf,
    pub edits: Vec<ScriptEdit>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    edit: Vec<toml::Table>,
}

impl Script {
    /// Reads a script; a bad edit is named by its number (1-based) and key.
    pub fn read(path: &Path) -> Result<Script, String> {
        let text =
            std::fs::read_to_string(path).map_err(|e| format!("`{}`: {e}", path.display()))?;
        Self::parse(path, &text)
    }

    pub fn parse(path: &Path, text: &str) -> Result<Script, String> {
        let named = |e: String| format!("`{}`: {e}", path.display());
        let file: File = toml::from_str(text).map_err(|e| named(e.to_string()))?;
        let mut edits = Vec::new();
        for (i, table) in file.edit.iter().enumerate() {
            let at = |e: String| named(format!("edit {}: {e}", i + 1));
            if table.len() != 1 {
                return Err(at(format!(
                    "has {} keys; each [[edit]] has exactly one of pack, scene, wait_ms",
                    table.len()
                )));
            }
            let (key, value) = table.iter().next().expect("one key");
            edits.push(match (key.as_str(), value) {
                ("pack", toml::Value::String(s)) => ScriptEdit::Pack(Box::new(
                    PackEdits::parse(s).map_err(|e| at(format!("pack: {e}")))?,
                )),
                ("scene", toml::Value::String(s)) => {
                    // Checked against the command grammar now, against the scene later.
                    check_command(s).map_err(|e| at(format!("scene: {e}")))?;
                    ScriptEdit::Scene(s.clone())
                }
                ("wait_ms", toml::Value::Integer(n)) if *n >= 0 => {
                    ScriptEdit::Wait(Duration::from_millis(*n as u64))
                }
                ("pack" | "scene", _) => return Err(at(format!("`{key}` must be a string"))),
                ("wait_ms", _) => return Err(at("`wait_ms` must be a whole number >= 0".into())),
                (k, _) => {
                    return Err(at(format!(
                        "unknown key `{k}` (expected pack, scene or wait_ms)"
                    )));
                }
            });
        }
        Ok(Script {
            path: path.to_path_buf(),
            edits,
        })
    }

    fn dir(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new("."))
    }

    /// Edit `index` as the edit it makes on `doc` now (`None` for a wait).
    pub fn edit_on(&self, index: usize, doc: &Document) -> Result<Option<SceneEdit>, String> {
        let at = |e: String| format!("`{}`: edit {}: {e}", self.path.display(), index + 1);
        match &self.edits[index] {
            ScriptEdit::Wait(_) => Ok(None),
            ScriptEdit::Pack(p) => {
                let pack = doc
                    .pack
                    .as_ref()
                    .ok_or_else(|| at("the scene has no pack to edit".into()))?;
                let Material::Spmm {
                    material,
                    uv_scale,
                    residual,
                    npca,
                } = &doc.scene.materials[pack.material]
                else {
                    return Err(at("the edited material is not an SPMM pack".into()));
                };
                let edited = p.apply(material, self.dir()).map_err(at)?;
                Ok(Some(SceneEdit::Material {
                    index: pack.material,
                    material: Material::Spmm {
                        material: Arc::new(edited.material),
                        uv_scale: *uv_scale,
                        residual: *residual,
                        npca: *npca,
                    },
                }))
            }
            ScriptEdit::Scene(command) => scene_edit(command, doc).map(Some).map_err(at),
        }
    }
}

/// Walks a script in time: the edits due now, then the wait before the next.
pub struct Runner {
    pub script: Script,
    next: usize,
    resume_at: Option<Instant>,
}

impl Runner {
    pub fn new(script: Script) -> Self {
        Self {
            script,
            next: 0,
            resume_at: None,
        }
    }

    pub fn done(&self) -> bool {
        self.next >= self.script.edits.len()
    }

    /// The indices of the edits due at `now` (stopping at a wait, which starts).
    pub fn due(&mut self, now: Instant) -> Vec<usize> {
        self.due_at_most(now, usize::MAX)
    }

    /// `due`, at most `n` of them (the rest stay due).
    pub fn due_at_most(&mut self, now: Instant, n: usize) -> Vec<usize> {
        if self.resume_at.is_some_and(|t| now < t) {
            return Vec::new();
        }
        self.resume_at = None;
        let mut out = Vec::new();
        while out.len() < n
            && let Some(e) = self.script.edits.get(self.next)
        {
            self.next += 1;
            match e {
                ScriptEdit::Wait(d) => {
                    self.resume_at = Some(now + *d);
                    break;
                }
                _ => out.push(self.next - 1),
            }
        }
        out
    }

    /// How long until the next edit is due (`None` when none is left).
    pub fn wait(&self, now: Instant) -> Option<Duration> {
        if self.done() && self.resume_at.is_none() {
            return None;
        }
        Some(
            self.resume_at
                .map_or(Duration::ZERO, |t| t.saturating_duration_since(now)),
        )
    }
}

// ---- scene commands ----

/// `name=value` pairs after a command's words.
struct Args<'a> {
    words: Vec<&'a str>,
    pairs: Vec<(&'a str, &'a str)>,
}

fn split(command: &str) -> Result<Args<'_>, String> {
    let mut words = Vec::new();
    let mut pairs = Vec::new();
    for token in command.split_whitespace() {
        match token.split_once('=') {
            Some((k, v)) => pairs.push((k, v)),
            None if pairs.is_empty() => words.push(token),
            None => {
                return Err(format!(
                    "`{token}`: expected NAME=VALUE after the first pair"
                ));
            }
        }
    }
    if words.is_empty() {
        return Err("an empty command".into());
    }
    Ok(Args { words, pairs })
}

fn num(key: &str, v: &str) -> Result<f64, String> {
    v.trim()
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .ok_or_else(|| format!("{key}=`{v}`: expected a finite number"))
}

fn vec3(key: &str, v: &str) -> Result<DVec3, String> {
    let parts: Vec<&str> = v.split(',').collect();
    match parts.as_slice() {
        [x] => Ok(DVec3::splat(num(key, x)?)),
        [x, y, z] => Ok(DVec3::new(num(key, x)?, num(key, y)?, num(key, z)?)),
        _ => Err(format!(
            "{key}=`{v}`: expected one number or three separated by commas"
        )),
    }
}

fn index(word: Option<&&str>, what: &str) -> Result<usize, String> {
    word.and_then(|w| w.parse().ok())
        .ok_or_else(|| format!("`{what}` needs an index: `{what} N ...`"))
}

const COMMANDS: &str = "light, add_light, remove_light, ambient, environment, background, light_samples, material, camera";

fn check_command(command: &str) -> Result<(), String> {
    let a = split(command)?;
    if COMMANDS.split(", ").any(|c| c == a.words[0]) {
        Ok(())
    } else {
        Err(format!(
            "unknown command `{}` (expected one of {COMMANDS})",
            a.words[0]
        ))
    }
}

/// The edit a scene command makes on `doc`'s scene now.
pub fn scene_edit(command: &str, doc: &Document) -> Result<SceneEdit, String> {
    let a = split(command)?;
    let scene = &doc.scene;
    let unknown = |k: &str, what: &str| format!("`{k}` is not a key of {what}");
    match a.words[0] {
        "light" => {
            let i = index(a.words.get(1), "light")?;
            let mut light = *scene.lights.get(i).ok_or_else(|| {
                format!(
                    "light {i} does not exist (the scene has {})",
                    scene.lights.len()
                )
            })?;
            for (k, v) in &a.pairs {
                match (&mut light, *k) {
                    (Light::Point { position, .. }, "position") => *position = vec3(k, v)?,
                    (Light::Point { intensity, .. }, "intensity") => *intensity = vec3(k, v)?,
                    (Light::Area { radiance, .. }, "radiance") => *radiance = vec3(k, v)?,
                    (Light::Area { corner, .. }, "corner") => *corner = vec3(k, v)?,
                    (Light::Point { position: p, .. } | Light::Area { corner: p, .. }, "move") => {
                        *p += vec3(k, v)?
                    }
                    _ => return Err(unknown(k, &format!("light {i} ({})", light_kind(&light)))),
                }
            }
            Ok(SceneEdit::Light { index: i, light })
        }
        "add_light" => {
            let mut position = DVec3::new(0.0, 2.0, 0.0);
            let mut intensity = DVec3::ONE;
            for (k, v) in &a.pairs {
                match *k {
                    "position" => position = vec3(k, v)?,
                    "intensity" => intensity = vec3(k, v)?,
                    _ => return Err(unknown(k, "add_light (a point light)")),
                }
            }
            Ok(SceneEdit::AddLight(Light::Point {
                position,
                intensity,
            }))
        }
        "remove_light" => Ok(SceneEdit::RemoveLight(index(
            a.words.get(1),
            "remove_light",
        )?)),
        "ambient" => {
            if a.words.get(1) == Some(&"off") {
                return Ok(SceneEdit::Ambient(None));
            }
            let mut ambient = scene.ambient.unwrap_or(Ambient {
                radiance: DVec3::splat(0.1),
                radius: f64::INFINITY,
            });
            for (k, v) in &a.pairs {
                match *k {
                    "radiance" => ambient.radiance = vec3(k, v)?,
                    "radius" => ambient.radius = num(k, v)?,
                    _ => return Err(unknown(k, "ambient")),
                }
            }
            Ok(SceneEdit::Ambient(Some(ambient)))
        }
        "environment" => {
            if a.words.get(1) == Some(&"off") {
                return Ok(SceneEdit::Environment(None));
            }
            let mut env = scene
                .environment
                .clone()
                .ok_or("the scene has no environment to change")?;
            for (k, v) in &a.pairs {
                match *k {
                    "strength" => env.strength = num(k, v)?,
                    "rotation" => env.rotate_y_deg = num(k, v)?,
                    _ => return Err(unknown(k, "environment")),
                }
            }
            Ok(SceneEdit::Environment(Some(env)))
        }
        "background" => match a.pairs.as_slice() {
            [("color", v)] => Ok(SceneEdit::Background(Background::Color(vec3("color", v)?))),
            _ if a.words.get(1) == Some(&"environment") => {
                Ok(SceneEdit::Background(Background::FromEnvironment))
            }
            _ => Err("background takes `color=R,G,B` or `environment`".into()),
        },
        "light_samples" => {
            let n = a
                .words
                .get(1)
                .and_then(|w| w.parse().ok())
                .ok_or("light_samples needs a count")?;
            Ok(SceneEdit::LightSamples(n))
        }
        "material" => {
            let i = index(a.words.get(1), "material")?;
            let mut m = scene.materials.get(i).cloned().ok_or_else(|| {
                format!(
                    "material {i} does not exist (the scene has {})",
                    scene.materials.len()
                )
            })?;
            for (k, v) in &a.pairs {
                material_key(&mut m, k, v).map_err(|e| format!("material {i}: {e}"))?;
            }
            Ok(SceneEdit::Material {
                index: i,
                material: m,
            })
        }
        "camera" => {
            let mut c = scene.camera;
            for (k, v) in &a.pairs {
                match *k {
                    "position" => c.position = vec3(k, v)?,
                    "look_at" => c.look_at = vec3(k, v)?,
                    "fov" => c.fov_y_deg = num(k, v)?,
                    _ => return Err(unknown(k, "camera")),
                }
            }
            Ok(SceneEdit::Camera(c))
        }
        w => Err(format!(
            "unknown command `{w}` (expected one of {COMMANDS})"
        )),
    }
}

fn light_kind(l: &Light) -> &'static str {
    match l {
        Light::Point { .. } => "a point light: position, intensity, move",
        Light::Area { .. } => "an area light: radiance, corner, move",
    }
}

fn material_key(m: &mut Material, k: &str, v: &str) -> Result<(), String> {
    match (m, k) {
        (Material::Brdf { albedo, .. }, "albedo") => *albedo = vec3(k, v)?,
        (Material::Brdf { brdf, .. }, name) => {
            let model = brdf.model();
            let mut values: Vec<(&str, f64)> = model
                .param_specs()
                .iter()
                .map(|s| s.name)
                .zip(brdf.param_values())
                .collect();
            let slot = values.iter_mut().find(|(n, _)| *n == name).ok_or_else(|| {
                format!("`{name}` is not albedo or a parameter of {}", model.name())
            })?;
            slot.1 = num(k, v)?;
            *brdf = AnalyticBrdf::new(model, &values).map_err(|e| e.to_string())?;
        }
        (Material::Spmm { uv_scale, .. } | Material::Btf { uv_scale, .. }, "uv_scale") => {
            let p: Vec<f64> = v.split(',').map(|x| num(k, x)).collect::<Result<_, _>>()?;
            *uv_scale = match p.as_slice() {
                [s] => DVec2::splat(*s),
                [u, w] => DVec2::new(*u, *w),
                _ => return Err(format!("uv_scale=`{v}`: expected one or two numbers")),
            };
        }
        (Material::Spmm { residual, .. }, "residual") => {
            *residual = match v {
                "on" | "true" => true,
                "off" | "false" => false,
                _ => return Err(format!("residual=`{v}`: expected on or off")),
            }
        }
        (Material::Merl { tint, .. }, "tint") => *tint = vec3(k, v)?,
        (Material::Mirror { reflectance }, "reflectance") => *reflectance = vec3(k, v)?,
        (m, k) => {
            return Err(format!(
                "`{k}` is not a key of a {} material",
                m.kind_name()
            ));
        }
    }
    Ok(())
}
