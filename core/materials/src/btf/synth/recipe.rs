//! The synthesis recipe file (docs/formats/btf.md, "Synthesis recipes"): the TOML as
//! written, its checks, and the `SynthSetup` it validates into. Its own module so the
//! file's parsing stays apart from the synthesis that runs on the setup.

use std::path::Path;

use glam::DVec3;
use serde::Deserialize;

use super::mesostructure::{Mesostructure, build_field};
use super::{Lobe, Region, SynthError, SynthErrorKind, SynthSetup, value_err};
use crate::brdf::{AnalyticBrdf, BrdfModel};
use crate::btf::directions;

/// A synthesis recipe as written (docs/formats/btf.md, "Synthesis recipes").
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RecipeFile {
    version: u32,
    name: String,
    width: u32,
    height: u32,
    /// `"bonn81"` (the default) for the Bonn/UBO2003 layout, `"ubo151"` for UBO2014's.
    directions: Option<String>,
    /// A ring layout `[[theta_deg, count], ...]` used for both light and view sets.
    direction_rings: Option<Vec<(f64, u32)>>,
    /// Height samples per texel side.
    #[serde(default = "default_detail")]
    detail: u32,
    /// Sub-texel samples per side (box-filtered, Sloan et al. use 2 x 2).
    #[serde(default = "default_supersample")]
    supersample: u32,
    /// Gather rays of the diffuse inter-reflection bounce per hit (0: no bounce).
    #[serde(default)]
    interreflection_samples: u32,
    #[serde(default)]
    pub(super) seed: u64,
    pub(super) mesostructure: Mesostructure,
    #[serde(rename = "region")]
    regions: Vec<RegionRecipe>,
}

fn default_detail() -> u32 {
    4
}
fn default_supersample() -> u32 {
    2
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RegionRecipe {
    #[serde(default)]
    name: String,
    /// Rotation of the BRDF tangent about the local normal, degrees (fibre direction).
    #[serde(default)]
    tangent_deg: f64,
    #[serde(rename = "lobe")]
    lobes: Vec<LobeRecipe>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LobeRecipe {
    model: String,
    #[serde(default)]
    params: toml::Table,
    weight: [f64; 3],
}

/// Reads a synthesis recipe (paths relative to its folder) and builds the setup.
pub fn load_recipe(path: &Path) -> Result<SynthSetup, SynthError> {
    let at = |kind: SynthErrorKind| SynthError {
        path: path.to_path_buf(),
        kind: Box::new(kind),
    };
    let text = std::fs::read_to_string(path).map_err(|e| at(e.into()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    parse_recipe(&text, dir, &name).map_err(at)
}

/// Parses recipe text; `dir` resolves image paths, `source` names the recipe in the
/// provenance.
pub fn parse_recipe(text: &str, dir: &Path, source: &str) -> Result<SynthSetup, SynthErrorKind> {
    let r: RecipeFile = toml::from_str(text).map_err(|e| SynthErrorKind::Toml(e.to_string()))?;
    if r.version != 1 {
        return Err(SynthErrorKind::Version(r.version));
    }
    if !(1..=4096).contains(&r.width) {
        return Err(value_err("width", r.width, "must be in 1..=4096"));
    }
    if !(1..=4096).contains(&r.height) {
        return Err(value_err("height", r.height, "must be in 1..=4096"));
    }
    if !(1..=16).contains(&r.detail) {
        return Err(value_err("detail", r.detail, "must be in 1..=16"));
    }
    if !(1..=8).contains(&r.supersample) {
        return Err(value_err("supersample", r.supersample, "must be in 1..=8"));
    }
    if r.interreflection_samples > 256 {
        return Err(value_err(
            "interreflection_samples",
            r.interreflection_samples,
            "must be in 0..=256",
        ));
    }
    let dirs = match (&r.directions, &r.direction_rings) {
        (Some(_), Some(_)) => return Err(SynthErrorKind::TwoLayouts),
        (Some(n), None) => directions::Layout::from_name(n)
            .ok_or_else(|| SynthErrorKind::Layout(n.clone()))?
            .directions(),
        (_, Some(rings)) => {
            for &(theta, count) in rings {
                if !(0.0..89.0).contains(&theta) || count == 0 || count > 360 {
                    return Err(value_err(
                        "direction_rings",
                        format!("[{theta}, {count}]"),
                        "each ring is [theta_deg in [0, 89), count in 1..=360]",
                    ));
                }
            }
            directions::rings(rings)
        }
        _ => directions::bonn81(),
    };
    let mut regions = Vec::new();
    for (ri, reg) in r.regions.iter().enumerate() {
        let mut lobes = Vec::new();
        for (li, lobe) in reg.lobes.iter().enumerate() {
            let model =
                BrdfModel::from_name(&lobe.model).map_err(|source| SynthErrorKind::Lobe {
                    region: ri,
                    name: reg.name.clone(),
                    lobe: li,
                    source,
                })?;
            let mut named = Vec::new();
            for (k, v) in &lobe.params {
                let x = v
                    .as_float()
                    .or_else(|| v.as_integer().map(|i| i as f64))
                    .ok_or_else(|| SynthErrorKind::ParamType {
                        region: ri,
                        lobe: li,
                        param: k.clone(),
                    })?;
                named.push((k.as_str(), x));
            }
            let brdf = AnalyticBrdf::new(model, &named).map_err(|source| SynthErrorKind::Lobe {
                region: ri,
                name: reg.name.clone(),
                lobe: li,
                source,
            })?;
            if lobe.weight.iter().any(|w| !w.is_finite() || *w < 0.0) {
                return Err(SynthErrorKind::Weight {
                    region: ri,
                    lobe: li,
                    weight: lobe.weight,
                });
            }
            lobes.push(Lobe {
                brdf,
                weight: DVec3::from_array(lobe.weight),
            });
        }
        if !reg.tangent_deg.is_finite() {
            return Err(value_err("tangent_deg", reg.tangent_deg, "must be finite"));
        }
        regions.push(Region {
            name: reg.name.clone(),
            tangent_deg: reg.tangent_deg,
            lobes,
        });
    }
    let field = build_field(&r.mesostructure, r.width, r.height, r.detail, r.seed, dir)?;
    let needed = field.regions.iter().copied().max().map_or(0, usize::from);
    if needed >= regions.len() {
        return Err(SynthErrorKind::MissingRegion {
            needed,
            defined: regions.len(),
        });
    }
    Ok(SynthSetup {
        name: r.name,
        provenance: format!(
            "meso btf synth {source} (mesostructure {:?})",
            kind_name(&r.mesostructure)
        ),
        width: r.width,
        height: r.height,
        light_dirs: dirs.clone(),
        view_dirs: dirs,
        supersample: r.supersample,
        interreflection_samples: r.interreflection_samples,
        seed: r.seed,
        field,
        regions,
    })
}

fn kind_name(m: &Mesostructure) -> &'static str {
    match m {
        Mesostructure::Flat {} => "flat",
        Mesostructure::Weave { .. } => "weave",
        Mesostructure::Knit { .. } => "knit",
        Mesostructure::Leather { .. } => "leather",
        Mesostructure::Ribs { .. } => "ribs",
        Mesostructure::Bumps { .. } => "bumps",
        Mesostructure::Image { .. } => "image",
    }
}
