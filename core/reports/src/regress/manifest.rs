//! The regression manifest (docs/regress.md): a TOML file read with serde and
//! `deny_unknown_fields`, expanded into the list of cases it names: scenes x material
//! substitutions x modes x devices for each `[[matrix]]`, plus the explicit `[[case]]`s.
//! Every error names the manifest, the line and the key. Scenes and substituted
//! materials are only named here; `run` loads the ones the selected cases need.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use toml::Spanned;

use meso_render::scene::{self, Material, MaterialTable, RenderSettings};
use meso_render::{Device, ModeKind};

use super::case::{Case, NO_SUBSTITUTION, Tolerance, case_name, check_case_name, check_key};

/// A manifest that cannot be read: the file, the line (when known), the key, and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{}`{}{}: {message}", file.display(), line.map(|l| format!(" line {l}")).unwrap_or_default(), key.as_ref().map(|k| format!(", `{k}`")).unwrap_or_default())]
pub struct ManifestError {
    pub file: PathBuf,
    pub line: Option<usize>,
    pub key: Option<String>,
    pub message: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestFile {
    version: Spanned<u32>,
    goldens: Spanned<PathBuf>,
    #[serde(default)]
    defaults: SettingsFile,
    #[serde(default)]
    scenes: BTreeMap<Spanned<String>, Spanned<SceneFile>>,
    #[serde(default)]
    materials: BTreeMap<Spanned<String>, MaterialTable>,
    #[serde(default, rename = "matrix")]
    matrices: Vec<Spanned<MatrixFile>>,
    #[serde(default, rename = "case")]
    cases: Vec<Spanned<CaseFile>>,
}

/// Size, frames, seed and tolerances: `[defaults]`, and overrides in a matrix or case.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SettingsFile {
    width: Option<Spanned<u32>>,
    height: Option<Spanned<u32>>,
    frames: Option<Spanned<u32>>,
    seed: Option<u64>,
    max_relative_rmse: Option<Spanned<f64>>,
    min_mssim: Option<Spanned<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    path: Spanned<PathBuf>,
    /// The scene's material that substitutions replace.
    replace: Option<Spanned<String>>,
}

// serde's `flatten` does not combine with `deny_unknown_fields`: the settings are
// spelt out in each table that takes them.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MatrixFile {
    scenes: Spanned<Vec<String>>,
    materials: Option<Spanned<Vec<String>>>,
    modes: Spanned<Vec<String>>,
    devices: Option<Spanned<Vec<String>>>,
    width: Option<Spanned<u32>>,
    height: Option<Spanned<u32>>,
    frames: Option<Spanned<u32>>,
    seed: Option<u64>,
    max_relative_rmse: Option<Spanned<f64>>,
    min_mssim: Option<Spanned<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CaseFile {
    name: Option<Spanned<String>>,
    scene: Spanned<String>,
    material: Option<Spanned<String>>,
    replace: Option<Spanned<String>>,
    mode: Spanned<String>,
    device: Option<Spanned<String>>,
    width: Option<Spanned<u32>>,
    height: Option<Spanned<u32>>,
    frames: Option<Spanned<u32>>,
    seed: Option<u64>,
    max_relative_rmse: Option<Spanned<f64>>,
    min_mssim: Option<Spanned<f64>>,
}

/// A scene the manifest names.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRef {
    pub path: PathBuf,
    pub replace: Option<String>,
    /// Line of `path` and of `replace`, for errors found when the scene is loaded.
    pub path_line: Option<usize>,
    pub replace_line: Option<usize>,
}

/// A checked manifest: where the goldens live and every case, in manifest order.
#[derive(Debug)]
pub struct Manifest {
    pub path: PathBuf,
    /// The folder of golden EXRs (relative paths are resolved against the manifest).
    pub goldens: PathBuf,
    pub scenes: BTreeMap<String, SceneRef>,
    pub cases: Vec<Case>,
    /// FNV-1a of the manifest's bytes, in hex: shard reports of one run carry the same.
    pub digest: String,
    text: String,
    materials: BTreeMap<String, MaterialTable>,
}

impl Manifest {
    /// The folder paths in the manifest are relative to.
    pub fn folder(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new("."))
    }

    /// Builds the substituted material `name` (a key of `[materials]`).
    pub fn material(&self, name: &str) -> Result<(Material, bool), ManifestError> {
        let table = self.materials.get(name).ok_or_else(|| ManifestError {
            file: self.path.clone(),
            line: None,
            key: Some(format!("materials.{name}")),
            message: "no such material".into(),
        })?;
        let key = format!("materials.{name}");
        scene::material_from_table(&self.path, &self.text, &key, table, self.folder())
            .map(|m| (m, table.sets_uv_scale()))
            .map_err(|e| ManifestError {
                file: e.file,
                line: e.line,
                key: e.key,
                message: e.message,
            })
    }

    /// The line of `[materials.NAME]`, for messages.
    pub fn material_line(&self, name: &str) -> Option<usize> {
        self.materials
            .get(name)
            .and_then(|t| line_of(&self.text, &t.span()))
    }
}

fn line_of(text: &str, span: &Range<usize>) -> Option<usize> {
    (span.end > 0 && span.start <= text.len()).then(|| text[..span.start].matches('\n').count() + 1)
}

struct Ctx<'a> {
    file: &'a Path,
    text: &'a str,
}

impl Ctx<'_> {
    fn err<T>(
        &self,
        span: &Range<usize>,
        key: impl Into<String>,
        message: impl Into<String>,
    ) -> Result<T, ManifestError> {
        Err(ManifestError {
            file: self.file.to_path_buf(),
            line: line_of(self.text, span),
            key: Some(key.into()),
            message: message.into(),
        })
    }
    fn line(&self, span: &Range<usize>) -> Option<usize> {
        line_of(self.text, span)
    }
}

/// Reads and checks a manifest and expands its cases.
pub fn load_manifest(path: &Path) -> Result<Manifest, ManifestError> {
    let text = std::fs::read_to_string(path).map_err(|e| ManifestError {
        file: path.to_path_buf(),
        line: None,
        key: None,
        message: format!("cannot read: {e}"),
    })?;
    parse_manifest(path, text)
}

/// Checks a manifest's `text` as if read from `path`.
pub fn parse_manifest(path: &Path, text: String) -> Result<Manifest, ManifestError> {
    let parsed = parse_toml(path, &text)?;
    let ctx = Ctx {
        file: path,
        text: &text,
    };
    if *parsed.version.get_ref() != 1 {
        return ctx.err(
            &parsed.version.span(),
            "version",
            format!("{}: only version 1 exists", parsed.version.get_ref()),
        );
    }
    let folder = path.parent().unwrap_or(Path::new("."));
    let goldens = folder.join(parsed.goldens.get_ref());
    let scenes = read_scenes(&ctx, &parsed.scenes, folder)?;
    let materials = read_materials(&ctx, parsed.materials)?;

    let defaults = Settings::read(
        &ctx,
        "defaults",
        &parsed.defaults.as_fields(),
        None,
        &(0..0),
    )?;
    let mut cases = Cases::default();
    for (i, m) in parsed.matrices.iter().enumerate() {
        expand_matrix(&ctx, i, m, &defaults, &scenes, &materials, &mut cases)?;
    }
    for (i, c) in parsed.cases.iter().enumerate() {
        let case = single_case(&ctx, i, c, &defaults, &scenes, &materials)?;
        cases.push(&ctx, case, &c.span())?;
    }
    let cases = cases.cases;
    if cases.is_empty() {
        return Err(ManifestError {
            file: path.to_path_buf(),
            line: None,
            key: None,
            message: "names no case: add a [[matrix]] or a [[case]]".into(),
        });
    }
    let digest = format!("{:016x}", super::shard::fnv1a64(text.as_bytes()));
    Ok(Manifest {
        path: path.to_path_buf(),
        goldens,
        scenes,
        cases,
        digest,
        text,
        materials,
    })
}

/// The TOML as written; a syntax or type error names its line and, where it can, the key.
fn parse_toml(path: &Path, text: &str) -> Result<ManifestFile, ManifestError> {
    toml::from_str(text).map_err(|e| {
        let line = e.span().and_then(|s| line_of(text, &s));
        // toml names the key of an unknown or missing field in its message but not of
        // a wrong type: take it from the offending line (`key = value`).
        let key = line
            .and_then(|l| text.lines().nth(l - 1))
            .and_then(|l| l.split_once('='))
            .map(|(k, _)| k.trim().to_string())
            .filter(|k| !k.is_empty() && !k.starts_with('['));
        ManifestError {
            file: path.to_path_buf(),
            line,
            key,
            message: e.message().trim().to_string(),
        }
    })
}

/// `[scenes]`: each name checked, its paths resolved against the manifest's `folder`.
fn read_scenes(
    ctx: &Ctx,
    parsed: &BTreeMap<Spanned<String>, Spanned<SceneFile>>,
    folder: &Path,
) -> Result<BTreeMap<String, SceneRef>, ManifestError> {
    let mut scenes = BTreeMap::new();
    for (name, s) in parsed {
        if let Some(p) = check_key(name.get_ref()) {
            return ctx.err(&name.span(), format!("scenes.{}", name.get_ref()), p);
        }
        let s = s.get_ref();
        scenes.insert(
            name.get_ref().clone(),
            SceneRef {
                path: folder.join(s.path.get_ref()),
                replace: s.replace.as_ref().map(|r| r.get_ref().clone()),
                path_line: ctx.line(&s.path.span()),
                replace_line: s.replace.as_ref().and_then(|r| ctx.line(&r.span())),
            },
        );
    }
    Ok(scenes)
}

/// `[materials]`: the substitutions by name (checked when a case uses them).
fn read_materials(
    ctx: &Ctx,
    parsed: BTreeMap<Spanned<String>, MaterialTable>,
) -> Result<BTreeMap<String, MaterialTable>, ManifestError> {
    let mut materials = BTreeMap::new();
    for (name, m) in parsed {
        let key = format!("materials.{}", name.get_ref());
        if let Some(p) = check_key(name.get_ref()) {
            return ctx.err(&name.span(), key, p);
        }
        if name.get_ref() == NO_SUBSTITUTION {
            return ctx.err(
                &name.span(),
                key,
                format!("`{NO_SUBSTITUTION}` is reserved: it names a scene's own material in `materials = [...]`"),
            );
        }
        materials.insert(name.into_inner(), m);
    }
    Ok(materials)
}

/// The cases so far, in manifest order, and which table made each name: names must
/// be unique.
#[derive(Default)]
struct Cases {
    cases: Vec<Case>,
    origin_of: BTreeMap<String, String>,
}

impl Cases {
    fn push(&mut self, ctx: &Ctx, case: Case, span: &Range<usize>) -> Result<(), ManifestError> {
        if let Some(first) = self.origin_of.get(&case.name) {
            return ctx.err(
                span,
                case.origin.clone(),
                format!(
                    "case `{}` is also made by {first}: case names must be unique",
                    case.name
                ),
            );
        }
        self.origin_of
            .insert(case.name.clone(), case.origin.clone());
        self.cases.push(case);
        Ok(())
    }
}

/// `[[matrix]]` number `i`: its scenes x material substitutions x modes x devices, each
/// case pushed to `out` as it is made.
fn expand_matrix(
    ctx: &Ctx,
    i: usize,
    m: &Spanned<MatrixFile>,
    defaults: &Settings,
    scenes: &BTreeMap<String, SceneRef>,
    materials: &BTreeMap<String, MaterialTable>,
    out: &mut Cases,
) -> Result<(), ManifestError> {
    let span = m.span();
    let m = m.get_ref();
    let table = format!("matrix[{i}]");
    let key = |k: &str| format!("{table}.{k}");
    let settings = Settings::read(ctx, &table, &m.as_fields(), Some(defaults), &span)?;
    let scene_names = names(ctx, &m.scenes, &key("scenes"), |n| {
        known(n, scenes.keys(), "scene")
    })?;
    let no_sub = [NO_SUBSTITUTION.to_string()];
    let material_names: Vec<String> = match &m.materials {
        Some(list) => names(ctx, list, &key("materials"), |n| {
            if n == NO_SUBSTITUTION {
                None
            } else {
                known(n, materials.keys(), "material")
            }
        })?,
        None => no_sub.to_vec(),
    };
    let modes = names(ctx, &m.modes, &key("modes"), |n| {
        ModeKind::from_name(n)
            .is_none()
            .then(|| format!("`{n}`: modes are spmm, biscale, adaptive"))
    })?;
    let devices = match &m.devices {
        Some(list) => names(ctx, list, &key("devices"), |n| {
            Device::from_name(n)
                .is_none()
                .then(|| format!("`{n}`: devices are cpu, gpu"))
        })?,
        None => vec!["cpu".to_string()],
    };
    for scene_name in &scene_names {
        for material in &material_names {
            let substitution = (material != NO_SUBSTITUTION).then(|| material.clone());
            let replace = scenes[scene_name].replace.clone();
            if substitution.is_some() && replace.is_none() {
                return ctx.err(
                    &m.materials.as_ref().map_or(span.clone(), |l| l.span()),
                    key("materials"),
                    format!(
                        "scene `{scene_name}` has no `replace` (the material substitutions replace), so `{material}` cannot be substituted in it"
                    ),
                );
            }
            for mode in &modes {
                for device in &devices {
                    let mode = ModeKind::from_name(mode).expect("checked above");
                    let device = Device::from_name(device).expect("checked above");
                    let case = Case {
                        name: case_name(scene_name, substitution.as_deref(), mode, device),
                        scene: scene_name.clone(),
                        material: substitution.clone(),
                        replace: substitution.as_ref().and(replace.clone()),
                        mode,
                        device,
                        width: settings.width,
                        height: settings.height,
                        frames: settings.frames,
                        seed: settings.seed,
                        tolerance: settings.tolerance,
                        origin: format!("{table} (line {})", ctx.line(&span).unwrap_or(0)),
                    };
                    out.push(ctx, case, &span)?;
                }
            }
        }
    }
    Ok(())
}

/// `[[case]]` number `i`, checked.
fn single_case(
    ctx: &Ctx,
    i: usize,
    c: &Spanned<CaseFile>,
    defaults: &Settings,
    scenes: &BTreeMap<String, SceneRef>,
    materials: &BTreeMap<String, MaterialTable>,
) -> Result<Case, ManifestError> {
    let span = c.span();
    let c = c.get_ref();
    let table = format!("case[{i}]");
    let key = |k: &str| format!("{table}.{k}");
    let settings = Settings::read(ctx, &table, &c.as_fields(), Some(defaults), &span)?;
    let scene_name = c.scene.get_ref();
    if let Some(p) = known(scene_name, scenes.keys(), "scene") {
        return ctx.err(&c.scene.span(), key("scene"), p);
    }
    let material = match &c.material {
        Some(m) if m.get_ref() != NO_SUBSTITUTION => {
            if let Some(p) = known(m.get_ref(), materials.keys(), "material") {
                return ctx.err(&m.span(), key("material"), p);
            }
            Some(m.get_ref().clone())
        }
        _ => None,
    };
    let replace = match (&material, &c.replace) {
        (None, Some(r)) => {
            return ctx.err(
                &r.span(),
                key("replace"),
                "a case without `material` replaces nothing",
            );
        }
        (Some(_), Some(r)) => Some(r.get_ref().clone()),
        (Some(m), None) => match &scenes[scene_name].replace {
            Some(r) => Some(r.clone()),
            None => {
                return ctx.err(
                    &span,
                    key("replace"),
                    format!(
                        "scene `{scene_name}` has no `replace`, so say which of its materials `{m}` replaces"
                    ),
                );
            }
        },
        (None, None) => None,
    };
    let Some(mode) = ModeKind::from_name(c.mode.get_ref()) else {
        return ctx.err(
            &c.mode.span(),
            key("mode"),
            format!("`{}`: modes are spmm, biscale, adaptive", c.mode.get_ref()),
        );
    };
    let device = match &c.device {
        None => Device::Cpu,
        Some(d) => match Device::from_name(d.get_ref()) {
            Some(d) => d,
            None => {
                return ctx.err(
                    &d.span(),
                    key("device"),
                    format!("`{}`: devices are cpu, gpu", d.get_ref()),
                );
            }
        },
    };
    let name = match &c.name {
        Some(n) => {
            if let Some(p) = check_case_name(n.get_ref()) {
                return ctx.err(&n.span(), key("name"), p);
            }
            n.get_ref().clone()
        }
        None => case_name(scene_name, material.as_deref(), mode, device),
    };
    Ok(Case {
        name,
        scene: scene_name.clone(),
        material,
        replace,
        mode,
        device,
        width: settings.width,
        height: settings.height,
        frames: settings.frames,
        seed: settings.seed,
        tolerance: settings.tolerance,
        origin: format!("{table} (line {})", ctx.line(&span).unwrap_or(0)),
    })
}

/// `None` if `name` is among `known`; otherwise the message.
fn known<'a>(
    name: &str,
    mut known: impl Iterator<Item = &'a String> + Clone,
    what: &str,
) -> Option<String> {
    if known.clone().any(|k| k == name) {
        None
    } else {
        let list: Vec<&str> = known.by_ref().map(|s| s.as_str()).collect();
        Some(format!(
            "no {what} `{name}` in the manifest (defined: {})",
            if list.is_empty() {
                "none".to_string()
            } else {
                list.join(", ")
            }
        ))
    }
}

/// The names of a list, each checked by `problem`; an empty list or a repeated name is
/// an error too.
fn names(
    ctx: &Ctx,
    list: &Spanned<Vec<String>>,
    key: &str,
    problem: impl Fn(&str) -> Option<String>,
) -> Result<Vec<String>, ManifestError> {
    if list.get_ref().is_empty() {
        return ctx.err(&list.span(), key, "is empty");
    }
    let mut seen = Vec::new();
    for n in list.get_ref() {
        if let Some(p) = problem(n) {
            return ctx.err(&list.span(), key, p);
        }
        if seen.contains(n) {
            return ctx.err(&list.span(), key, format!("names `{n}` twice"));
        }
        seen.push(n.clone());
    }
    Ok(seen)
}

/// The settings fields of any table, borrowed.
struct Fields<'a> {
    width: &'a Option<Spanned<u32>>,
    height: &'a Option<Spanned<u32>>,
    frames: &'a Option<Spanned<u32>>,
    seed: Option<u64>,
    max_relative_rmse: &'a Option<Spanned<f64>>,
    min_mssim: &'a Option<Spanned<f64>>,
}

macro_rules! fields_of {
    ($t:ty) => {
        impl $t {
            fn as_fields(&self) -> Fields<'_> {
                Fields {
                    width: &self.width,
                    height: &self.height,
                    frames: &self.frames,
                    seed: self.seed,
                    max_relative_rmse: &self.max_relative_rmse,
                    min_mssim: &self.min_mssim,
                }
            }
        }
    };
}
fields_of!(SettingsFile);
fields_of!(MatrixFile);
fields_of!(CaseFile);

/// Checked settings; `None` size or frames means the scene's own.
#[derive(Clone, Copy, Debug)]
struct Settings {
    width: Option<u32>,
    height: Option<u32>,
    frames: Option<u32>,
    seed: Option<u64>,
    tolerance: Tolerance,
}

impl Settings {
    /// Reads `f` over `defaults`; a case (not `[defaults]`) must end with a tolerance.
    fn read(
        ctx: &Ctx,
        table: &str,
        f: &Fields,
        defaults: Option<&Settings>,
        span: &Range<usize>,
    ) -> Result<Settings, ManifestError> {
        let key = |k: &str| format!("{table}.{k}");
        let get = |v: &Option<Spanned<u32>>| v.as_ref().map(|s| *s.get_ref());
        let width = get(f.width).or(defaults.and_then(|d| d.width));
        let height = get(f.height).or(defaults.and_then(|d| d.height));
        for (v, k) in [(f.width, "width"), (f.height, "height")] {
            if let Some(v) = v
                && let Some(p) = RenderSettings::size_problem(*v.get_ref(), 1)
            {
                return ctx.err(&v.span(), key(k), p);
            }
        }
        if let Some(fr) = f.frames
            && *fr.get_ref() == 0
        {
            return ctx.err(&fr.span(), key("frames"), "must be at least 1");
        }
        if let Some(r) = f.max_relative_rmse {
            let v = *r.get_ref();
            if !(v.is_finite() && v >= 0.0) {
                return ctx.err(
                    &r.span(),
                    key("max_relative_rmse"),
                    format!("{v} must be finite and non-negative"),
                );
            }
        }
        if let Some(s) = f.min_mssim {
            let v = *s.get_ref();
            if !(-1.0..=1.0).contains(&v) {
                return ctx.err(
                    &s.span(),
                    key("min_mssim"),
                    format!("{v} is outside [-1, 1] (the range of MSSIM)"),
                );
            }
        }
        let tolerance = Tolerance {
            max_relative_rmse: f
                .max_relative_rmse
                .as_ref()
                .map(|v| *v.get_ref())
                .or(defaults.and_then(|d| d.tolerance.max_relative_rmse)),
            min_mssim: f
                .min_mssim
                .as_ref()
                .map(|v| *v.get_ref())
                .or(defaults.and_then(|d| d.tolerance.min_mssim)),
        };
        if defaults.is_some()
            && tolerance.max_relative_rmse.is_none()
            && tolerance.min_mssim.is_none()
        {
            return ctx.err(
                span,
                table,
                "has no tolerance: give `max_relative_rmse` and/or `min_mssim` here or in [defaults]",
            );
        }
        Ok(Settings {
            width,
            height,
            frames: get(f.frames).or(defaults.and_then(|d| d.frames)),
            seed: f.seed.or(defaults.and_then(|d| d.seed)),
            tolerance,
        })
    }
}

#[cfg(test)]
#[path = "manifest_tests.rs"]
mod tests;
