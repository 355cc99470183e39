//! BTF synthesis by ray tracing a height-field mesostructure patch, the way Sloan et al.
//! 2003 (section 4.2) built their weave and stucco BTFs: for each texel, view direction
//! and sub-texel sample, a view ray through the patch's mid-depth sampling plane is
//! marched against the tiled height field (it may enter neighbouring tiles), the hit is
//! shaded with its region's analytic BRDFs times the cosine, with a shadow ray towards
//! the light and, optionally, one diffuse inter-reflection bounce gathered with
//! cosine-distributed rays. No refraction, no volumetric fibres, no multiple bounces.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use serde::Deserialize;

use super::{Btf, BtfError, directions};
use crate::brdf::{AnalyticBrdf, BrdfError, BrdfModel, Frame, warp};
use crate::image::{self, ImageError};
use crate::rng::SampleStream;

/// A synthesis recipe as written (docs/formats/btf.md, "Synthesis recipes").
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RecipeFile {
    version: u32,
    name: String,
    width: u32,
    height: u32,
    /// `"bonn81"` (the default) for the Bonn/UBO layout.
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
    seed: u64,
    mesostructure: Mesostructure,
    #[serde(rename = "region")]
    regions: Vec<RegionRecipe>,
}

fn default_detail() -> u32 {
    4
}
fn default_supersample() -> u32 {
    2
}

/// The procedural height fields; each gives a height in [0, 1] (scaled by `depth`,
/// in texel widths) and a region id per point of one tile.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Mesostructure {
    /// A flat surface at height 0, region 0.
    Flat {},
    /// Plain weave: `threads` warp threads (along v, region 0) over and under
    /// `threads` weft threads (along u, region 1); region 2 is the gap beneath.
    Weave {
        depth: f64,
        threads: u32,
        /// Gap between threads as a fraction of the thread spacing, [0, 0.9].
        #[serde(default = "default_gap")]
        gap: f64,
    },
    /// Stockinette knit: `columns` x `rows` V-shaped stitches of two yarn legs
    /// (region 0) over a dark gap (region 1).
    Knit { depth: f64, columns: u32, rows: u32 },
    /// Grain leather: `cells` Voronoi grain cells (region 0) separated by creases of
    /// relative width `crease` (region 1).
    Leather { depth: f64, cells: u32, crease: f64 },
    /// Corduroy: `ribs` ribs along v (region 0) with pile roughness `pile` in [0, 1],
    /// grooves between them (region 1).
    Ribs { depth: f64, ribs: u32, pile: f64 },
    /// `count` round bumps of radius `radius` (fraction of the tile) on a base plane:
    /// bumps region 0, base region 1.
    Bumps { depth: f64, count: u32, radius: f64 },
    /// A grey image as height (white high), `(width * detail) x (height * detail)`
    /// pixels, and optionally a grey region map of the same size (8-bit value k is
    /// region k).
    Image {
        depth: f64,
        path: PathBuf,
        regions: Option<PathBuf>,
    },
}

fn default_gap() -> f64 {
    0.1
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

#[derive(Debug, thiserror::Error)]
#[error("`{}`: {kind}", path.display())]
pub struct SynthError {
    pub path: PathBuf,
    pub kind: Box<SynthErrorKind>,
}

#[derive(Debug, thiserror::Error)]
pub enum SynthErrorKind {
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// toml's message names the line, column and key.
    #[error("{0}")]
    Toml(String),
    #[error("version {0}: this build reads BTF recipe version 1")]
    Version(u32),
    #[error("`{key}` = {value}: {rule}")]
    Value {
        key: &'static str,
        value: String,
        rule: &'static str,
    },
    #[error("`directions` = `{0}`: the only named layout is `bonn81` (or give `direction_rings`)")]
    Layout(String),
    #[error("give `directions` or `direction_rings`, not both")]
    TwoLayouts,
    #[error("region {region} ({name}) lobe {lobe}: {source}")]
    Lobe {
        region: usize,
        name: String,
        lobe: usize,
        source: BrdfError,
    },
    #[error("region {region} lobe {lobe}: parameter `{param}` is not a number")]
    ParamType {
        region: usize,
        lobe: usize,
        param: String,
    },
    #[error("region {region} lobe {lobe}: weight {weight:?} must be finite and >= 0")]
    Weight {
        region: usize,
        lobe: usize,
        weight: [f64; 3],
    },
    #[error("the mesostructure uses region {needed}, but only {defined} region(s) are defined")]
    MissingRegion { needed: usize, defined: usize },
    #[error("{what} `{}`: {source}", path.display())]
    Image {
        what: &'static str,
        path: PathBuf,
        source: ImageError,
    },
    #[error("{what} `{}` is {found_w}x{found_h}, expected {w}x{h} (width x detail, height x detail)", path.display())]
    ImageSize {
        what: &'static str,
        path: PathBuf,
        found_w: u32,
        found_h: u32,
        w: u32,
        h: u32,
    },
    #[error("{0}")]
    Btf(#[from] BtfError),
    #[error("cancelled")]
    Cancelled,
}

/// One analytic lobe of a region's BRDF with its RGB weight.
#[derive(Clone, Copy, Debug)]
pub struct Lobe {
    pub brdf: AnalyticBrdf,
    pub weight: DVec3,
}

/// The material of one part of the mesostructure: a weighted sum of analytic BRDFs
/// in the local frame of the surface normal, its tangent turned by `tangent_deg`.
#[derive(Clone, Debug)]
pub struct Region {
    pub name: String,
    pub tangent_deg: f64,
    pub lobes: Vec<Lobe>,
}

impl Region {
    /// RGB BRDF value with `wi`, `wo` in the local frame.
    fn eval_local(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        self.lobes
            .iter()
            .map(|l| l.weight * l.brdf.eval(wi, wo))
            .sum()
    }
    /// The diffuse weight used for the inter-reflection bounce: the summed weights of
    /// the Lambertian and Oren-Nayar lobes (the secondary surface is treated as
    /// Lambertian with this albedo).
    fn diffuse_albedo(&self) -> DVec3 {
        self.lobes
            .iter()
            .filter(|l| matches!(l.brdf.model(), BrdfModel::Lambertian | BrdfModel::OrenNayar))
            .map(|l| l.weight)
            .sum()
    }
}

/// A tiled height field over the patch: `grid_w x grid_h` samples, sample (i, j) at
/// x = (i + 0.5) / detail, y = (j + 0.5) / detail in texel widths (x right, y up: j = 0
/// is the bottom row of the patch), heights in texel widths.
#[derive(Clone, Debug)]
pub struct HeightField {
    pub grid_w: usize,
    pub grid_h: usize,
    pub detail: f64,
    pub heights: Vec<f64>,
    pub regions: Vec<u8>,
    h_min: f64,
    h_max: f64,
}

impl HeightField {
    pub fn new(
        grid_w: usize,
        grid_h: usize,
        detail: f64,
        heights: Vec<f64>,
        regions: Vec<u8>,
    ) -> Self {
        let h_min = heights.iter().copied().fold(f64::INFINITY, f64::min);
        let h_max = heights.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Self {
            grid_w,
            grid_h,
            detail,
            heights,
            regions,
            h_min,
            h_max,
        }
    }

    fn at(&self, i: isize, j: isize) -> f64 {
        let i = i.rem_euclid(self.grid_w as isize) as usize;
        let j = j.rem_euclid(self.grid_h as isize) as usize;
        self.heights[j * self.grid_w + i]
    }

    /// Bilinear height at (x, y) in texel units, wrapping.
    fn height(&self, p: DVec2) -> f64 {
        let gx = p.x * self.detail - 0.5;
        let gy = p.y * self.detail - 0.5;
        let (fx, fy) = (gx.floor(), gy.floor());
        let (tx, ty) = (gx - fx, gy - fy);
        let (i, j) = (fx as isize, fy as isize);
        let h00 = self.at(i, j);
        let h10 = self.at(i + 1, j);
        let h01 = self.at(i, j + 1);
        let h11 = self.at(i + 1, j + 1);
        (h00 * (1.0 - tx) + h10 * tx) * (1.0 - ty) + (h01 * (1.0 - tx) + h11 * tx) * ty
    }

    /// Surface normal of the bilinear surface at (x, y).
    fn normal(&self, p: DVec2) -> DVec3 {
        let gx = p.x * self.detail - 0.5;
        let gy = p.y * self.detail - 0.5;
        let (fx, fy) = (gx.floor(), gy.floor());
        let (tx, ty) = (gx - fx, gy - fy);
        let (i, j) = (fx as isize, fy as isize);
        let h00 = self.at(i, j);
        let h10 = self.at(i + 1, j);
        let h01 = self.at(i, j + 1);
        let h11 = self.at(i + 1, j + 1);
        // Derivatives of the bilinear patch, per texel unit.
        let dx = ((h10 - h00) * (1.0 - ty) + (h11 - h01) * ty) * self.detail;
        let dy = ((h01 - h00) * (1.0 - tx) + (h11 - h10) * tx) * self.detail;
        DVec3::new(-dx, -dy, 1.0).normalize()
    }

    fn region(&self, p: DVec2) -> usize {
        let i = ((p.x * self.detail).floor() as isize).rem_euclid(self.grid_w as isize) as usize;
        let j = ((p.y * self.detail).floor() as isize).rem_euclid(self.grid_h as isize) as usize;
        usize::from(self.regions[j * self.grid_w + i])
    }

    /// First intersection of the ray `o + t d` (d pointing down or sideways) with the
    /// surface, marching in steps of half a height sample and bisecting the crossing.
    fn intersect_down(&self, o: DVec3, d: DVec3) -> Option<DVec3> {
        if d.z >= 0.0 {
            return None;
        }
        let horizontal = d.truncate().length();
        if horizontal < 1e-12 {
            let h = self.height(o.truncate());
            return Some(DVec3::new(o.x, o.y, h));
        }
        let step = 0.5 / (self.detail * horizontal);
        let (mut t0, mut t) = (0.0, 0.0);
        // d.z < 0: the ray ends below h_min, where it is surely under the surface.
        loop {
            let p = o + d * t;
            if p.z <= self.height(p.truncate()) {
                break;
            }
            t0 = t;
            t += step;
        }
        let (mut a, mut b) = (t0, t);
        for _ in 0..24 {
            let m = 0.5 * (a + b);
            let p = o + d * m;
            if p.z <= self.height(p.truncate()) {
                b = m;
            } else {
                a = m;
            }
        }
        let p = o + d * b;
        Some(DVec3::new(p.x, p.y, self.height(p.truncate())))
    }

    /// Whether the ray from surface point `p` towards `d` (d.z > 0) is blocked before
    /// it leaves the height field's slab.
    fn occluded(&self, p: DVec3, d: DVec3) -> bool {
        self.hit_up(p, d).is_some()
    }

    /// Where a gather ray from surface point `p` towards `d` (in the hemisphere of the
    /// surface normal) first meets the surface, if it does before leaving the slab.
    fn gather_hit(&self, p: DVec3, d: DVec3) -> Option<DVec2> {
        if d.z > 0.0 {
            return self.hit_up(p, d);
        }
        // Downwards: start half a marching step out, clear of the point's own patch.
        let horizontal = d.truncate().length().max(1e-12);
        let o = p + d * (0.25 / (self.detail * horizontal));
        self.intersect_down(o, d).map(|q| q.truncate())
    }

    /// Where the ray from surface point `p` towards `d` (d.z > 0) first goes under the
    /// surface before leaving the slab (for gather rays), if it does.
    fn hit_up(&self, p: DVec3, d: DVec3) -> Option<DVec2> {
        let horizontal = d.truncate().length();
        if horizontal < 1e-12 {
            return None;
        }
        let step = 0.5 / (self.detail * horizontal);
        // Start half a step out so the starting point's own patch does not occlude.
        let mut t = 0.5 * step;
        loop {
            let q = p + d * t;
            if q.z > self.h_max {
                return None;
            }
            if q.z < self.height(q.truncate()) - 1e-6 {
                return Some(q.truncate());
            }
            t += step;
        }
    }
}

/// Everything a synthesis needs, validated.
#[derive(Clone, Debug)]
pub struct SynthSetup {
    pub name: String,
    pub provenance: String,
    pub width: u32,
    pub height: u32,
    pub light_dirs: Vec<DVec3>,
    pub view_dirs: Vec<DVec3>,
    pub supersample: u32,
    pub interreflection_samples: u32,
    pub seed: u64,
    pub field: HeightField,
    pub regions: Vec<Region>,
}

fn value_err(
    key: &'static str,
    value: impl std::fmt::Display,
    rule: &'static str,
) -> SynthErrorKind {
    SynthErrorKind::Value {
        key,
        value: value.to_string(),
        rule,
    }
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
        (Some(n), None) if n != "bonn81" => return Err(SynthErrorKind::Layout(n.clone())),
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

fn check_depth(depth: f64) -> Result<f64, SynthErrorKind> {
    if depth.is_finite() && (0.0..=64.0).contains(&depth) {
        Ok(depth)
    } else {
        Err(value_err("depth", depth, "must be in [0, 64] texel widths"))
    }
}

fn check_count(key: &'static str, n: u32) -> Result<f64, SynthErrorKind> {
    if (1..=256).contains(&n) {
        Ok(f64::from(n))
    } else {
        Err(value_err(key, n, "must be in 1..=256"))
    }
}

fn check_unit(key: &'static str, x: f64, max: f64) -> Result<f64, SynthErrorKind> {
    if x.is_finite() && (0.0..=max).contains(&x) {
        Ok(x)
    } else {
        Err(value_err(
            key,
            x,
            "must be in the documented range (see docs/formats/btf.md)",
        ))
    }
}

/// Rounded profile of a thread or rib: 1 on its axis, 0 at distance `half` and beyond.
fn profile(s: f64, half: f64) -> f64 {
    let q = s / half;
    (1.0 - q * q).max(0.0).sqrt()
}

/// Samples one tile's procedural height (before `depth` scaling) and region at (u, v)
/// in [0, 1)^2, v up.
fn procedural(
    m: &Mesostructure,
    u: f64,
    v: f64,
    seeds: &[DVec2],
) -> Result<(f64, u8), SynthErrorKind> {
    Ok(match m {
        Mesostructure::Flat {} | Mesostructure::Image { .. } => (0.0, 0),
        Mesostructure::Weave { threads, gap, .. } => {
            let n = check_count("threads", *threads)?;
            let gap = check_unit("gap", *gap, 0.9)?;
            let half = 0.5 * (1.0 - gap);
            // Warp i runs along v; over weft j where i + j is even.
            let (su, sv) = (u * n, v * n);
            let (i, j) = (su.floor(), sv.floor());
            let (du, dv) = (su - i - 0.5, sv - j - 0.5);
            let amp = 0.5;
            let warp_c = amp * (std::f64::consts::PI * (sv - 0.5 - i)).cos();
            let weft_c = -amp * (std::f64::consts::PI * (su - 0.5 - j)).cos();
            let warp = (du.abs() < half).then(|| warp_c + 0.5 * profile(du, half));
            let weft = (dv.abs() < half).then(|| weft_c + 0.5 * profile(dv, half));
            let floor = -amp - 0.5;
            let h = match (warp, weft) {
                (Some(a), Some(b)) if a >= b => (a, 0),
                (Some(_), Some(b)) => (b, 1),
                (Some(a), None) => (a, 0),
                (None, Some(b)) => (b, 1),
                (None, None) => (floor, 2),
            };
            ((h.0 - floor) / (2.0 * amp + 1.0), h.1)
        }
        Mesostructure::Knit { columns, rows, .. } => {
            let (nc, nr) = (
                check_count("columns", *columns)?,
                check_count("rows", *rows)?,
            );
            let (cu, cv) = (u * nc, v * nr);
            let x = cu - cu.floor();
            let base_v = cv - cv.floor();
            let mut best: (f64, u8) = (0.0, 1);
            // A stitch's legs span 1.4 rows, so the stitch below reaches into this cell.
            for shift in [0.0, 1.0] {
                let t = base_v + shift; // position along the stitch, 0 = its bottom tip
                if t > 1.4 {
                    continue;
                }
                let along = t / 1.4;
                for side in [-1.0, 1.0] {
                    let centre = 0.5 + side * 0.38 * along;
                    let d = (x - centre) * (1.0f64 - 0.1 * side * along).max(0.5);
                    let p = profile(d, 0.2);
                    if p > 0.0 {
                        // Legs bulge in the middle and dive at both ends (under the
                        // neighbouring loops); a fine twist ridge runs along the yarn.
                        let bulge = (std::f64::consts::PI * along).sin();
                        let twist = 0.06 * (2.0 * std::f64::consts::PI * (6.0 * t + 8.0 * d)).sin();
                        let h = (0.25 + 0.75 * bulge) * p + twist * p;
                        if h > best.0 {
                            best = (h, 0);
                        }
                    }
                }
            }
            (best.0.clamp(0.0, 1.0), best.1)
        }
        Mesostructure::Leather { crease, .. } => {
            let crease = check_unit("crease", *crease, 1.0)?;
            // F2 - F1 of the periodic Voronoi diagram of the seeds.
            let p = DVec2::new(u, v);
            let (mut f1, mut f2) = (f64::INFINITY, f64::INFINITY);
            for s in seeds {
                let mut d = p - *s;
                d -= d.round();
                let r = d.length();
                if r < f1 {
                    f2 = f1;
                    f1 = r;
                } else if r < f2 {
                    f2 = r;
                }
            }
            let edge = (f2 - f1) * (seeds.len() as f64).sqrt();
            let c = (edge / crease.max(1e-6)).min(1.0);
            let top = c * c * (3.0 - 2.0 * c);
            // Slightly domed cells.
            let dome = 0.15 * (1.0 - f1 * (seeds.len() as f64).sqrt()).max(0.0);
            (0.85 * top + dome, if c < 0.6 { 1 } else { 0 })
        }
        Mesostructure::Ribs { ribs, pile, .. } => {
            let n = check_count("ribs", *ribs)?;
            let pile = check_unit("pile", *pile, 1.0)?;
            let s = u * n;
            let d = s - s.floor() - 0.5;
            let p = profile(d, 0.42);
            // Pile: tufts as a hash of a fine lattice, fixed per tile.
            let (a, b) = ((u * 97.0).floor() as u64, (v * 97.0).floor() as u64);
            let tuft = SampleStream::new(&[0x7069_6c65, a, b]).at(0);
            let h = p * (1.0 - 0.3 * pile) + 0.3 * pile * p * tuft;
            (h, if p > 0.3 { 0 } else { 1 })
        }
        Mesostructure::Bumps { radius, .. } => {
            let radius = check_unit("radius", *radius, 0.5)?;
            let p = DVec2::new(u, v);
            let mut h: f64 = 0.0;
            for s in seeds {
                let mut d = p - *s;
                d -= d.round();
                let q = d.length() / radius.max(1e-6);
                if q < 1.0 {
                    h = h.max((1.0 - q * q).sqrt());
                }
            }
            (h, if h > 0.0 { 0 } else { 1 })
        }
    })
}

/// The `count` seeded points of the Voronoi and bump patterns, in [0, 1)^2.
fn pattern_seeds(count: usize, seed: u64) -> Vec<DVec2> {
    (0..count)
        .map(|k| {
            let s = SampleStream::new(&[seed, 0x7365_6564, k as u64]);
            DVec2::new(s.at(0), s.at(1))
        })
        .collect()
}

fn build_field(
    m: &Mesostructure,
    width: u32,
    height: u32,
    detail: u32,
    seed: u64,
    dir: &Path,
) -> Result<HeightField, SynthErrorKind> {
    let (gw, gh) = ((width * detail) as usize, (height * detail) as usize);
    let (depth, seed_count) = match m {
        Mesostructure::Flat {} => (0.0, 0),
        Mesostructure::Weave { depth, .. }
        | Mesostructure::Knit { depth, .. }
        | Mesostructure::Ribs { depth, .. }
        | Mesostructure::Image { depth, .. } => (check_depth(*depth)?, 0),
        Mesostructure::Leather { depth, cells, .. } => {
            (check_depth(*depth)?, check_count("cells", *cells)? as usize)
        }
        Mesostructure::Bumps { depth, count, .. } => {
            (check_depth(*depth)?, check_count("count", *count)? as usize)
        }
    };
    let seeds = pattern_seeds(seed_count, seed);
    let mut heights = vec![0.0; gw * gh];
    let mut regions = vec![0u8; gw * gh];
    if let Mesostructure::Image {
        path,
        regions: region_path,
        ..
    } = m
    {
        let load = |what: &'static str, p: &Path| -> Result<Vec<f32>, SynthErrorKind> {
            let full = dir.join(p);
            let img = image::read_image(&full).map_err(|source| SynthErrorKind::Image {
                what,
                path: full.clone(),
                source,
            })?;
            if img.width() as usize != gw || img.height() as usize != gh {
                return Err(SynthErrorKind::ImageSize {
                    what,
                    path: full,
                    found_w: img.width(),
                    found_h: img.height(),
                    w: gw as u32,
                    h: gh as u32,
                });
            }
            // Image row 0 is the top; grid row 0 the bottom.
            let mut out = vec![0.0; gw * gh];
            for j in 0..gh {
                for i in 0..gw {
                    let px = img.get(i as u32, (gh - 1 - j) as u32);
                    out[j * gw + i] = (px[0] + px[1] + px[2]) / 3.0;
                }
            }
            Ok(out)
        };
        let h = load("height image", path)?;
        for (dst, src) in heights.iter_mut().zip(&h) {
            *dst = depth * f64::from(src.clamp(0.0, 1.0));
        }
        if let Some(rp) = region_path {
            // Region maps are 8-bit indices: read the PNG's stored value, not linear light.
            let g = load("region map", rp)?;
            for (dst, src) in regions.iter_mut().zip(&g) {
                let srgb = if *src <= 0.003_130_8 {
                    src * 12.92
                } else {
                    1.055 * src.powf(1.0 / 2.4) - 0.055
                };
                *dst = (srgb * 255.0).round().clamp(0.0, 255.0) as u8;
            }
        }
    } else {
        for j in 0..gh {
            for i in 0..gw {
                let u = (i as f64 + 0.5) / gw as f64;
                let v = (j as f64 + 0.5) / gh as f64;
                let (h, r) = procedural(m, u, v, &seeds)?;
                heights[j * gw + i] = depth * h;
                regions[j * gw + i] = r;
            }
        }
    }
    Ok(HeightField::new(
        gw,
        gh,
        f64::from(detail),
        heights,
        regions,
    ))
}

/// The local shading frame of a surface point: the SPMM frame rule around `n`, its
/// tangent turned by the region's `tangent_deg`.
fn shading_frame(n: DVec3, tangent_deg: f64) -> Frame {
    let f = Frame::from_normal_spmm(n);
    if tangent_deg == 0.0 {
        return f;
    }
    let (s, c) = tangent_deg.to_radians().sin_cos();
    let x = f.x * c + f.y * s;
    Frame {
        x,
        y: n.cross(x),
        z: n,
    }
}

/// One view-ray hit of a texel sample, with what every light needs.
struct Hit {
    p: DVec3,
    frame: Frame,
    region: usize,
    wo_local: DVec3,
    /// Inter-reflection gathers: grid index of the point seen and the RGB factor
    /// f(wg, wo) * pi / N of the cosine-distributed gather ray.
    gathers: Vec<(usize, DVec3)>,
}

/// Progress of a synthesis, texels done (for a progress bar).
pub type Progress<'a> = &'a (dyn Fn(usize, usize) + Sync);

/// Ray traces the BTF of `setup`. `cancel` is checked between texels; `progress` gets
/// (texels done, texels in all).
pub fn synthesize(
    setup: &SynthSetup,
    cancel: &AtomicBool,
    progress: Progress,
) -> Result<Btf, SynthErrorKind> {
    let field = &setup.field;
    let (nl, nv) = (setup.light_dirs.len(), setup.view_dirs.len());
    let texels = setup.width as usize * setup.height as usize;
    let ss = setup.supersample as usize;
    let n_gather = setup.interreflection_samples as usize;

    // Outgoing diffuse radiance of every height sample under each light (unit
    // irradiance perpendicular to the light), for the inter-reflection bounce.
    let bounce: Vec<DVec3> = if n_gather > 0 {
        let g = field.grid_w * field.grid_h;
        (0..nl * g)
            .into_par_iter()
            .map(|k| {
                let (l, idx) = (k / g, k % g);
                let (i, j) = (idx % field.grid_w, idx / field.grid_w);
                let xy = DVec2::new(
                    (i as f64 + 0.5) / field.detail,
                    (j as f64 + 0.5) / field.detail,
                );
                let n = field.normal(xy);
                let wi = setup.light_dirs[l];
                let cos = n.dot(wi);
                if cos <= 0.0 {
                    return DVec3::ZERO;
                }
                let p = DVec3::new(xy.x, xy.y, field.height(xy));
                if field.occluded(p, wi) {
                    return DVec3::ZERO;
                }
                setup.regions[usize::from(field.regions[idx])].diffuse_albedo()
                    * (cos / std::f64::consts::PI)
            })
            .collect()
    } else {
        Vec::new()
    };

    let z_mid = 0.5 * (field.h_min + field.h_max);
    let z_top = field.h_max + 1e-6;
    let done = AtomicUsize::new(0);
    let per_texel = nl * nv * 3;
    let mut data = vec![0.0f32; texels * per_texel];
    data.par_chunks_mut(per_texel)
        .enumerate()
        .try_for_each(|(t, out)| {
            if cancel.load(Ordering::Relaxed) {
                return Err(SynthErrorKind::Cancelled);
            }
            let (col, row) = (t % setup.width as usize, t / setup.width as usize);
            // Row 0 is the top of the texture; y points up.
            let y0 = (setup.height as usize - 1 - row) as f64;
            let mut acc = vec![DVec3::ZERO; nl * nv];
            for (v, &wo) in setup.view_dirs.iter().enumerate() {
                for sub in 0..ss * ss {
                    let (a, b) = (sub % ss, sub / ss);
                    // Sub-sample points sit a quarter sub-sample-cell of the height grid
                    // off the centres, which never falls on a region-cell edge
                    // (detail (2a + 1) / 2ss + 1 / 4ss is never an integer): on an edge
                    // the hit point's tiny direction-dependent offset chose the region.
                    let off = 0.25 / (ss as f64 * field.detail);
                    let q = DVec3::new(
                        col as f64 + (a as f64 + 0.5) / ss as f64 + off,
                        y0 + (b as f64 + 0.5) / ss as f64 + off,
                        z_mid,
                    );
                    let o = q + wo * ((z_top - z_mid) / wo.z);
                    let Some(p) = field.intersect_down(o, -wo) else {
                        continue;
                    };
                    let n = field.normal(p.truncate());
                    let region = field.region(p.truncate());
                    let frame = shading_frame(n, setup.regions[region].tangent_deg);
                    let wo_local = frame.to_local(wo);
                    let mut hit = Hit {
                        p,
                        frame,
                        region,
                        wo_local,
                        gathers: Vec::new(),
                    };
                    if n_gather > 0 {
                        let key = [setup.seed, t as u64, v as u64, sub as u64];
                        let stream = SampleStream::new(&key);
                        for k in 0..n_gather {
                            let u =
                                DVec2::new(stream.at(2 * k as u64), stream.at(2 * k as u64 + 1));
                            let wg_local = warp::cosine_hemisphere(u);
                            let wg = frame.to_world(wg_local);
                            // Rays into the hemisphere that point downwards (on a slope)
                            // surely meet the surface; upward ones may leave the slab.
                            if let Some(qxy) = field.gather_hit(p, wg) {
                                let gi = ((qxy.x * field.detail).floor() as isize)
                                    .rem_euclid(field.grid_w as isize)
                                    as usize;
                                let gj = ((qxy.y * field.detail).floor() as isize)
                                    .rem_euclid(field.grid_h as isize)
                                    as usize;
                                let f = setup.regions[region].eval_local(wg_local, wo_local);
                                hit.gathers.push((
                                    gj * field.grid_w + gi,
                                    f * (std::f64::consts::PI / n_gather as f64),
                                ));
                            }
                        }
                    }
                    shade_lights(setup, &hit, v, &bounce, &mut acc);
                }
            }
            let scale = 1.0 / (ss * ss) as f64;
            for (k, value) in acc.iter().enumerate() {
                let rgb = *value * scale;
                out[k * 3] = rgb.x as f32;
                out[k * 3 + 1] = rgb.y as f32;
                out[k * 3 + 2] = rgb.z as f32;
            }
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(d, texels);
            Ok(())
        })?;
    Ok(Btf::new(
        setup.name.clone(),
        setup.provenance.clone(),
        setup.width,
        setup.height,
        setup.light_dirs.clone(),
        setup.view_dirs.clone(),
        data,
    )?)
}

/// Adds the direct (shadowed) and bounced light of every light direction at one hit.
fn shade_lights(setup: &SynthSetup, hit: &Hit, v: usize, bounce: &[DVec3], acc: &mut [DVec3]) {
    let nv = setup.view_dirs.len();
    let g = setup.field.grid_w * setup.field.grid_h;
    let region = &setup.regions[hit.region];
    for (l, &wi) in setup.light_dirs.iter().enumerate() {
        let mut rgb = DVec3::ZERO;
        let cos = hit.frame.z.dot(wi);
        if cos > 0.0 && !setup.field.occluded(hit.p, wi) {
            rgb += region.eval_local(hit.frame.to_local(wi), hit.wo_local) * cos;
        }
        for &(idx, factor) in &hit.gathers {
            rgb += bounce[l * g + idx] * factor;
        }
        acc[l * nv + v] += rgb;
    }
}

#[cfg(test)]
mod tests;
