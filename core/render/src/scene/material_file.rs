//! A material table (`[materials.NAME]`, or a regression manifest's substitution in
//! the same form) checked into a `Material`: the keys each kind accepts, the files it
//! names (packs, MERL tables, BTFs) read and validated.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

use glam::{DVec2, DVec3};
use toml::Spanned;

use super::load::{BtfOpened, Ctx, SceneError, btf_key};
use super::{Material, file};
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::btf::table::{BtfTable, MemoryBound};
use meso_materials::merl::{self, MerlBrdf};
use meso_materials::spmm::pack;

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
    let opened = BtfOpened::default();
    let ctx = Ctx {
        file,
        text,
        btf_memory: MemoryBound::default(),
        btf_opened: &opened,
    };
    build_material(&ctx, table_key, &table.0, folder)
}

/// `table`: the key of the material's table (`materials.cloth`), for errors.
pub(super) fn build_material(
    ctx: &Ctx,
    table: &str,
    m: &Spanned<file::MaterialFile>,
    folder: &Path,
) -> Result<Material, SceneError> {
    let span = m.span();
    let m = m.get_ref();
    let key = |k: &str| format!("{table}.{k}");
    check_keys(ctx, table, &span, m)?;
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
        "merl" => merl_material(ctx, table, &span, m, folder),
        "btf" => {
            let Some(path) = &m.path else {
                return ctx.err(&span, key("path"), "a `btf` material needs `path`");
            };
            let full = folder.join(path.get_ref());
            let file = btf_key(&full);
            let shared = (ctx.btf_opened.borrow().iter())
                .find(|(k, _)| *k == file)
                .map(|(_, t)| Arc::clone(t));
            let table = match shared {
                Some(t) => t,
                None => {
                    let t = BtfTable::open(&full, ctx.btf_memory)
                        .or_else(|e| ctx.err(&path.span(), key("path"), e.to_string()))?;
                    let t = Arc::new(t);
                    ctx.btf_opened.borrow_mut().push((file, Arc::clone(&t)));
                    t
                }
            };
            Ok(Material::Btf {
                table,
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

/// Refuses a key that does not belong to the material's kind.
fn check_keys(
    ctx: &Ctx,
    table: &str,
    span: &Range<usize>,
    m: &file::MaterialFile,
) -> Result<(), SceneError> {
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
            span,
            key(k),
            format!("does not belong to a `{}` material", m.kind.get_ref()),
        );
    }
    Ok(())
}

/// A `merl` material: a table read from `path`, or an analytic model tabulated.
fn merl_material(
    ctx: &Ctx,
    table: &str,
    span: &Range<usize>,
    m: &file::MaterialFile,
    folder: &Path,
) -> Result<Material, SceneError> {
    let key = |k: &str| format!("{table}.{k}");
    let brdf = match (&m.path, &m.tabulate) {
        (Some(path), None) => MerlBrdf::read(&folder.join(path.get_ref()))
            .or_else(|e| ctx.err(&path.span(), key("path"), e.to_string()))?,
        (None, Some(t)) => {
            let span = &t.span();
            let t = t.get_ref();
            let model = BrdfModel::from_name(&t.model)
                .or_else(|e| ctx.err(span, key("tabulate.model"), e.to_string()))?;
            let named: Vec<(&str, f64)> = t.params.iter().map(|(k, v)| (k.as_str(), *v)).collect();
            let analytic = AnalyticBrdf::new(model, &named)
                .or_else(|e| ctx.err(span, key("tabulate.params"), e.to_string()))?;
            let albedo = DVec3::from_array(t.albedo.unwrap_or([1.0; 3]));
            merl::tabulate(&analytic, albedo)
                .or_else(|e| ctx.err(span, key("tabulate.albedo"), e.to_string()))?
        }
        _ => {
            return ctx.err(
                span,
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
