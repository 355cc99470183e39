//! BTF synthesis by ray tracing a height-field mesostructure patch, the way Sloan et al.
//! 2003 (section 4.2) built their weave and stucco BTFs: for each texel, view direction
//! and sub-texel sample, a view ray through the patch's mid-depth sampling plane is
//! marched against the tiled height field (it may enter neighbouring tiles), the hit is
//! shaded with its region's analytic BRDFs times the cosine, with a shadow ray towards
//! the light and, optionally, one diffuse inter-reflection bounce gathered with
//! cosine-distributed rays. No refraction, no volumetric fibres, no multiple bounces.
//!
//! The recipe file and its checks are in `recipe.rs`, the procedural mesostructures
//! in `mesostructure.rs`, the height field's ray marching in `height_field.rs`; this
//! module holds what they share (the errors, the regions' BRDFs, the setup) and the
//! synthesis itself.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::{Btf, BtfError};
use crate::brdf::{AnalyticBrdf, BrdfError, BrdfModel, Frame, warp};
use crate::image::ImageError;
use crate::rng::SampleStream;

mod height_field;
mod mesostructure;
mod recipe;

pub use height_field::HeightField;
pub use mesostructure::Mesostructure;
#[cfg(test)]
use mesostructure::{pattern_seeds, procedural};
#[cfg(test)]
use recipe::RecipeFile;
pub use recipe::{load_recipe, parse_recipe};

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
    #[error(
        "`directions` = `{0}`: the named layouts are `bonn81` and `ubo151` (or give `direction_rings`)"
    )]
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
