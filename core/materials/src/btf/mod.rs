//! Bidirectional texture functions (Dana et al. 1999): per texel, the reflectance
//! tabulated over a light-direction set and a view-direction set, RGB, with the
//! foreshortening cosine included (the convention of an SPMM basis function rho_j,
//! docs/brdf.md). `synth.rs` makes BTFs by ray tracing a height-field mesostructure
//! (Sloan et al. 2003, section 4.2), `import.rs` reads measured image sets, `file.rs`
//! is the `.btf` container (docs/formats/btf.md), `table.rs` the BTF as the spmm mode
//! shades it (the scene's `btf` material), `lobe.rs` how light directions are drawn
//! for it. `ubo2003.rs` and `ubo2014.rs` read the
//! University of Bonn's database formats (zips of JPEGs, factorised binaries) and
//! `crop.rs` keeps an import within memory. `texels.rs` is where a fit reads texels
//! from, `on_disk.rs` a `.btf` read block by block (BTFs larger than memory) and
//! `cache.rs` the bounded cache of its blocks an out-of-core table shades from.
//! Fitting them lives in `fit`.

pub mod cache;
pub mod crop;
pub mod directions;
pub mod file;
pub mod import;
pub mod lobe;
pub mod on_disk;
pub mod synth;
pub mod table;
pub mod texels;
pub mod ubo2003;
pub mod ubo2014;

use glam::DVec3;

/// Largest texel-grid side a BTF may have.
pub const MAX_SIDE: u32 = 16384;

/// A validated BTF. `data` is texel-major: value (t, l, v, c) sits at
/// `((t * L + l) * V + v) * 3 + c`, texels row-major with row 0 the top row, so one
/// texel's apparent BRDF (its `L * V * 3` values) is contiguous.
#[derive(Clone, Debug, PartialEq)]
pub struct Btf {
    name: String,
    provenance: String,
    width: u32,
    height: u32,
    light_dirs: Vec<DVec3>,
    view_dirs: Vec<DVec3>,
    data: Vec<f32>,
}

/// What is wrong with a BTF's parts; each message names the part and element.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum BtfError {
    #[error("texel grid {width}x{height}: both sides must be in 1..={MAX_SIDE}")]
    GridSize { width: u32, height: u32 },
    #[error("{part}: no directions (at least 1 is needed)")]
    NoDirections { part: &'static str },
    #[error("{part}[{index}] = {value:?} is not a unit vector with z > 0 (|v| within 1e-3 of 1)")]
    Direction {
        part: &'static str,
        index: usize,
        value: [f64; 3],
    },
    #[error("{part}[{first}] and {part}[{second}] are the same direction")]
    DuplicateDirection {
        part: &'static str,
        first: usize,
        second: usize,
    },
    #[error("reflectance: {len} values, expected {expected} (texels x lights x views x 3)")]
    Length { len: usize, expected: usize },
    #[error(
        "reflectance[texel {texel}, light {light}, view {view}, channel {channel}] = {value} is not finite"
    )]
    NonFinite {
        texel: usize,
        light: usize,
        view: usize,
        channel: usize,
        value: f32,
    },
}

pub(crate) fn check_dirs(part: &'static str, dirs: &[DVec3]) -> Result<(), BtfError> {
    if dirs.is_empty() {
        return Err(BtfError::NoDirections { part });
    }
    for (index, d) in dirs.iter().enumerate() {
        if !d.is_finite() || (d.length() - 1.0).abs() > 1e-3 || d.z <= 0.0 {
            return Err(BtfError::Direction {
                part,
                index,
                value: d.to_array(),
            });
        }
        if let Some(first) = dirs[..index]
            .iter()
            .position(|e| e.distance_squared(*d) < 1e-12)
        {
            return Err(BtfError::DuplicateDirection {
                part,
                first,
                second: index,
            });
        }
    }
    Ok(())
}

impl Btf {
    /// Checks the grid size, the direction sets (unit, above the surface, distinct),
    /// the value count and that every value is finite.
    pub fn new(
        name: String,
        provenance: String,
        width: u32,
        height: u32,
        light_dirs: Vec<DVec3>,
        view_dirs: Vec<DVec3>,
        data: Vec<f32>,
    ) -> Result<Self, BtfError> {
        if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
            return Err(BtfError::GridSize { width, height });
        }
        check_dirs("light_dirs", &light_dirs)?;
        check_dirs("view_dirs", &view_dirs)?;
        let (l, v) = (light_dirs.len(), view_dirs.len());
        let expected = width as usize * height as usize * l * v * 3;
        if data.len() != expected {
            return Err(BtfError::Length {
                len: data.len(),
                expected,
            });
        }
        if let Some(i) = data.iter().position(|x| !x.is_finite()) {
            return Err(BtfError::NonFinite {
                texel: i / (l * v * 3),
                light: i / (v * 3) % l,
                view: i / 3 % v,
                channel: i % 3,
                value: data[i],
            });
        }
        Ok(Self {
            name,
            provenance,
            width,
            height,
            light_dirs,
            view_dirs,
            data,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    pub fn provenance(&self) -> &str {
        &self.provenance
    }
    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn texels(&self) -> usize {
        self.width as usize * self.height as usize
    }
    pub fn light_dirs(&self) -> &[DVec3] {
        &self.light_dirs
    }
    pub fn view_dirs(&self) -> &[DVec3] {
        &self.view_dirs
    }
    /// Direction pairs per texel, `L * V`.
    pub fn pairs(&self) -> usize {
        self.light_dirs.len() * self.view_dirs.len()
    }
    /// All values, texel-major (see the type's documentation).
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    /// The apparent BRDF of texel `t`: `L * V * 3` values, light-major then view, RGB.
    pub fn texel(&self, t: usize) -> &[f32] {
        let n = self.pairs() * 3;
        &self.data[t * n..(t + 1) * n]
    }
    /// RGB value at texel `t`, light `l`, view `v`.
    pub fn value(&self, t: usize, l: usize, v: usize) -> [f32; 3] {
        let i = ((t * self.light_dirs.len() + l) * self.view_dirs.len() + v) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
    /// Mean of every value (all texels, pairs and channels), in f64.
    pub fn mean_value(&self) -> f64 {
        self.data.iter().map(|&x| f64::from(x)).sum::<f64>() / self.data.len() as f64
    }

    /// A uniform BTF tabulating an analytic BRDF: every texel holds
    /// `albedo * f(l, v) * cos_l` (the foreshortening cosine of the light) at every
    /// pair of the direction sets. The closed-form reference of the `btf` material.
    pub fn from_brdf(
        brdf: &crate::brdf::AnalyticBrdf,
        albedo: DVec3,
        width: u32,
        height: u32,
        light_dirs: Vec<DVec3>,
        view_dirs: Vec<DVec3>,
    ) -> Result<Self, BtfError> {
        if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
            return Err(BtfError::GridSize { width, height });
        }
        let mut texel = Vec::with_capacity(light_dirs.len() * view_dirs.len() * 3);
        for l in &light_dirs {
            for v in &view_dirs {
                let f = albedo * (brdf.eval(*l, *v) * l.z);
                texel.extend(f.to_array().map(|x| x as f32));
            }
        }
        let data = texel.repeat(width as usize * height as usize);
        Self::new(
            format!("{:?}", brdf.model()).to_lowercase(),
            "tabulated analytic BRDF".into(),
            width,
            height,
            light_dirs,
            view_dirs,
            data,
        )
    }
}
