//! Scene edits as the journal writes them (JSON): values as numbers, and the assets
//! an edit brings (maps, measured BRDFs, packs) by where they came from — the scene
//! file itself, a file the session read, or the edited pack — since the journal
//! must not copy them. An edit whose asset has no known source is written as
//! unrecorded, by name, so a restore can say what it could not bring back.

use std::any::Any;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec2, DVec3};
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::merl::MerlBrdf;
use meso_materials::spmm::pack;
use meso_render::SceneEdit;
use meso_render::scene::{Ambient, Background, Camera, Environment, Light, Material, Scene};
use serde::{Deserialize, Serialize};

fn v3(v: DVec3) -> [f64; 3] {
    v.to_array()
}

fn d3(v: [f64; 3]) -> DVec3 {
    DVec3::from_array(v)
}

/// The assets the session read from files, by object, so an edit that brings one
/// can name its file.
#[derive(Default, Clone)]
pub struct Sources {
    files: Vec<(Arc<dyn Any + Send + Sync>, PathBuf)>,
}

fn same_object<A: ?Sized, B: ?Sized>(a: &Arc<A>, b: &Arc<B>) -> bool {
    std::ptr::addr_eq(Arc::as_ptr(a), Arc::as_ptr(b))
}

impl Sources {
    /// Notes that `asset` was read from `path` (kept alive so the address stays its).
    pub fn note<T: Any + Send + Sync>(&mut self, asset: &Arc<T>, path: &Path) {
        let asset: Arc<dyn Any + Send + Sync> = asset.clone();
        self.files.retain(|(a, _)| !same_object(a, &asset));
        self.files.push((asset, path.to_path_buf()));
    }

    fn file_of<T: ?Sized>(&self, asset: &Arc<T>) -> Option<PathBuf> {
        self.files
            .iter()
            .find(|(a, _)| same_object(a, asset))
            .map(|(_, p)| p.clone())
    }
}

/// Where an asset comes from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// What the scene file has there (its environment map, background map, or the
    /// material of the same slot).
    Scene,
    /// A file the session read.
    File(PathBuf),
    /// The edited pack as the journal has it so far.
    EditedPack,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LightRecord {
    Point {
        position: [f64; 3],
        intensity: [f64; 3],
    },
    Area {
        corner: [f64; 3],
        edge_u: [f64; 3],
        edge_v: [f64; 3],
        radiance: [f64; 3],
    },
}

impl From<&Light> for LightRecord {
    fn from(l: &Light) -> Self {
        match *l {
            Light::Point {
                position,
                intensity,
            } => LightRecord::Point {
                position: v3(position),
                intensity: v3(intensity),
            },
            Light::Area {
                corner,
                edge_u,
                edge_v,
                radiance,
            } => LightRecord::Area {
                corner: v3(corner),
                edge_u: v3(edge_u),
                edge_v: v3(edge_v),
                radiance: v3(radiance),
            },
        }
    }
}

impl From<&LightRecord> for Light {
    fn from(l: &LightRecord) -> Self {
        match *l {
            LightRecord::Point {
                position,
                intensity,
            } => Light::Point {
                position: d3(position),
                intensity: d3(intensity),
            },
            LightRecord::Area {
                corner,
                edge_u,
                edge_v,
                radiance,
            } => Light::Area {
                corner: d3(corner),
                edge_u: d3(edge_u),
                edge_v: d3(edge_v),
                radiance: d3(radiance),
            },
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvironmentRecord {
    pub map: Source,
    pub strength: f64,
    pub rotate_y_deg: f64,
    pub mis: bool,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum BackgroundRecord {
    FromEnvironment,
    Color { rgb: [f64; 3] },
    Map { map: Source },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum MaterialRecord {
    Brdf {
        model: String,
        params: Vec<f64>,
        albedo: [f64; 3],
    },
    Mirror {
        reflectance: [f64; 3],
    },
    Spmm {
        pack: Source,
        uv_scale: [f64; 2],
        residual: bool,
        npca: usize,
    },
    Merl {
        brdf: Source,
        tint: [f64; 3],
    },
    Btf {
        table: Source,
        uv_scale: [f64; 2],
    },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    pub position: [f64; 3],
    pub look_at: [f64; 3],
    pub up: [f64; 3],
    pub fov_y_deg: f64,
}

/// A scene edit as the journal writes it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "edit", rename_all = "snake_case")]
pub enum SceneRecord {
    Camera {
        camera: CameraRecord,
    },
    Light {
        index: usize,
        light: LightRecord,
    },
    AddLight {
        light: LightRecord,
    },
    RemoveLight {
        index: usize,
    },
    Ambient {
        radiance: Option<[f64; 3]>,
        radius: Option<f64>,
    },
    LightSamples {
        n: u32,
    },
    Environment {
        environment: Option<EnvironmentRecord>,
    },
    Background {
        background: BackgroundRecord,
    },
    Material {
        index: usize,
        material: MaterialRecord,
    },
}

/// What the scene file gave: the assets a record names as `Source::Scene`.
#[derive(Clone, Debug)]
pub struct Opened {
    pub materials: Vec<Material>,
    pub environment: Option<Environment>,
    pub background: Background,
    pub camera: Camera,
}

impl Opened {
    pub fn of(scene: &Scene) -> Self {
        Self {
            materials: scene.materials.clone(),
            environment: scene.environment.clone(),
            background: scene.background.clone(),
            camera: scene.camera,
        }
    }
}

/// What a record is made from: the scene as its file gave it, the files read since,
/// and which slot holds the edited pack.
pub struct RecordContext<'a> {
    pub opened: &'a Opened,
    pub sources: &'a Sources,
    pub edited_slot: Option<usize>,
}

/// An edit as a record, or `Err(what)` naming an edit whose asset has no known
/// source. Resize and moving are not edits of the document: `Ok(None)`.
pub fn record_of(edit: &SceneEdit, ctx: &RecordContext) -> Result<Option<SceneRecord>, String> {
    Ok(Some(match edit {
        SceneEdit::Camera(c) => SceneRecord::Camera {
            camera: CameraRecord {
                position: v3(c.position),
                look_at: v3(c.look_at),
                up: v3(c.up),
                fov_y_deg: c.fov_y_deg,
            },
        },
        SceneEdit::Resize { .. } | SceneEdit::Moving(_) => return Ok(None),
        SceneEdit::Meshes(_) => return Err("a mesh replacement".into()),
        SceneEdit::Light { index, light } => SceneRecord::Light {
            index: *index,
            light: light.into(),
        },
        SceneEdit::AddLight(l) => SceneRecord::AddLight { light: l.into() },
        SceneEdit::RemoveLight(i) => SceneRecord::RemoveLight { index: *i },
        SceneEdit::Ambient(a) => SceneRecord::Ambient {
            radiance: a.map(|a| v3(a.radiance)),
            // JSON has no infinity: none means occluders at any distance count.
            radius: a.and_then(|a| a.radius.is_finite().then_some(a.radius)),
        },
        SceneEdit::LightSamples(n) => SceneRecord::LightSamples { n: *n },
        SceneEdit::Environment(e) => SceneRecord::Environment {
            environment: match e {
                None => None,
                Some(e) => Some(EnvironmentRecord {
                    map: map_source(&e.map, ctx)
                        .ok_or("an environment map read from an unknown place")?,
                    strength: e.strength,
                    rotate_y_deg: e.rotate_y_deg,
                    mis: e.mis,
                }),
            },
        },
        SceneEdit::Background(b) => SceneRecord::Background {
            background: match b {
                Background::FromEnvironment => BackgroundRecord::FromEnvironment,
                Background::Color(c) => BackgroundRecord::Color { rgb: v3(*c) },
                Background::Environment(map) => BackgroundRecord::Map {
                    map: map_source(map, ctx)
                        .ok_or("a background map read from an unknown place")?,
                },
            },
        },
        SceneEdit::Material { index, material } => SceneRecord::Material {
            index: *index,
            material: material_record(*index, material, ctx)?,
        },
    }))
}

fn map_source<T: ?Sized>(map: &Arc<T>, ctx: &RecordContext) -> Option<Source> {
    let from_scene = ctx
        .opened
        .environment
        .as_ref()
        .is_some_and(|e| same_object(&e.map, map))
        || matches!(&ctx.opened.background, Background::Environment(m) if same_object(m, map));
    if from_scene {
        Some(Source::Scene)
    } else {
        ctx.sources.file_of(map).map(Source::File)
    }
}

fn material_record(
    index: usize,
    m: &Material,
    ctx: &RecordContext,
) -> Result<MaterialRecord, String> {
    let opened = ctx.opened.materials.get(index);
    let source = |asset: &Arc<dyn Any + Send + Sync>,
                  scene_asset: Option<&Arc<dyn Any + Send + Sync>>| {
        if scene_asset.is_some_and(|s| same_object(s, asset)) {
            Some(Source::Scene)
        } else {
            ctx.sources.file_of(asset).map(Source::File)
        }
    };
    Ok(match m {
        Material::Brdf { brdf, albedo } => MaterialRecord::Brdf {
            model: brdf.model().name().to_string(),
            params: brdf.param_values(),
            albedo: v3(*albedo),
        },
        Material::Mirror { reflectance } => MaterialRecord::Mirror {
            reflectance: v3(*reflectance),
        },
        Material::Spmm {
            material,
            uv_scale,
            residual,
            npca,
        } => {
            // The edited pack's content is journaled as deltas and files of its
            // own; its material record carries the settings only.
            let pack = if ctx.edited_slot == Some(index) {
                Source::EditedPack
            } else {
                let scene = match opened {
                    Some(Material::Spmm { material: s, .. }) => {
                        Some(Arc::clone(s) as Arc<dyn Any + Send + Sync>)
                    }
                    _ => None,
                };
                let asset = Arc::clone(material) as Arc<dyn Any + Send + Sync>;
                source(&asset, scene.as_ref()).ok_or("a pack read from an unknown place")?
            };
            MaterialRecord::Spmm {
                pack,
                uv_scale: uv_scale.to_array(),
                residual: *residual,
                npca: *npca,
            }
        }
        Material::Merl { brdf, tint } => {
            let scene = match opened {
                Some(Material::Merl { brdf: s, .. }) => {
                    Some(Arc::clone(s) as Arc<dyn Any + Send + Sync>)
                }
                _ => None,
            };
            let asset = Arc::clone(brdf) as Arc<dyn Any + Send + Sync>;
            MaterialRecord::Merl {
                brdf: source(&asset, scene.as_ref())
                    .ok_or("a MERL BRDF read from an unknown place")?,
                tint: v3(*tint),
            }
        }
        Material::Btf { table, uv_scale } => {
            let scene = match opened {
                Some(Material::Btf { table: s, .. }) => {
                    Some(Arc::clone(s) as Arc<dyn Any + Send + Sync>)
                }
                _ => None,
            };
            let asset = Arc::clone(table) as Arc<dyn Any + Send + Sync>;
            MaterialRecord::Btf {
                table: source(&asset, scene.as_ref()).ok_or("a BTF read from an unknown place")?,
                uv_scale: uv_scale.to_array(),
            }
        }
    })
}

/// What a record is turned back into an edit with: the scene as its file gave it
/// and the edited pack as replayed so far.
pub struct ReplayContext<'a> {
    pub opened: &'a Opened,
    pub edited_pack: Option<Arc<meso_materials::spmm::SpmmMaterial>>,
}

fn read(path: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("`{}`: {e}", path.display()))
}

/// The edit a record stands for, reading the files it names.
pub fn edit_of(record: &SceneRecord, ctx: &ReplayContext) -> Result<SceneEdit, String> {
    let opened_material = |index: usize| {
        ctx.opened
            .materials
            .get(index)
            .cloned()
            .ok_or_else(|| format!("the scene file has no material {index}"))
    };
    Ok(match record {
        SceneRecord::Camera { camera: c } => SceneEdit::Camera(Camera {
            position: d3(c.position),
            look_at: d3(c.look_at),
            up: d3(c.up),
            fov_y_deg: c.fov_y_deg,
        }),
        SceneRecord::Light { index, light } => SceneEdit::Light {
            index: *index,
            light: light.into(),
        },
        SceneRecord::AddLight { light } => SceneEdit::AddLight(light.into()),
        SceneRecord::RemoveLight { index } => SceneEdit::RemoveLight(*index),
        SceneRecord::Ambient { radiance, radius } => {
            SceneEdit::Ambient(radiance.map(|r| Ambient {
                radiance: d3(r),
                radius: radius.unwrap_or(f64::INFINITY),
            }))
        }
        SceneRecord::LightSamples { n } => SceneEdit::LightSamples(*n),
        SceneRecord::Environment { environment } => SceneEdit::Environment(match environment {
            None => None,
            Some(e) => Some(Environment {
                map: map_of(&e.map, ctx)?,
                strength: e.strength,
                rotate_y_deg: e.rotate_y_deg,
                mis: e.mis,
            }),
        }),
        SceneRecord::Background { background } => SceneEdit::Background(match background {
            BackgroundRecord::FromEnvironment => Background::FromEnvironment,
            BackgroundRecord::Color { rgb } => Background::Color(d3(*rgb)),
            BackgroundRecord::Map { map } => Background::Environment(map_of(map, ctx)?),
        }),
        SceneRecord::Material { index, material } => SceneEdit::Material {
            index: *index,
            material: match material {
                MaterialRecord::Brdf {
                    model,
                    params,
                    albedo,
                } => {
                    let model = BrdfModel::from_name(model).map_err(|e| e.to_string())?;
                    let named: Vec<(&str, f64)> = model
                        .param_specs()
                        .iter()
                        .map(|s| s.name)
                        .zip(params.iter().copied())
                        .collect();
                    Material::Brdf {
                        brdf: AnalyticBrdf::new(model, &named).map_err(|e| e.to_string())?,
                        albedo: d3(*albedo),
                    }
                }
                MaterialRecord::Mirror { reflectance } => Material::Mirror {
                    reflectance: d3(*reflectance),
                },
                MaterialRecord::Spmm {
                    pack: source,
                    uv_scale,
                    residual,
                    npca,
                } => {
                    let material = match source {
                        Source::EditedPack => ctx
                            .edited_pack
                            .clone()
                            .ok_or("the journal names an edited pack before any")?,
                        Source::Scene => match opened_material(*index)? {
                            Material::Spmm { material, .. } => material,
                            _ => {
                                return Err(format!(
                                    "the scene file's material {index} is not a pack"
                                ));
                            }
                        },
                        Source::File(p) => Arc::new(
                            pack::decode_pack(&read(p)?)
                                .map_err(|e| format!("`{}`: {e}", p.display()))?,
                        ),
                    };
                    Material::Spmm {
                        material,
                        uv_scale: DVec2::from_array(*uv_scale),
                        residual: *residual,
                        npca: *npca,
                    }
                }
                MaterialRecord::Merl { brdf, tint } => Material::Merl {
                    brdf: match brdf {
                        Source::File(p) => Arc::new(
                            MerlBrdf::from_bytes(&read(p)?)
                                .map_err(|e| format!("`{}`: {e}", p.display()))?,
                        ),
                        _ => match opened_material(*index)? {
                            Material::Merl { brdf, .. } => brdf,
                            _ => {
                                return Err(format!(
                                    "the scene file's material {index} is not MERL"
                                ));
                            }
                        },
                    },
                    tint: d3(*tint),
                },
                MaterialRecord::Btf { table, uv_scale } => Material::Btf {
                    table: match (table, opened_material(*index)?) {
                        (Source::Scene, Material::Btf { table, .. }) => table,
                        _ => {
                            return Err(format!("material {index}: a BTF not from the scene file"));
                        }
                    },
                    uv_scale: DVec2::from_array(*uv_scale),
                },
            },
        },
    })
}

fn map_of(
    source: &Source,
    ctx: &ReplayContext,
) -> Result<Arc<meso_materials::image::Image>, String> {
    match source {
        Source::File(p) => {
            let map = meso_materials::image::read_image(p)
                .map_err(|e| format!("`{}`: {e}", p.display()))?;
            Ok(Arc::new(map))
        }
        _ => ctx
            .opened
            .environment
            .as_ref()
            .map(|e| Arc::clone(&e.map))
            .or(match &ctx.opened.background {
                Background::Environment(m) => Some(Arc::clone(m)),
                _ => None,
            })
            .ok_or_else(|| "the scene file has no environment map".to_string()),
    }
}
