//! The scene file as written (docs/scenes.md): serde structs with
//! `deny_unknown_fields`, spans kept on the values whose meaning is checked after
//! parsing (material names, geometry, light sizes) so those errors can name the line.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::Deserialize;
use toml::Spanned;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub version: Spanned<u32>,
    #[serde(default)]
    pub render: RenderFile,
    pub camera: CameraFile,
    #[serde(default)]
    pub materials: BTreeMap<String, Spanned<MaterialFile>>,
    #[serde(default, rename = "mesh")]
    pub meshes: Vec<MeshFile>,
    #[serde(default, rename = "quad")]
    pub quads: Vec<QuadFile>,
    #[serde(default, rename = "light")]
    pub lights: Vec<Spanned<LightFile>>,
    pub ambient: Option<AmbientFile>,
    pub environment: Option<EnvironmentFile>,
    /// Absent: rays that leave the scene see the `[environment]` (black without one).
    pub background: Option<BackgroundFile>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderFile {
    #[serde(default = "default_size")]
    pub width: Spanned<u32>,
    #[serde(default = "default_size")]
    pub height: Spanned<u32>,
    #[serde(default = "default_frames")]
    pub frames: Spanned<u32>,
    #[serde(default)]
    pub seed: u64,
    #[serde(default = "default_depth")]
    pub max_specular_depth: Spanned<u32>,
    pub mode: Option<Spanned<String>>,
    pub device: Option<Spanned<String>>,
    pub sampler: Option<Spanned<String>>,
    #[serde(default = "default_light_samples")]
    pub light_samples: Spanned<u32>,
}

fn default_size() -> Spanned<u32> {
    Spanned::new(0..0, 512)
}
fn default_frames() -> Spanned<u32> {
    Spanned::new(0..0, 64)
}
fn default_light_samples() -> Spanned<u32> {
    Spanned::new(0..0, 1)
}
fn default_depth() -> Spanned<u32> {
    Spanned::new(0..0, 4)
}

impl Default for RenderFile {
    fn default() -> Self {
        Self {
            width: default_size(),
            height: default_size(),
            frames: default_frames(),
            seed: 0,
            max_specular_depth: default_depth(),
            mode: None,
            device: None,
            sampler: None,
            light_samples: default_light_samples(),
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    pub position: Spanned<[f64; 3]>,
    pub look_at: Spanned<[f64; 3]>,
    pub up: Spanned<[f64; 3]>,
    pub fov_y_deg: Spanned<f64>,
}

/// All material kinds in one struct: `kind` says which fields belong; the others must
/// be absent (checked in scene/mod.rs), so a misplaced key is still an error.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialFile {
    pub kind: Spanned<String>,
    // kind = "brdf"
    pub model: Option<Spanned<String>>,
    pub params: Option<Spanned<BTreeMap<String, f64>>>,
    pub albedo: Option<Spanned<[f64; 3]>>,
    // kind = "spmm"
    pub pack: Option<Spanned<PathBuf>>,
    pub uv_scale: Option<Spanned<[f64; 2]>>,
    pub residual: Option<bool>,
    pub npca: Option<Spanned<u32>>,
    // kind = "mirror"
    pub reflectance: Option<Spanned<[f64; 3]>>,
    // kind = "merl": a file, or a table made at load from an analytic BRDF
    pub path: Option<Spanned<PathBuf>>,
    pub tabulate: Option<Spanned<TabulateFile>>,
    pub tint: Option<Spanned<[f64; 3]>>,
}

/// `tabulate = { model = "...", params = {...}, albedo = [...] }` of a `merl` material.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TabulateFile {
    pub model: String,
    #[serde(default)]
    pub params: BTreeMap<String, f64>,
    pub albedo: Option<[f64; 3]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshFile {
    pub path: Spanned<PathBuf>,
    pub material: Spanned<String>,
    #[serde(default = "one")]
    pub scale: Spanned<f64>,
    #[serde(default = "y_axis")]
    pub rotate_axis: Spanned<[f64; 3]>,
    #[serde(default = "zero")]
    pub rotate_deg: Spanned<f64>,
    #[serde(default = "origin")]
    pub translate: Spanned<[f64; 3]>,
}

fn one() -> Spanned<f64> {
    Spanned::new(0..0, 1.0)
}
fn zero() -> Spanned<f64> {
    Spanned::new(0..0, 0.0)
}
fn origin() -> Spanned<[f64; 3]> {
    Spanned::new(0..0, [0.0; 3])
}
fn y_axis() -> Spanned<[f64; 3]> {
    Spanned::new(0..0, [0.0, 1.0, 0.0])
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuadFile {
    pub corner: Spanned<[f64; 3]>,
    pub edge_u: Spanned<[f64; 3]>,
    pub edge_v: Spanned<[f64; 3]>,
    pub material: Spanned<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightFile {
    pub kind: Spanned<String>,
    // kind = "point"
    pub position: Option<Spanned<[f64; 3]>>,
    pub intensity: Option<Spanned<[f64; 3]>>,
    // kind = "area"
    pub corner: Option<Spanned<[f64; 3]>>,
    pub edge_u: Option<Spanned<[f64; 3]>>,
    pub edge_v: Option<Spanned<[f64; 3]>>,
    pub radiance: Option<Spanned<[f64; 3]>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmbientFile {
    pub radiance: Spanned<[f64; 3]>,
    pub radius: Spanned<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentFile {
    pub path: Spanned<PathBuf>,
    #[serde(default = "one")]
    pub strength: Spanned<f64>,
    #[serde(default = "zero")]
    pub rotate_y_deg: Spanned<f64>,
    /// Meso's addition: false samples the map alone (to measure what MIS gains).
    #[serde(default = "yes")]
    pub mis: bool,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackgroundFile {
    #[serde(default = "origin")]
    pub color: Spanned<[f64; 3]>,
    pub environment: Option<Spanned<PathBuf>>,
}
