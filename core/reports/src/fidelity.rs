//! How well a fitted pack reproduces its BTF (`meso report fit`): in table space (the
//! pack evaluated at the BTF's tabulated direction pairs, split into grazing pairs,
//! where light or view is more than 60 degrees from the normal, and the rest) and in
//! images (one scene rendered by the spmm mode once with the BTF as a `btf` material
//! and once with the pack in its place, the same random numbers for both: the two
//! materials sample alike, so the difference is the material's, not the noise's).
//!
//! Between its tabulated directions a `btf` material interpolates, while a pack's basis
//! sum is analytic everywhere: even a pack equal to the BTF at every tabulated pair
//! renders differently. A third render, the pack tabulated at the BTF's pairs and shown
//! as a `btf` material (`tabulate_pack`), splits the image error into the fit's part
//! (BTF against that tabulation: both interpolated alike) and the interpolation's part
//! (the tabulation against the pack), which no fit can remove.

use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use crate::regress::case::substitute;
use meso_materials::btf::Btf;
use meso_materials::btf::table::BtfTable;
use meso_materials::btf::texels::TexelSource;
use meso_materials::image::Image;
use meso_materials::metrics::{MetricsError, compare};
use meso_materials::spmm::SpmmMaterial;
use meso_modes::trace::{PackSampling, SpmmMode};
use meso_render::RenderModeExt;
use meso_render::scene::{Material, Scene};
use meso_render::{ModeError, RenderMode};

/// Polar angle beyond which a direction counts as grazing, degrees.
pub const GRAZING_DEG: f64 = 60.0;

/// The pack against the BTF at the BTF's direction pairs (every texel, every pair,
/// RGB), RMSE relative to the BTF's mean value.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct TableErrors {
    pub mean_reflectance: f64,
    pub relative_rmse: f64,
    /// Pairs with light or view beyond `GRAZING_DEG`.
    pub grazing_relative_rmse: f64,
    pub elsewhere_relative_rmse: f64,
    /// Fraction of the pairs that are grazing.
    pub grazing_fraction: f64,
    /// Same without the residual (the basis sum alone).
    pub basis_relative_rmse: f64,
}

#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum FidelityError {
    #[error(
        "the pack's texel grid {pack_width}x{pack_height} differs from the BTF's {btf_width}x{btf_height}: it was not fitted to this BTF"
    )]
    GridMismatch {
        btf_width: u32,
        btf_height: u32,
        pack_width: u32,
        pack_height: u32,
    },
    #[error("{0}")]
    Scene(String),
    #[error("{0}")]
    Mode(String),
    #[error("{0}")]
    Metrics(String),
    /// The BTF's values could not be read (the reader names the file and texel).
    #[error("{0}")]
    Read(String),
}

fn grazing(d: DVec3) -> bool {
    d.z < GRAZING_DEG.to_radians().cos()
}

fn check_grid(btf: &dyn TexelSource, pack: &SpmmMaterial) -> Result<(), FidelityError> {
    if (btf.width(), btf.height()) != (pack.width(), pack.height()) {
        return Err(FidelityError::GridMismatch {
            btf_width: btf.width(),
            btf_height: btf.height(),
            pack_width: pack.width(),
            pack_height: pack.height(),
        });
    }
    Ok(())
}

/// Table-space errors of `pack` against `btf` (same texel grid), the BTF read
/// `block_texels` texels at a time (`meso report fit --max-memory`). Each texel's sums
/// are added up in texel order, so the result does not depend on the block size.
pub fn table_errors(
    btf: &dyn TexelSource,
    pack: &SpmmMaterial,
    block_texels: usize,
) -> Result<TableErrors, FidelityError> {
    check_grid(btf, pack)?;
    let (lights, views) = (btf.light_dirs(), btf.view_dirs());
    let per_texel = btf.pairs() * 3;
    let block_texels = block_texels.clamp(1, btf.texels());
    let mut buf = vec![0.0f32; block_texels * per_texel];
    // Per texel: squared errors (grazing, elsewhere, basis only) and its values' sum.
    let mut sums = Vec::with_capacity(btf.texels());
    for first in (0..btf.texels()).step_by(block_texels) {
        let n = block_texels.min(btf.texels() - first);
        let block = &mut buf[..n * per_texel];
        btf.read_texels(first, block).map_err(FidelityError::Read)?;
        let mut part = Vec::new();
        block
            .par_chunks(per_texel)
            .enumerate()
            .map(|(i, values)| texel_sums(pack, lights, views, first + i, values))
            .collect_into_vec(&mut part);
        sums.extend(part);
    }
    let sums = sums.iter().fold([0.0f64; 4], |a, b| {
        [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]]
    });
    let graze_pairs = lights
        .iter()
        .flat_map(|&l| views.iter().map(move |&v| grazing(l) || grazing(v)))
        .filter(|&g| g)
        .count();
    let pairs = btf.pairs();
    let values = |pairs: usize| (btf.texels() * pairs * 3).max(1) as f64;
    let mean = sums[3] / values(pairs);
    let rel = |sum: f64, pairs: usize| (sum / values(pairs)).sqrt() / mean;
    Ok(TableErrors {
        mean_reflectance: mean,
        relative_rmse: rel(sums[0] + sums[1], pairs),
        grazing_relative_rmse: if graze_pairs > 0 {
            rel(sums[0], graze_pairs)
        } else {
            0.0
        },
        elsewhere_relative_rmse: if graze_pairs < pairs {
            rel(sums[1], pairs - graze_pairs)
        } else {
            0.0
        },
        grazing_fraction: graze_pairs as f64 / pairs as f64,
        basis_relative_rmse: rel(sums[2], pairs),
    })
}

/// One texel's squared errors (grazing pairs, the others, the basis sum alone) and
/// the sum of its values.
fn texel_sums(
    pack: &SpmmMaterial,
    lights: &[DVec3],
    views: &[DVec3],
    t: usize,
    values: &[f32],
) -> [f64; 4] {
    let mut s = [0.0f64; 4];
    let pairs = lights
        .iter()
        .flat_map(|&wi| views.iter().map(move |&wo| (wi, wo)));
    for ((wi, wo), rgb) in pairs.zip(values.chunks_exact(3)) {
        let want = DVec3::new(rgb[0].into(), rgb[1].into(), rgb[2].into());
        let full = pack.eval_texel(t, wi, wo, true, usize::MAX);
        let basis = pack.eval_texel(t, wi, wo, false, 0);
        let e = (full - want).length_squared();
        s[if grazing(wi) || grazing(wo) { 0 } else { 1 }] += e;
        s[2] += (basis - want).length_squared();
        s[3] += want.x + want.y + want.z;
    }
    s
}

/// Image error of the pack's render against the BTF's.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct ImageErrors {
    /// RMSE over pixels and channels divided by the BTF image's mean value.
    pub relative_rmse: f64,
    pub rmse: f64,
    /// `meso compare`'s PSNR (peak 1); `None` for identical images.
    pub psnr_db: Option<f64>,
    pub mssim: f64,
}

/// `meso compare` of `pack` against the reference `btf`, plus the relative RMSE.
pub fn image_errors(btf: &Image, pack: &Image) -> Result<ImageErrors, MetricsError> {
    let c = compare(btf, pack, 0.0)?;
    let n = btf.pixels().len().max(1) as f64 * 3.0;
    let mean: f64 = btf
        .pixels()
        .iter()
        .flat_map(|p| p.iter().map(|&x| f64::from(x)))
        .sum::<f64>()
        / n;
    Ok(ImageErrors {
        relative_rmse: if mean > 0.0 {
            c.rmse / mean
        } else {
            f64::INFINITY
        },
        rmse: c.rmse,
        psnr_db: c.psnr_db.is_finite().then_some(c.psnr_db),
        mssim: c.mssim,
    })
}

/// How the two renders are made.
#[derive(Clone, Debug)]
pub struct RenderRequest {
    pub width: u32,
    pub height: u32,
    pub frames: u32,
    /// The scene material the BTF and then the pack replace.
    pub material: String,
}

fn render(scene: &Scene, r: &RenderRequest) -> Result<Image, FidelityError> {
    let mut mode = SpmmMode::new(scene.clone(), r.width, r.height)
        .map_err(|e: ModeError| FidelityError::Mode(e.to_string()))?;
    // A BTF is sampled with the defensive mixture only; the pack must be too, or the
    // two images differ by their noise as well as by their materials (packs are
    // sampled from their bases by default).
    mode.set_pack_sampling(PackSampling::Defensive);
    for _ in 0..r.frames {
        mode.render_frame();
    }
    Ok(mode.image())
}

/// The pack evaluated at a BTF's direction pairs, texel by texel on demand, as a
/// `TexelSource`: what `tabulate_pack` holds whole, and what `meso report fit` shades
/// as a `btf` material through a bounded cache when it exceeds `--max-memory`.
pub struct PackTabulation {
    name: String,
    width: u32,
    height: u32,
    light_dirs: Vec<DVec3>,
    view_dirs: Vec<DVec3>,
    pack: Arc<SpmmMaterial>,
}

impl PackTabulation {
    /// `pack` at the pairs of `btf` (same texel grid).
    pub fn new(btf: &dyn TexelSource, pack: Arc<SpmmMaterial>) -> Result<Self, FidelityError> {
        check_grid(btf, &pack)?;
        Ok(Self {
            name: format!("{} tabulated", btf.name()),
            width: btf.width(),
            height: btf.height(),
            light_dirs: btf.light_dirs().to_vec(),
            view_dirs: btf.view_dirs().to_vec(),
            pack,
        })
    }
}

impl TexelSource for PackTabulation {
    fn name(&self) -> &str {
        &self.name
    }
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    fn light_dirs(&self) -> &[DVec3] {
        &self.light_dirs
    }
    fn view_dirs(&self) -> &[DVec3] {
        &self.view_dirs
    }
    fn read_texels(&self, first: usize, out: &mut [f32]) -> Result<(), String> {
        let per_texel = self.pairs() * 3;
        if !out.len().is_multiple_of(per_texel) || first + out.len() / per_texel > self.texels() {
            return Err(format!(
                "{}: texels {first}..{} are outside its {} texels",
                self.name,
                first + out.len().div_ceil(per_texel),
                self.texels()
            ));
        }
        let (lights, views) = (&self.light_dirs, &self.view_dirs);
        out.par_chunks_mut(per_texel)
            .enumerate()
            .for_each(|(i, out)| {
                let pairs = lights
                    .iter()
                    .flat_map(|&wi| views.iter().map(move |&wo| (wi, wo)));
                for ((wi, wo), rgb) in pairs.zip(out.chunks_exact_mut(3)) {
                    let v = self.pack.eval_texel(first + i, wi, wo, true, usize::MAX);
                    rgb.copy_from_slice(&v.to_array().map(|x| x as f32));
                }
            });
        match out.iter().position(|x| !x.is_finite()) {
            Some(i) => Err(format!(
                "{}: value {} of texel {} is not finite",
                self.name,
                out[i],
                first + i / per_texel
            )),
            None => Ok(()),
        }
    }
}

/// The pack evaluated at the BTF's direction pairs (residual on, every component),
/// as a BTF of the same grid and directions, held whole.
pub fn tabulate_pack(btf: &Btf, pack: &SpmmMaterial) -> Result<Btf, FidelityError> {
    let source = PackTabulation::new(btf, Arc::new(pack.clone()))?;
    let mut data = vec![0.0f32; btf.texels() * btf.pairs() * 3];
    source
        .read_texels(0, &mut data)
        .map_err(FidelityError::Mode)?;
    Btf::new(
        source.name,
        "a pack evaluated at a BTF's direction pairs (meso report fit)".into(),
        btf.width(),
        btf.height(),
        source.light_dirs,
        source.view_dirs,
        data,
    )
    .map_err(|e| FidelityError::Mode(format!("the pack tabulated at the BTF's pairs: {e}")))
}

/// The three renders of one scene.
pub struct Renders {
    /// With the BTF (the reference).
    pub btf: Image,
    /// With the pack.
    pub pack: Image,
    /// With the pack tabulated at the BTF's pairs, shown as a `btf` material.
    pub tabulated: Image,
}

/// Renders `scene` with material `r.material` replaced by the BTF, then by the pack
/// (residual on, all its components), then by the pack's tabulation (`tabulate_pack`,
/// already made into a table); each keeps the replaced material's tiling when that was
/// a pack or a BTF.
pub fn render_all(
    scene: &Scene,
    btf: Arc<BtfTable>,
    pack: Arc<SpmmMaterial>,
    tabulated: Arc<BtfTable>,
    r: &RenderRequest,
) -> Result<Renders, FidelityError> {
    let with = |m: Material| {
        let mut s = scene.clone();
        substitute(&mut s, &r.material, m, false).map_err(FidelityError::Scene)?;
        render(&s, r)
    };
    let as_btf = |table| Material::Btf {
        table,
        uv_scale: glam::DVec2::ONE,
    };
    let npca = pack.npca();
    Ok(Renders {
        btf: with(as_btf(btf))?,
        pack: with(Material::Spmm {
            material: pack,
            uv_scale: glam::DVec2::ONE,
            residual: true,
            npca,
        })?,
        tabulated: with(as_btf(tabulated))?,
    })
}

/// Three panels left to right: `a`, `b` and `|a - b| * gain` per channel.
pub fn side_by_side(a: &Image, b: &Image, gain: f32) -> Image {
    let (w, h) = (a.width(), a.height());
    let mut out = Image::new(3 * w, h);
    for y in 0..h {
        for x in 0..w {
            let (pa, pb) = (a.get(x, y), b.get(x, y));
            out.set(x, y, pa);
            out.set(w + x, y, pb);
            out.set(
                2 * w + x,
                y,
                [0, 1, 2].map(|c| (pa[c] - pb[c]).abs() * gain),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::spmm::testing::sample_material;

    /// A black BTF on `pack`'s texel grid and residual directions.
    fn black_btf_like(pack: &SpmmMaterial) -> Btf {
        let r = pack.residual().expect("a residual");
        let (lights, views) = (r.light_dirs.clone(), r.view_dirs.clone());
        let texels = (pack.width() * pack.height()) as usize;
        let data = vec![0.0; texels * lights.len() * views.len() * 3];
        Btf::new(
            "black".into(),
            "test".into(),
            pack.width(),
            pack.height(),
            lights,
            views,
            data,
        )
        .expect("valid")
    }

    /// The pack's render is the one the defensive sampling gives (what the BTF's
    /// render uses), not the bases' sampling, so both draw the same directions.
    #[test]
    fn the_pack_is_rendered_with_the_btf_s_sampling() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/scenes");
        let mut scene = meso_render::scene::load_scene(&dir.join("fit_bunny.toml")).expect("scene");
        let pack = Arc::new(sample_material(4, 3, 2, Some(2)));
        let npca = pack.npca();
        let m = Material::Spmm {
            material: pack,
            uv_scale: glam::DVec2::ONE,
            residual: true,
            npca,
        };
        substitute(&mut scene, "sample", m, false).expect("the scene's material");
        let r = RenderRequest {
            width: 24,
            height: 24,
            frames: 2,
            material: "sample".into(),
        };
        let with = |sampling: PackSampling| {
            let mut m = SpmmMode::new(scene.clone(), 24, 24).expect("mode");
            m.set_pack_sampling(sampling);
            for _ in 0..2 {
                m.render_frame();
            }
            m.image()
        };
        let got = render(&scene, &r).expect("render");
        assert!(got.pixels() == with(PackSampling::Defensive).pixels());
        assert!(got.pixels() != with(PackSampling::Bases).pixels());
    }

    /// A BTF made by tabulating a pack at its own residual directions: the pack is
    /// exact there, so the table error is the f32 rounding; scaling the BTF's grazing
    /// values shows up only in the grazing error.
    #[test]
    fn a_pack_tabulated_into_a_btf_has_no_table_error_and_grazing_errors_stay_grazing() {
        let pack = sample_material(4, 3, 2, Some(2));
        let r = pack.residual().expect("a residual");
        let (lights, views) = (r.light_dirs.clone(), r.view_dirs.clone());
        let btf = tabulate_pack(&black_btf_like(&pack), &pack).expect("same grid");
        // Laid out texel, light, view, channel, as the pack evaluates there.
        let (t, l, v) = (5, 1, 2);
        let direct = pack.eval_texel(t, lights[l], views[v], true, usize::MAX);
        assert_eq!(btf.value(t, l, v), direct.to_array().map(|x| x as f32));
        let bumped: Vec<f32> = btf
            .data()
            .chunks_exact(3)
            .enumerate()
            .flat_map(|(i, rgb)| {
                let (wi, wo) = (
                    lights[i / views.len() % lights.len()],
                    views[i % views.len()],
                );
                let k = if grazing(wi) || grazing(wo) { 1.5 } else { 1.0 };
                rgb.iter().map(move |x| x * k)
            })
            .collect();
        let e = table_errors(&btf, &pack, 3).expect("same grid");
        assert!(e.relative_rmse < 1e-6, "{e:?}");
        assert!(
            e.basis_relative_rmse > 1e-3,
            "the residual matters here: {e:?}"
        );
        let bumped = Btf::new("b".into(), "b".into(), 4, 3, lights, views, bumped).expect("valid");
        let e = table_errors(&bumped, &pack, usize::MAX).expect("same grid");
        assert!(
            e.grazing_fraction > 0.0 && e.grazing_fraction < 1.0,
            "{e:?}"
        );
        assert!(e.elsewhere_relative_rmse < 1e-6, "{e:?}");
        assert!(e.grazing_relative_rmse > 0.05, "{e:?}");
        // Overall = the pair-weighted mix of the two parts.
        let mix = (e.grazing_fraction * e.grazing_relative_rmse.powi(2)
            + (1.0 - e.grazing_fraction) * e.elsewhere_relative_rmse.powi(2))
        .sqrt();
        assert!((mix - e.relative_rmse).abs() < 1e-9 * mix.max(1.0), "{e:?}");
        let small = sample_material(2, 2, 1, None);
        assert!(matches!(
            table_errors(&btf, &small, 1),
            Err(FidelityError::GridMismatch { .. })
        ));
        assert!(matches!(
            tabulate_pack(&btf, &small),
            Err(FidelityError::GridMismatch { .. })
        ));
    }

    /// With the pack's own tabulation as the BTF, the fit's part of the image error is
    /// nil (the two `btf` renders agree bit for bit) and what is left is the
    /// interpolation's: the pack between the tabulated directions is not their linear
    /// interpolation.
    #[test]
    fn the_fit_part_is_nil_for_a_btf_that_is_the_pack_s_own_table() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/scenes");
        let scene = meso_render::scene::load_scene(&dir.join("fit_grazing.toml")).expect("scene");
        let pack = sample_material(4, 3, 2, Some(2));
        let own = tabulate_pack(&black_btf_like(&pack), &pack).expect("same grid");
        let own = Arc::new(BtfTable::new(&own).expect("table"));
        let request = RenderRequest {
            width: 24,
            height: 24,
            frames: 2,
            material: "sample".into(),
        };
        let renders =
            render_all(&scene, Arc::clone(&own), Arc::new(pack), own, &request).expect("renders");
        assert!(renders.btf.pixels() == renders.tabulated.pixels());
        let e = image_errors(&renders.tabulated, &renders.pack).expect("same size");
        assert!(e.relative_rmse > 1e-3, "{e:?}");
    }
}
