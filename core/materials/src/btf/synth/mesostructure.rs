//! The procedural mesostructures of a recipe (weave, knit, leather, ribs, bumps, a grey
//! image) and how each becomes a `HeightField` with its region map. Its own module:
//! the patterns are the bulk of the recipe's meaning, apart from the file's parsing and
//! from the ray tracing.

use std::path::{Path, PathBuf};

use glam::DVec2;
use serde::Deserialize;

use super::height_field::HeightField;
use super::{SynthErrorKind, value_err};
use crate::image;
use crate::rng::SampleStream;

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
pub(super) fn procedural(
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
pub(super) fn pattern_seeds(count: usize, seed: u64) -> Vec<DVec2> {
    (0..count)
        .map(|k| {
            let s = SampleStream::new(&[seed, 0x7365_6564, k as u64]);
            DVec2::new(s.at(0), s.at(1))
        })
        .collect()
}

pub(super) fn build_field(
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
