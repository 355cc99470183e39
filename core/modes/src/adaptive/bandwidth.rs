//! The precomputed bandwidths the adaptive mode propagates (Bagher et al. 2013,
//! section 2.3): a material's angular bandwidth per pair of directions (16 x 16 fixed
//! directions, each lobe imaged at `LOBE_RES`^2 and analysed by `wavelet`, reduced to
//! 16 x 16 by max), the environment map's angular bandwidth per map pixel, and an
//! area light's spatial bandwidth over its surface (zero-padded to twice its size, as
//! the paper does). All rates are Nyquist rates: samples per radian or per metre.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::sync::{Mutex, PoisonError};

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::wavelet::{Pyramid, max_blocks};
use meso_materials::angle::atan2;
use meso_materials::brdf::BasisFunction;
use meso_materials::image::{Image, luminance};
use meso_materials::spmm::SpmmMaterial;
use meso_render::environment::pixel_of;
use meso_render::scene::{Environment, Light, Material};

/// Fixed directions per side (theta x phi) and stored outgoing cells per side.
pub const GRID: usize = 16;
/// Side of each analysed lobe image (azimuthal equidistant over the hemisphere).
pub const LOBE_RES: usize = 128;
/// Rec. 709 luminance.
const LUMINANCE: DVec3 = DVec3::new(0.2126, 0.7152, 0.0722);

/// Cluster lobes remembered (`MaterialBandwidth::of_cluster`): 256 KB each.
const CLUSTER_CACHE: usize = 64;

/// The polar angle of local direction `w` (0 at the normal, pi/2 at and below the
/// horizon) and its azimuth's cosine and sine (1 and 0 at the pole). The fast
/// `atan2` (within 2e-13 rad) and no sine or cosine: the bandwidth pass looks up
/// several directions per stratum.
fn polar(w: DVec3) -> (f64, f64, f64) {
    let rho = (w.x * w.x + w.y * w.y).sqrt();
    let theta = atan2(rho, w.z.max(0.0));
    if rho > 0.0 {
        (theta, w.x / rho, w.y / rho)
    } else {
        (theta, 1.0, 0.0)
    }
}

/// The cell of the fixed-direction grid holding local direction `w` (upper hemisphere).
fn grid_cell(w: DVec3) -> usize {
    grid_cell_at(w, polar(w).0)
}

/// `grid_cell` of `w` whose polar angle `theta` is known.
fn grid_cell_at(w: DVec3, theta: f64) -> usize {
    let phi = atan2(w.y, w.x).rem_euclid(TAU);
    let t = ((theta / FRAC_PI_2 * GRID as f64) as usize).min(GRID - 1);
    let p = ((phi / TAU * GRID as f64) as usize).min(GRID - 1);
    t * GRID + p
}

/// The centre direction of grid cell (t, p).
fn grid_direction(t: usize, p: usize) -> DVec3 {
    let theta = (t as f64 + 0.5) / GRID as f64 * FRAC_PI_2;
    let phi = (p as f64 + 0.5) / GRID as f64 * TAU;
    DVec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

/// The azimuthal equidistant image coordinates in [0, 1)^2 of local direction `w`.
fn lobe_coords((theta, cos_phi, sin_phi): (f64, f64, f64)) -> (f64, f64) {
    let r = theta / FRAC_PI_2;
    (0.5 + 0.5 * r * cos_phi, 0.5 + 0.5 * r * sin_phi)
}

/// The lobe-image pixel (row-major on the `GRID`^2 grid) that a local direction falls
/// in, from its `polar` angles.
fn lobe_pixel_at(angles: (f64, f64, f64)) -> usize {
    let (u, v) = lobe_coords(angles);
    let x = ((u * GRID as f64) as usize).min(GRID - 1);
    let y = ((v * GRID as f64) as usize).min(GRID - 1);
    y * GRID + x
}

/// Where a local direction falls in a `MaterialBandwidth`'s tables, as a fixed
/// direction (its cell) and as a lobe's argument (its pixel): the trigonometry of
/// a lookup, done once per direction.
#[derive(Clone, Copy, Debug)]
pub struct LobeIndex {
    cell: usize,
    pixel: usize,
}

impl LobeIndex {
    pub fn of(w: DVec3) -> Self {
        // One `polar` for both tables.
        let angles = polar(w);
        Self {
            cell: grid_cell_at(w, angles.0),
            pixel: lobe_pixel_at(angles),
        }
    }
}

/// The direction at the centre of lobe pixel (x, y) of a `res`^2 image; outside the
/// disc, the horizon direction of the same azimuth (so the image has no false edge).
fn lobe_direction(x: usize, y: usize, res: usize) -> DVec3 {
    let u = (x as f64 + 0.5) / res as f64 * 2.0 - 1.0;
    let v = (y as f64 + 0.5) / res as f64 * 2.0 - 1.0;
    let r = u.hypot(v);
    let theta = (r * FRAC_PI_2).min(FRAC_PI_2 - 1e-3);
    let phi = v.atan2(u);
    DVec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

/// A material's angular bandwidth: for each fixed direction (one of `GRID`^2), the
/// rate map of the BRDF lobe over the other direction, `GRID`^2 cells, in samples per
/// radian. Symmetric use: by reciprocity the lobe of `wo` over `wi` is the lobe of
/// `wi` over `wo`.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialBandwidth {
    rates: Vec<f32>,
}

/// Texture positions at which a `btf` material's lobes are analysed (its texels differ;
/// the widest lobe of these stands for all).
const TABLE_TEXELS: [DVec2; 5] = [
    DVec2::new(0.5, 0.5),
    DVec2::new(0.25, 0.25),
    DVec2::new(0.75, 0.25),
    DVec2::new(0.25, 0.75),
    DVec2::new(0.75, 0.75),
];

impl MaterialBandwidth {
    /// Analyses `f(wi, wo)` (luminance, 1/sr) over `GRID`^2 fixed directions `wo`.
    pub fn analyse(f: impl Fn(DVec3, DVec3) -> f64 + Sync) -> Self {
        let pixel_rad = PI / LOBE_RES as f64;
        let rates: Vec<f32> = (0..GRID * GRID)
            .into_par_iter()
            .flat_map_iter(|fixed| {
                let wo = grid_direction(fixed / GRID, fixed % GRID);
                let lobe: Vec<f64> = (0..LOBE_RES * LOBE_RES)
                    .map(|i| f(lobe_direction(i % LOBE_RES, i / LOBE_RES, LOBE_RES), wo))
                    .collect();
                let map = Pyramid::new(LOBE_RES, LOBE_RES, &lobe).rate_map();
                max_blocks(&map, LOBE_RES, LOBE_RES, GRID, GRID)
                    .into_iter()
                    .map(move |r| (r / pixel_rad) as f32)
            })
            .collect();
        Self { rates }
    }

    /// The bandwidth of a scene material (its luminance; a MERL table looked up
    /// trilinearly, so its cells' steps are not taken for the BRDF's own detail);
    /// `None` for materials the mode does not shade.
    pub fn of_material(m: &Material) -> Option<Self> {
        match m {
            Material::Brdf { brdf, .. } => Some(Self::analyse(|wi, wo| brdf.eval(wi, wo))),
            Material::Merl { brdf, .. } => Some(Self::analyse(|wi, wo| {
                brdf.eval_trilinear(wi, wo).dot(LUMINANCE)
            })),
            Material::Spmm { material, .. } => Some(Self::of_pack(material)),
            Material::Btf { table, .. } => Some(Self::widest(TABLE_TEXELS.iter().map(|&uv| {
                Self::analyse(|wi, wo| table.eval_uv(uv, DVec2::ONE, wi, wo).dot(LUMINANCE))
            }))),
            Material::Mirror { .. } => None,
        }
    }

    /// A pack's bandwidth: per cluster, the lobe of its bases weighted by their mean
    /// luminance weight over the cluster's texels (what a typical texel of it
    /// reflects), and per direction the widest of the clusters'. The residual is left
    /// out: it is tabulated on the measured directions (the Bonn layout's 15 degrees
    /// apart), far coarser than the bases' lobes.
    fn of_pack(pack: &SpmmMaterial) -> Self {
        let clusters = pack.clusters();
        let mut sums: Vec<Vec<f64>> = clusters.iter().map(|c| vec![0.0; c.bases.len()]).collect();
        let mut texels = vec![0usize; clusters.len()];
        for (t, &c) in pack.texel_cluster().iter().enumerate() {
            let c = c as usize;
            texels[c] += 1;
            for (j, rgb) in pack.texel_weights(t) {
                let lum = LUMINANCE.dot(DVec3::new(rgb[0].into(), rgb[1].into(), rgb[2].into()));
                sums[c][j as usize] += lum;
            }
        }
        Self::widest(clusters.iter().enumerate().map(|(c, cluster)| {
            let n = texels[c].max(1) as f64;
            let weights: Vec<f64> = sums[c].iter().map(|s| s / n).collect();
            Self::of_cluster(&cluster.bases, &weights)
        }))
    }

    /// One cluster's lobe (its bases with these mean weights), remembered for the
    /// last `CLUSTER_CACHE` clusters analysed in this process: an edit of one
    /// cluster of a pack analyses that cluster again, not the others.
    fn of_cluster(bases: &[BasisFunction], weights: &[f64]) -> Self {
        type Entry = (Vec<BasisFunction>, Vec<f64>, MaterialBandwidth);
        static CACHE: Mutex<Vec<Entry>> = Mutex::new(Vec::new());
        let lock = || CACHE.lock().unwrap_or_else(PoisonError::into_inner);
        let found = lock()
            .iter()
            .find(|(b, w, _)| b == bases && w == weights)
            .map(|e| e.2.clone());
        if let Some(bandwidth) = found {
            return bandwidth;
        }
        let bandwidth = Self::analyse(|wi, wo| {
            bases
                .iter()
                .zip(weights)
                .map(|(b, w)| w * b.eval(wi, wo))
                .sum()
        });
        let mut cache = lock();
        if cache.len() >= CLUSTER_CACHE {
            cache.remove(0);
        }
        cache.push((bases.to_vec(), weights.to_vec(), bandwidth.clone()));
        bandwidth
    }

    /// Per direction, the largest rate of `each`.
    fn widest(each: impl Iterator<Item = Self>) -> Self {
        each.reduce(|a, b| Self {
            rates: a
                .rates
                .iter()
                .zip(&b.rates)
                .map(|(x, y)| x.max(*y))
                .collect(),
        })
        // No analysis (a pack without clusters): a constant lobe.
        .unwrap_or_else(|| Self::analyse(|_, _| 0.0))
    }

    /// The rate (samples per radian) of the lobe of `fixed` around direction `at`,
    /// both local and in the upper hemisphere, each placed in the tables once
    /// (`LobeIndex::of`): the bandwidth pass looks each of its directions up both
    /// ways against the pixel's view.
    pub fn rate_of(&self, fixed: LobeIndex, at: LobeIndex) -> f64 {
        f64::from(self.rates[fixed.cell * GRID * GRID + at.pixel])
    }

    /// The rates, `GRID`^2 per fixed direction (row-major by its cell), each over the
    /// lobe's `GRID`^2 pixels.
    pub fn rates(&self) -> &[f32] {
        &self.rates
    }

    /// The highest rate of the lobe of `fixed` (local, upper hemisphere).
    pub fn peak(&self, fixed: DVec3) -> f64 {
        let c = grid_cell(fixed);
        f64::from(
            self.rates[c * GRID * GRID..(c + 1) * GRID * GRID]
                .iter()
                .copied()
                .fold(0.0f32, f32::max),
        )
    }

    /// The mean over fixed directions of the lobe's highest rate: one number to
    /// compare materials by (a lobe's peak region sets how finely it must be sampled).
    pub fn mean_peak(&self) -> f64 {
        self.rates
            .chunks(GRID * GRID)
            .map(|lobe| f64::from(lobe.iter().copied().fold(0.0f32, f32::max)))
            .sum::<f64>()
            / (GRID * GRID) as f64
    }
}

/// The largest factor by which a lat-long pixel's width shrinks towards the poles that
/// the analysis believes (1 / sin theta up to this): the rows nearest the poles hold
/// few distinct directions and would otherwise claim unbounded frequencies.
const MIN_SIN_THETA: f64 = 0.1;

/// The environment's angular bandwidth per map pixel (samples per radian), in map
/// space; `turn` applies the scene's rotation on lookup.
#[derive(Clone, Debug)]
pub struct EnvironmentBandwidth {
    width: u32,
    height: u32,
    rates: Vec<f32>,
}

impl EnvironmentBandwidth {
    pub fn analyse(map: &Image) -> Self {
        let (w, h) = (map.width() as usize, map.height() as usize);
        let lum: Vec<f64> = map
            .pixels()
            .iter()
            .map(|p| f64::from(luminance(*p)))
            .collect();
        let map_rates = Pyramid::new(w, h, &lum).rate_map();
        // Eq. of section 2.3: rate per pixel over the pixel's angular size; the
        // Jacobian's larger eigenvalue is the narrower of its two sides.
        let rates = map_rates
            .iter()
            .enumerate()
            .map(|(i, &r)| {
                let y = i / w;
                let theta = (y as f64 + 0.5) / h as f64 * PI;
                let across = TAU / w as f64 * theta.sin().max(MIN_SIN_THETA);
                let down = PI / h as f64;
                (r / across.min(down)) as f32
            })
            .collect();
        Self {
            width: w as u32,
            height: h as u32,
            rates,
        }
    }

    /// The rate seen in world direction `dir` (unit) under `env`'s rotation.
    pub fn rate(&self, env: &Environment, dir: DVec3) -> f64 {
        self.rate_in_map(meso_render::environment::rotate_y(dir, -env.rotate_y_deg))
    }

    /// The rate seen in map-space direction `d` (unit): `rate` once the caller has
    /// turned the direction into the map.
    pub fn rate_in_map(&self, d: DVec3) -> f64 {
        let (x, y) = pixel_of(self.width, self.height, d);
        f64::from(self.rates[(y * self.width + x) as usize])
    }

    /// Width, height and rates per map pixel (row-major), in map space.
    pub fn table(&self) -> (u32, u32, &[f32]) {
        (self.width, self.height, &self.rates)
    }

    /// The largest rate of the map (0 for a constant map).
    pub fn max(&self) -> f64 {
        self.rates.iter().copied().fold(0.0f32, f32::max) as f64
    }
}

/// Samples per side of an area light's image before padding.
pub const LIGHT_RES: usize = 32;

/// An area light's spatial bandwidth over its surface (samples per metre), on a
/// `LIGHT_RES`^2 grid over (u, v) in [0, 1)^2.
#[derive(Clone, Debug)]
pub struct LightBandwidth {
    rates: Vec<f32>,
}

impl LightBandwidth {
    /// Constant radiance over the parallelogram, zero-padded to twice its size so that
    /// its border counts (section 2.3), analysed, and cropped back.
    pub fn analyse(light: &Light) -> Option<Self> {
        let Light::Area { edge_u, edge_v, .. } = *light else {
            return None;
        };
        let n = 2 * LIGHT_RES;
        let pad = LIGHT_RES / 2;
        let inside = |i: usize| (pad..pad + LIGHT_RES).contains(&i);
        let img: Vec<f64> = (0..n * n)
            .map(|i| f64::from(u8::from(inside(i % n) && inside(i / n))))
            .collect();
        let map = Pyramid::new(n, n, &img).rate_map();
        let pixel_m = (edge_u.length() / LIGHT_RES as f64).min(edge_v.length() / LIGHT_RES as f64);
        let rates = (0..LIGHT_RES * LIGHT_RES)
            .map(|i| {
                let (x, y) = (i % LIGHT_RES + pad, i / LIGHT_RES + pad);
                (map[y * n + x] / pixel_m.max(1e-12)) as f32
            })
            .collect();
        Some(Self { rates })
    }

    /// The rates, `LIGHT_RES`^2 over (u, v), row-major in v.
    pub fn rates(&self) -> &[f32] {
        &self.rates
    }

    /// The rate at light coordinates (u, v) in [0, 1)^2.
    pub fn rate(&self, u: f64, v: f64) -> f64 {
        let x = ((u * LIGHT_RES as f64) as usize).min(LIGHT_RES - 1);
        let y = ((v * LIGHT_RES as f64) as usize).min(LIGHT_RES - 1);
        f64::from(self.rates[y * LIGHT_RES + x])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::brdf::{AnalyticBrdf, BrdfModel};

    fn cook_torrance(m: f64) -> AnalyticBrdf {
        AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", m), ("f0", 0.9)]).expect("valid")
    }

    fn merl_of(brdf: &AnalyticBrdf) -> Material {
        Material::Merl {
            brdf: std::sync::Arc::new(
                meso_materials::merl::tabulate(brdf, DVec3::ONE).expect("tabulates"),
            ),
            tint: DVec3::ONE,
        }
    }

    #[test]
    fn lambertian_below_rough_below_sharp_and_monotone_in_roughness_for_tabulated_cook_torrance() {
        let lambert = MaterialBandwidth::of_material(&merl_of(&AnalyticBrdf::with_defaults(
            BrdfModel::Lambertian,
        )))
        .expect("merl")
        .mean_peak();
        let means: Vec<f64> = [0.6, 0.3, 0.15, 0.075]
            .iter()
            .map(|&m| {
                MaterialBandwidth::of_material(&merl_of(&cook_torrance(m)))
                    .expect("merl")
                    .mean_peak()
            })
            .collect();
        eprintln!("lambertian {lambert}, cook-torrance m = 0.6 .. 0.075: {means:?}");
        assert!(lambert < means[0], "{lambert} {means:?}");
        assert!(means.windows(2).all(|w| w[0] < w[1]), "{means:?}");
    }

    #[test]
    fn an_analytic_lambertian_has_zero_bandwidth() {
        let b = MaterialBandwidth::of_material(&Material::Brdf {
            brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
            albedo: DVec3::ONE,
        })
        .expect("brdf");
        assert_eq!(b.mean_peak(), 0.0);
    }

    #[test]
    fn a_sharp_lobe_is_wide_band_around_its_peak_and_not_far_from_it() {
        let b = MaterialBandwidth::of_material(&Material::Brdf {
            brdf: cook_torrance(0.05),
            albedo: DVec3::ONE,
        })
        .expect("brdf");
        // The plain definition: the fixed direction's cell, the lobe pixel of `at`.
        let rate = |fixed: DVec3, at: DVec3| {
            f64::from(b.rates[grid_cell(fixed) * GRID * GRID + lobe_pixel_at(polar(at))])
        };
        let wo = DVec3::new(0.5f64.sin(), 0.0, 0.5f64.cos());
        let mirror = DVec3::new(-wo.x, -wo.y, wo.z);
        let far = DVec3::new(0.0, 0.9f64.sin(), 0.9f64.cos());
        assert!(rate(wo, mirror) > 4.0 * rate(wo, far).max(1e-9) || rate(wo, far) == 0.0);
        assert!(rate(wo, mirror) > 10.0, "{}", rate(wo, mirror));
        // Directions placed once give the plain definition's lookups, both ways round.
        let mut rng = meso_materials::rng::SampleStream::new(&[11]);
        for _ in 0..500 {
            let a = meso_materials::brdf::warp::cosine_hemisphere(rng.next_2d());
            let c = meso_materials::brdf::warp::cosine_hemisphere(rng.next_2d());
            let (ia, ic) = (LobeIndex::of(a), LobeIndex::of(c));
            assert_eq!(b.rate_of(ia, ic).to_bits(), rate(a, c).to_bits());
            assert_eq!(b.rate_of(ic, ia).to_bits(), rate(c, a).to_bits());
        }
    }

    #[test]
    fn a_constant_environment_has_zero_bandwidth_and_a_sharp_one_does_not() {
        let mut map = Image::new(64, 32);
        map.pixels_mut()
            .iter_mut()
            .for_each(|p| *p = [2.0, 2.0, 2.0]);
        assert_eq!(EnvironmentBandwidth::analyse(&map).max(), 0.0);
        map.set(20, 10, [100.0, 100.0, 100.0]);
        let b = EnvironmentBandwidth::analyse(&map);
        // At the bright pixel: the finest level, one sample per pixel of 2 pi / 64 rad
        // across (sin theta < 1 at row 10 makes it narrower, a higher rate).
        let theta = 10.5 / 32.0 * PI;
        let expected = 1.0 / (TAU / 64.0 * theta.sin()).min(PI / 32.0);
        let env = Environment {
            map: std::sync::Arc::new(map.clone()),
            strength: 1.0,
            rotate_y_deg: 0.0,
            mis: true,
        };
        let dir = meso_render::environment::direction_at(20.5 / 64.0, 10.5 / 32.0);
        let got = b.rate(&env, dir);
        assert!((got - expected).abs() < 1e-3 * expected, "{got} {expected}");
        // Far from it the map is flat at the finest levels.
        let far = meso_render::environment::direction_at(52.5 / 64.0, 26.5 / 32.0);
        assert!(b.rate(&env, far) < got / 4.0, "{}", b.rate(&env, far));
    }

    #[test]
    fn an_area_light_is_wide_band_at_its_border_and_its_rates_scale_with_its_size() {
        let light = |s: f64| Light::Area {
            corner: DVec3::ZERO,
            edge_u: DVec3::X * s,
            edge_v: DVec3::Z * s,
            radiance: DVec3::ONE,
        };
        let b = LightBandwidth::analyse(&light(1.0)).expect("area");
        let b2 = LightBandwidth::analyse(&light(2.0)).expect("area");
        assert!(b.rate(0.01, 0.5) >= b.rate(0.5, 0.5));
        assert!(b.rate(0.01, 0.5) > 0.0);
        assert!((b.rate(0.01, 0.5) - 2.0 * b2.rate(0.01, 0.5)).abs() < 1e-4);
    }
}
