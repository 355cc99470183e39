//! UBO2014 BTF files (University of Bonn, Weinmann et al. 2014): one binary file per
//! material holding a matrix factorisation of the BTF, read here without expanding it.
//! The layout (docs/formats/ubo.md) was taken from Bonn's own readers, btflib (MATLAB)
//! and the `btf_extractor` Python package; the code is Meso's own.
//!
//! `Ubo2014::open` parses the header and the small side of the file (DFMF and FMF:
//! the pair-side factors U; PVF: each view's side over the lights, in `pvf`; BDI: where
//! each chunk of texels starts, in `bdi`) and records where the texel side starts;
//! `read_texels` reconstructs a rectangle of texels from it on demand, so a 400 x 400 x
//! 151 x 151 file is never expanded whole. `write_dfmf` writes Meso's BTF as
//! `!DFMF08FCR`.

use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use glam::DVec3;
use rayon::prelude::*;

use super::crop::{self, CropError, TexelRect};
use super::{Btf, BtfError, MAX_SIDE};
use crate::atomic::{AtomicWriteError, write_atomic};

mod bdi;
mod pvf;

/// The kinds of Bonn BTF file, told apart by their signature.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Decorrelated full matrix factorisation: one factorisation per colour channel.
    Dfmf,
    /// Full matrix factorisation: one for all channels; `extended` adds a header byte
    /// (dynamic-range reduction, height map).
    Fmf { extended: bool },
    /// Per-view factorisation: one PCA per view direction.
    Pvf,
    /// Bonn's directional images in chunks of scan lines; `header_flag` (the `!` at
    /// the end of the signature) adds a compression byte, else the chunks are bzip2.
    Bdi { header_flag: bool },
}

/// Every signature Bonn's readers accept, with what follows it: rotations when the
/// signature ends in `R` (btflib's list, plus the forms without `R` btf_extractor takes).
pub const SIGNATURES: [(&str, Kind); 10] = [
    ("!DFMF08FCR", Kind::Dfmf),
    ("!DFMF08FC", Kind::Dfmf),
    ("!FMF12FCER", Kind::Fmf { extended: true }),
    ("!FMF12FCE", Kind::Fmf { extended: true }),
    ("!FMF06FCR", Kind::Fmf { extended: false }),
    ("!FMF06FC", Kind::Fmf { extended: false }),
    ("!PVF06FCR", Kind::Pvf),
    ("!PVF06FC", Kind::Pvf),
    ("!BDIF06R2!", Kind::Bdi { header_flag: true }),
    ("!BDIF06R2", Kind::Bdi { header_flag: false }),
];

/// The longest signature `head` starts with.
pub fn identify(head: &[u8]) -> Option<(&'static str, Kind)> {
    SIGNATURES
        .iter()
        .filter(|(s, _)| head.starts_with(s.as_bytes()))
        .max_by_key(|(s, _)| s.len())
        .copied()
}

/// Offset btflib and btf_extractor use in their logarithmic encodings.
const DRR_EPS: f32 = 1e-5;
/// Largest finite half float.
const F16_MAX: f32 = 65504.0;
/// Longest XML string or channel name read (the measurement XML is a few hundred KB).
const MAX_TEXT: u32 = 64 << 20;

#[derive(Debug, thiserror::Error)]
#[error("`{}`: {kind}", path.display())]
pub struct UboError {
    pub path: PathBuf,
    pub kind: Box<UboErrorKind>,
}

/// What is wrong with a UBO2014 file (or a BTF to write as one). Places are named by
/// part and byte offset.
#[derive(Debug, thiserror::Error)]
pub enum UboErrorKind {
    #[error("cannot read: {0}")]
    Io(#[from] io::Error),
    #[error(
        "does not start with a UBO2014 signature (`!DFMF08FCR`, `!FMF12FCER`, `!FMF06FCR`, `!PVF06FCR`, ...): found {found:?}"
    )]
    Signature { found: String },
    #[error("`{signature}`: {what} files are recognised but Meso does not read them")]
    Unsupported {
        signature: &'static str,
        what: &'static str,
    },
    #[error("the file ends at byte {len}, inside {part} (bytes {start}..{end})")]
    Truncated {
        part: String,
        start: u64,
        end: u64,
        len: u64,
    },
    #[error("{part} (byte {offset}) = {value}: {rule}")]
    Field {
        part: String,
        offset: u64,
        value: String,
        rule: String,
    },
    #[error("the meta-data block declares {declared} bytes, but its fields take {read}")]
    HeaderSize { declared: u32, read: u64 },
    #[error(
        "{extra} bytes follow the last factor (which ends at byte {end}); Bonn's readers refuse such a file"
    )]
    Trailing { end: u64, extra: u64 },
    #[error("{0}")]
    Crop(#[from] CropError),
    #[error("{0}")]
    Btf(#[from] BtfError),
    #[error(
        "value at texel {texel}, light {light}, view {view}, channel {channel} = {value} does not fit a half float (|v| <= 65504)"
    )]
    HalfRange {
        texel: usize,
        light: usize,
        view: usize,
        channel: usize,
        value: f32,
    },
    #[error(
        "{count} {side} directions: a DFMF file counts them in 32 bits, and Bonn's readers need as many lights as views ({lights} and {views} here are written, btf_extractor reads only equal counts)"
    )]
    Directions {
        side: &'static str,
        count: usize,
        lights: usize,
        views: usize,
    },
    #[error("cannot write: {0}")]
    Write(#[from] AtomicWriteError),
}

/// The header of a UBO2014 file: what Bonn's common header, the sampling and the
/// factorisation's preamble say.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    pub signature: &'static str,
    pub kind: Kind,
    /// Version of the meta-data block (1..=4 carry more fields).
    pub version: u32,
    pub measurement_setup: String,
    pub image_sensor: String,
    pub light_source: String,
    /// Pixels per millimetre.
    pub ppmm: f32,
    /// Stored, applied by neither Bonn reader nor Meso.
    pub rgb_scale: [f32; 3],
    /// Whether the light's cos(theta) is multiplied into the stored values.
    pub cosine_flag: bool,
    pub xml: String,
    pub channels: Vec<String>,
    /// (theta, phi) in radians as stored.
    pub light_angles: Vec<[f32; 2]>,
    pub view_angles: Vec<[f32; 2]>,
    pub width: u32,
    pub height: u32,
    pub rotations: u32,
    /// btflib's colour models: 0 RGB, 1 YUV, 3 PCA (mean and matrix), 4 YCoCg,
    /// 9 log Y UV, 10 log Y log U log V, 11 log Y U/Y V/Y, 12 log RGB.
    pub color_model: i32,
    pub color_mean: [f32; 3],
    /// Row-major, as stored: rgb_j = sum_i c_i m[i][j] + mean_j (colour model 3).
    pub color_transform: [[f32; 3]; 3],
    /// FMF: values are stored as log(v + 1e-5).
    pub dynamic_range_reduction: bool,
}

/// One factorisation: U (pair side) in memory, S x V (texel side) left in the file.
#[derive(Clone, Debug)]
struct Plane {
    scalar: u8,
    components: usize,
    u: Vec<f32>,
    sxv_offset: u64,
}

/// What follows the header: where the values are and the small factors read.
enum Body {
    /// DFMF (one plane per channel) or FMF (one plane).
    Factors(Vec<Plane>),
    /// PVF: one factorisation per view.
    PerView(pvf::PerView),
    /// BDI: the values themselves, in chunks of scan lines.
    Chunks(bdi::Chunks),
}

/// An open UBO2014 file.
pub struct Ubo2014<R> {
    source: R,
    header: Header,
    body: Body,
}

/// A reader that knows the file's length and refuses to read past it.
struct Cursor<'a, R> {
    src: &'a mut R,
    pos: u64,
    len: u64,
}

impl<R: Read + Seek> Cursor<'_, R> {
    fn need(&self, n: u64, part: &str) -> Result<(), UboErrorKind> {
        match self.pos.checked_add(n) {
            Some(end) if end <= self.len => Ok(()),
            end => Err(UboErrorKind::Truncated {
                part: part.to_string(),
                start: self.pos,
                end: end.unwrap_or(u64::MAX),
                len: self.len,
            }),
        }
    }

    fn bytes(&mut self, n: u64, part: &str) -> Result<Vec<u8>, UboErrorKind> {
        self.need(n, part)?;
        let mut b = vec![0; n as usize];
        self.src.read_exact(&mut b)?;
        self.pos += n;
        Ok(b)
    }

    fn array<const N: usize>(&mut self, part: &str) -> Result<[u8; N], UboErrorKind> {
        self.need(N as u64, part)?;
        let mut b = [0; N];
        self.src.read_exact(&mut b)?;
        self.pos += N as u64;
        Ok(b)
    }

    fn u8(&mut self, part: &str) -> Result<u8, UboErrorKind> {
        Ok(self.array::<1>(part)?[0])
    }
    fn u32(&mut self, part: &str) -> Result<u32, UboErrorKind> {
        Ok(u32::from_le_bytes(self.array(part)?))
    }
    fn i32(&mut self, part: &str) -> Result<i32, UboErrorKind> {
        Ok(i32::from_le_bytes(self.array(part)?))
    }
    fn f32(&mut self, part: &str) -> Result<f32, UboErrorKind> {
        Ok(f32::from_le_bytes(self.array(part)?))
    }
    fn f32s<const N: usize>(&mut self, part: &str) -> Result<[f32; N], UboErrorKind> {
        let mut out = [0.0; N];
        for x in &mut out {
            *x = self.f32(part)?;
        }
        Ok(out)
    }

    fn skip(&mut self, n: u64, part: &str) -> Result<(), UboErrorKind> {
        self.need(n, part)?;
        self.pos += n;
        self.src.seek(SeekFrom::Start(self.pos))?;
        Ok(())
    }

    fn text(&mut self, n: u32, part: &str) -> Result<String, UboErrorKind> {
        if n > MAX_TEXT {
            return Err(self.field(part, n, "longer than Meso reads (64 MiB)"));
        }
        let b = self.bytes(u64::from(n), part)?;
        // Fixed-size fields are NUL-padded.
        let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
        Ok(String::from_utf8_lossy(&b[..end]).into_owned())
    }

    /// A field error at the value just read (`size` bytes back).
    fn field(&self, part: &str, value: impl ToString, rule: &str) -> UboErrorKind {
        UboErrorKind::Field {
            part: part.to_string(),
            offset: self.pos.saturating_sub(4),
            value: value.to_string(),
            rule: rule.to_string(),
        }
    }
}

fn scalar_bytes(scalar: u8) -> u64 {
    u64::from(scalar)
}

/// Converts `raw` little-endian scalars of `scalar` bytes (2: half, 4: f32, 8: f64).
fn to_f32(raw: &[u8], scalar: u8) -> Vec<f32> {
    match scalar {
        2 => raw
            .chunks_exact(2)
            .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect(),
        4 => raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        _ => raw
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
            .collect(),
    }
}

/// The file's texel index of Meso's texel (x, y): the file counts rows from the
/// bottom of the image (btf_extractor flips them on load; Meso follows it).
fn file_texel(header: &Header, x: u32, y: u32) -> usize {
    (header.height - 1 - y) as usize * header.width as usize + x as usize
}

/// Unit vector of (theta, phi) in radians, as btflib's `sph2cart2`.
fn direction(a: [f32; 2]) -> DVec3 {
    let (t, p) = (f64::from(a[0]), f64::from(a[1]));
    if t == 0.0 {
        return DVec3::Z;
    }
    DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
}

/// (theta, phi) in radians of a unit vector, as btflib's `cart2sph2`.
fn angles(d: DVec3) -> [f32; 2] {
    [d.x.hypot(d.y).atan2(d.z) as f32, d.y.atan2(d.x) as f32]
}

impl Header {
    /// A header with nothing read yet: RGB, no cosine in the values, no meta data.
    fn empty(signature: &'static str, kind: Kind) -> Self {
        Header {
            signature,
            kind,
            version: 0,
            measurement_setup: String::new(),
            image_sensor: String::new(),
            light_source: String::new(),
            ppmm: 0.0,
            rgb_scale: [1.0; 3],
            cosine_flag: false,
            xml: String::new(),
            channels: vec!["R".into(), "G".into(), "B".into()],
            light_angles: Vec::new(),
            view_angles: Vec::new(),
            width: 0,
            height: 0,
            rotations: 0,
            color_model: 0,
            color_mean: [0.0; 3],
            color_transform: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            dynamic_range_reduction: false,
        }
    }
}

/// Bonn's common header after the signature (btflib's read_common_header): meta data,
/// sampling, extent and, for a signature ending in `R`, the rotations.
fn read_common<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    header: &mut Header,
) -> Result<(), UboErrorKind> {
    read_meta(c, header)?;
    read_sampling(c, header)?;
    read_extent(c, header)?;
    if header.signature.ends_with('R') {
        header.rotations = skip_rotations(c)?;
    }
    Ok(())
}

/// The meta-data block (btflib's read_meta_data).
fn read_meta<R: Read + Seek>(c: &mut Cursor<'_, R>, h: &mut Header) -> Result<(), UboErrorKind> {
    let start = c.pos;
    let declared = c.u32("the meta-data size")?;
    h.version = c.u32("the meta-data version")?;
    h.measurement_setup = c.text(80, "the measurement setup")?;
    h.image_sensor = c.text(80, "the image sensor")?;
    h.light_source = c.text(80, "the light source")?;
    h.ppmm = c.f32("ppmm")?;
    h.rgb_scale = c.f32s::<3>("the RGB scale factors")?;
    h.cosine_flag = h.version > 1 && c.u32("the cosine flag")? != 0;
    if h.version > 2 {
        let n = c.u32("the XML length")?;
        h.xml = c.text(n, "the XML string")?;
    }
    if h.version > 3 {
        let n = c.u32("the channel count")?;
        if n != 3 {
            return Err(c.field(
                "the channel count",
                n,
                "Meso reads 3 colour channels (no multispectral BTFs)",
            ));
        }
        h.channels = (0..n)
            .map(|k| {
                let len = c.u32(&format!("channel {k}'s name length"))?;
                c.text(len, &format!("channel {k}'s name"))
            })
            .collect::<Result<_, _>>()?;
    }
    if c.pos - start != u64::from(declared) {
        return Err(UboErrorKind::HeaderSize {
            declared,
            read: c.pos - start,
        });
    }
    Ok(())
}

/// The sampling: every view with its light list (btflib's read_bidir_sampling).
fn read_sampling<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    h: &mut Header,
) -> Result<(), UboErrorKind> {
    let views = c.u32("the view count")?;
    if views == 0 {
        return Err(c.field("the view count", 0, "must be at least 1"));
    }
    // Each view takes at least 12 bytes: refuse a count the file cannot hold.
    c.need(u64::from(views) * 12, "the view directions")?;
    let mut view_angles = Vec::with_capacity(views as usize);
    let mut light_angles: Vec<[f32; 2]> = Vec::new();
    for v in 0..views {
        view_angles.push(check_angles(c, &format!("view {v}"))?);
        let lights = c.u32(&format!("view {v}'s light count"))?;
        if v == 0 {
            if lights == 0 {
                return Err(c.field("view 0's light count", 0, "must be at least 1"));
            }
            c.need(u64::from(lights) * 8, "the light directions")?;
            light_angles = (0..lights)
                .map(|l| check_angles(c, &format!("light {l}")))
                .collect::<Result<_, _>>()?;
        } else if lights as usize != light_angles.len() {
            return Err(c.field(
                &format!("view {v}'s light count"),
                lights,
                &format!(
                    "every view must have view 0's {} lights (Bonn's readers need one light set)",
                    light_angles.len()
                ),
            ));
        } else {
            // Bonn's readers use view 0's list for every view.
            c.skip(
                u64::from(lights) * 8,
                &format!("view {v}'s light directions"),
            )?;
        }
    }
    h.light_angles = light_angles;
    h.view_angles = view_angles;
    Ok(())
}

/// Width and height in texels.
fn read_extent<R: Read + Seek>(c: &mut Cursor<'_, R>, h: &mut Header) -> Result<(), UboErrorKind> {
    h.width = c.u32("the width")?;
    check_side(c, "the width", h.width)?;
    h.height = c.u32("the height")?;
    check_side(c, "the height", h.height)?;
    Ok(())
}

/// The rotation count and the 3 x 3 rotations, which Meso does not use.
fn skip_rotations<R: Read + Seek>(c: &mut Cursor<'_, R>) -> Result<u32, UboErrorKind> {
    let n = c.u32("the rotation count")?;
    c.skip(u64::from(n) * 36, "the rotations")?;
    Ok(n)
}

/// The header of a DFMF or FMF file: the common header and the factorisation's preamble.
fn read_header<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    signature: &'static str,
    kind: Kind,
) -> Result<Header, UboErrorKind> {
    c.skip(signature.len() as u64, "the signature")?;
    let mut header = Header::empty(signature, kind);
    read_common(c, &mut header)?;
    match kind {
        Kind::Dfmf => {
            c.u32("the largest component count")?;
            let model = c.i32("the colour model")?;
            if ![0, 1, 3, 4, 9, 10, 11, 12].contains(&model) {
                return Err(c.field(
                    "the colour model",
                    model,
                    "Meso reads models 0 (RGB), 1 (YUV), 3 (PCA), 4 (YCoCg), 9, 10, 11 (log YUV forms) and 12 (log RGB)",
                ));
            }
            header.color_model = model;
            header.color_mean = c.f32s::<3>("the colour mean")?;
            let m = c.f32s::<9>("the colour transform")?;
            header.color_transform = [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]];
        }
        Kind::Fmf { extended: true } => {
            let hv = c.u8("the FMF header version")?;
            if hv >= 3 {
                return Err(c.field("the FMF header version", hv, "Bonn's readers know 0..=2"));
            }
            if hv >= 1 {
                header.dynamic_range_reduction = c.u32("the dynamic-range reduction")? != 0;
            }
            if hv >= 2 {
                let w = c.u32("the height map's width")?;
                let h = c.u32("the height map's height")?;
                c.skip(u64::from(w) * u64::from(h) * 2, "the height map")?;
            }
        }
        _ => {}
    }
    Ok(header)
}

fn check_angles<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    part: &str,
) -> Result<[f32; 2], UboErrorKind> {
    let a = c.f32s::<2>(&format!("{part}'s angles"))?;
    if !a[0].is_finite() || !a[1].is_finite() || !(0.0..std::f32::consts::FRAC_PI_2).contains(&a[0])
    {
        return Err(UboErrorKind::Field {
            part: format!("{part}'s (theta, phi)"),
            offset: c.pos - 8,
            value: format!("({}, {}) rad", a[0], a[1]),
            rule: "theta must be in [0, pi/2) and phi finite".into(),
        });
    }
    Ok(a)
}

fn check_side<R: Read + Seek>(c: &Cursor<'_, R>, part: &str, v: u32) -> Result<(), UboErrorKind> {
    if (1..=MAX_SIDE).contains(&v) {
        Ok(())
    } else {
        Err(c.field(part, v, &format!("must be in 1..={MAX_SIDE}")))
    }
}

/// Reads one factorisation's preamble and U, and skips S x V after checking its size.
fn read_plane<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    name: &str,
    scalar: u8,
    rows: u64,
    cols: u64,
) -> Result<Plane, UboErrorKind> {
    let components = c.u32(&format!("{name}'s component count"))?;
    if components == 0 {
        return Err(c.field(
            &format!("{name}'s component count"),
            0,
            "must be at least 1",
        ));
    }
    let found_rows = c.u32(&format!("{name}'s row count"))?;
    if u64::from(found_rows) != rows {
        return Err(c.field(
            &format!("{name}'s row count"),
            found_rows,
            &format!("must be {rows} (one row per light-view pair and factorised channel; the transposed layout is not read)"),
        ));
    }
    let found_cols = c.u32(&format!("{name}'s column count"))?;
    if u64::from(found_cols) != cols {
        return Err(c.field(
            &format!("{name}'s column count"),
            found_cols,
            &format!("must be {cols} (width x height)"),
        ));
    }
    let k = u64::from(components);
    let s = scalar_bytes(scalar);
    // Check the whole plane fits before allocating U.
    let total = (k * s)
        .saturating_add(rows.saturating_mul(k * s))
        .saturating_add(cols.saturating_mul(k * s));
    c.need(
        total,
        &format!("{name}'s factors ({components} components)"),
    )?;
    c.skip(k * s, &format!("{name}'s singular values"))?;
    let u = to_f32(&c.bytes(rows * k * s, &format!("{name}'s U"))?, scalar);
    let sxv_offset = c.pos;
    c.skip(cols * k * s, &format!("{name}'s S x V"))?;
    Ok(Plane {
        scalar,
        components: components as usize,
        u,
        sxv_offset,
    })
}

fn read_scalar<R: Read + Seek>(c: &mut Cursor<'_, R>, part: &str) -> Result<u8, UboErrorKind> {
    let s = c.u8(part)?;
    if ![2, 4, 8].contains(&s) {
        return Err(UboErrorKind::Field {
            part: part.into(),
            offset: c.pos - 1,
            value: s.to_string(),
            rule: "must be 2 (half), 4 (f32) or 8 (f64) bytes".into(),
        });
    }
    Ok(s)
}

/// The factor planes of a DFMF (one per channel) or FMF (one for all) file.
fn read_planes<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    header: &Header,
) -> Result<Vec<Plane>, UboErrorKind> {
    let pairs = (header.light_angles.len() * header.view_angles.len()) as u64;
    let cols = u64::from(header.width) * u64::from(header.height);
    if header.kind == Kind::Dfmf {
        (0..3)
            .map(|ch| {
                let name = format!("channel {ch}");
                let scalar = read_scalar(c, &format!("{name}'s scalar size"))?;
                read_plane(c, &name, scalar, pairs, cols)
            })
            .collect()
    } else {
        c.u32("the largest component count")?;
        let scalar = read_scalar(c, "the scalar size")?;
        Ok(vec![read_plane(
            c,
            "the factorisation",
            scalar,
            3 * pairs,
            cols,
        )?])
    }
}

impl Ubo2014<BufReader<File>> {
    /// Opens a file (header and U factors; S x V stays on disk).
    pub fn open_path(path: &Path) -> Result<Self, UboError> {
        let at = |kind: UboErrorKind| UboError {
            path: path.to_path_buf(),
            kind: Box::new(kind),
        };
        let file = File::open(path).map_err(|e| at(e.into()))?;
        Self::open(BufReader::new(file)).map_err(at)
    }
}

impl<R: Read + Seek> Ubo2014<R> {
    /// Parses the header and the pair-side factors; every size is checked against the
    /// file's length before anything is allocated.
    pub fn open(mut source: R) -> Result<Self, UboErrorKind> {
        let len = source.seek(SeekFrom::End(0))?;
        source.seek(SeekFrom::Start(0))?;
        let mut head = Vec::with_capacity(10);
        (&mut source).take(10).read_to_end(&mut head)?;
        source.seek(SeekFrom::Start(0))?;
        let Some((signature, kind)) = identify(&head) else {
            return Err(UboErrorKind::Signature {
                found: String::from_utf8_lossy(&head).into_owned(),
            });
        };
        let mut c = Cursor {
            src: &mut source,
            pos: 0,
            len,
        };
        let (header, body) = match kind {
            Kind::Dfmf | Kind::Fmf { .. } => {
                let header = read_header(&mut c, signature, kind)?;
                let planes = read_planes(&mut c, &header)?;
                if c.pos != len {
                    return Err(UboErrorKind::Trailing {
                        end: c.pos,
                        extra: len - c.pos,
                    });
                }
                (header, Body::Factors(planes))
            }
            Kind::Pvf => {
                let (header, body) = pvf::read(&mut c, signature)?;
                (header, Body::PerView(body))
            }
            Kind::Bdi { header_flag } => {
                let (header, body) = bdi::read(&mut c, signature, header_flag)?;
                (header, Body::Chunks(body))
            }
        };
        Ok(Self {
            source,
            header,
            body,
        })
    }

    pub fn header(&self) -> &Header {
        &self.header
    }
    pub fn light_dirs(&self) -> Vec<DVec3> {
        self.header
            .light_angles
            .iter()
            .map(|&a| direction(a))
            .collect()
    }
    pub fn view_dirs(&self) -> Vec<DVec3> {
        self.header
            .view_angles
            .iter()
            .map(|&a| direction(a))
            .collect()
    }
    /// Components per factorisation: one per channel for DFMF, one for FMF, one per
    /// view for PVF, none for BDI (which stores the values).
    pub fn components(&self) -> Vec<usize> {
        match &self.body {
            Body::Factors(planes) => planes.iter().map(|p| p.components).collect(),
            Body::PerView(p) => p.components(),
            Body::Chunks(_) => Vec::new(),
        }
    }

    /// How the values are stored, in a line for `meso btf info`.
    pub fn storage(&self) -> String {
        match &self.body {
            Body::Factors(planes) => format!(
                "{} factorisation{} ({} components), colour model {}",
                planes.len(),
                if planes.len() == 1 { "" } else { "s" },
                planes
                    .iter()
                    .map(|p| p.components.to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                self.header.color_model
            ),
            Body::PerView(p) => p.describe(),
            Body::Chunks(c) => c.describe(&self.header),
        }
    }

    /// S x V rows of the texels in `rect` (Meso rows, top first) for each plane.
    fn read_sxv(
        source: &mut R,
        header: &Header,
        planes: &[Plane],
        rect: TexelRect,
    ) -> Result<Vec<Vec<f32>>, UboErrorKind> {
        let mut out = Vec::with_capacity(planes.len());
        for p in planes {
            let (k, s) = (p.components as u64, scalar_bytes(p.scalar));
            let mut values = Vec::with_capacity(rect.texels() * p.components);
            let mut raw = vec![0u8; (u64::from(rect.width) * k * s) as usize];
            for y in rect.y..rect.y + rect.height {
                let at = p.sxv_offset + (file_texel(header, rect.x, y) as u64) * k * s;
                source.seek(SeekFrom::Start(at))?;
                source.read_exact(&mut raw)?;
                values.extend(to_f32(&raw, p.scalar));
            }
            out.push(values);
        }
        Ok(out)
    }

    /// The stored channels of the texels in `rect` from DFMF or FMF factors, in Meso's
    /// order (texel, light, view, channel).
    fn read_factors(
        source: &mut R,
        header: &Header,
        planes: &[Plane],
        rect: TexelRect,
    ) -> Result<Vec<f32>, UboErrorKind> {
        let (nl, nv) = (header.light_angles.len(), header.view_angles.len());
        let sxv = Self::read_sxv(source, header, planes, rect)?;
        let fmf = matches!(header.kind, Kind::Fmf { .. });
        let mut data = vec![0.0f32; rect.texels() * nl * nv * 3];
        data.par_chunks_mut(nl * nv * 3)
            .enumerate()
            .for_each(|(t, out)| {
                for l in 0..nl {
                    for v in 0..nv {
                        // Bonn's pair index: light fastest.
                        let pair = l + nl * v;
                        for ch in 0..3 {
                            let (plane, row) = if fmf {
                                (&planes[0], ch + 3 * pair)
                            } else {
                                (&planes[ch], pair)
                            };
                            let k = plane.components;
                            let u = &plane.u[row * k..(row + 1) * k];
                            let sv = &sxv[if fmf { 0 } else { ch }][t * k..(t + 1) * k];
                            out[(l * nv + v) * 3 + ch] = u.iter().zip(sv).map(|(a, b)| a * b).sum();
                        }
                    }
                }
            });
        Ok(data)
    }

    /// The values of the texels in `rect`, in Meso's order (texel-major, then light,
    /// view, RGB; see `Btf`), RGB after the colour model and dynamic-range reduction
    /// are undone, the light's cosine included.
    pub fn read_texels(&mut self, rect: TexelRect) -> Result<Vec<f32>, UboErrorKind> {
        rect.check_inside(self.header.width, self.header.height)?;
        let (nl, nv) = (
            self.header.light_angles.len(),
            self.header.view_angles.len(),
        );
        crop::check_budget(rect.texels() as u64, (nl * nv) as u64)?;
        let header = &self.header;
        let mut data = match &self.body {
            Body::Factors(planes) => Self::read_factors(&mut self.source, header, planes, rect)?,
            Body::PerView(p) => p.read_texels(&mut self.source, header, rect)?,
            Body::Chunks(c) => c.read_texels(&mut self.source, header, rect)?,
        };
        let cosines: Vec<f32> = self
            .light_dirs()
            .iter()
            .map(|d| if header.cosine_flag { 1.0 } else { d.z as f32 })
            .collect();
        data.par_chunks_mut(nl * nv * 3).for_each(|texel| {
            for (l, &cos) in cosines.iter().enumerate() {
                for v in 0..nv {
                    let i = (l * nv + v) * 3;
                    let rgb = to_rgb(header, [texel[i], texel[i + 1], texel[i + 2]]);
                    for ch in 0..3 {
                        texel[i + ch] = rgb[ch] * cos;
                    }
                }
            }
        });
        Ok(data)
    }

    /// The texels of `rect` (default: all) as a Meso BTF.
    pub fn to_btf(
        &mut self,
        name: &str,
        provenance: &str,
        rect: Option<TexelRect>,
    ) -> Result<Btf, UboErrorKind> {
        let rect = rect.unwrap_or(TexelRect::full(self.header.width, self.header.height));
        let data = self.read_texels(rect)?;
        Ok(Btf::new(
            name.to_string(),
            provenance.to_string(),
            rect.width,
            rect.height,
            self.light_dirs(),
            self.view_dirs(),
            data,
        )?)
    }
}

/// Undoes the colour model (btflib's `undecorrelate`) and the dynamic-range reduction.
fn to_rgb(h: &Header, c: [f32; 3]) -> [f32; 3] {
    const YUV: [[f32; 3]; 3] = [
        [1.0, 0.0, 1.13983],
        [1.0, -0.39465, -0.5806],
        [1.0, 2.03211, 0.0],
    ];
    const YCOCG: [[f32; 3]; 3] = [[1.0, 1.0, -1.0], [1.0, 0.0, 1.0], [1.0, -1.0, -1.0]];
    let mul = |m: &[[f32; 3]; 3], c: [f32; 3]| {
        [0, 1, 2].map(|r| m[r][0] * c[0] + m[r][1] * c[1] + m[r][2] * c[2])
    };
    let [c0, c1, c2] = c;
    let rgb = match h.color_model {
        1 => mul(&YUV, c),
        3 => [0, 1, 2].map(|j| {
            let m = &h.color_transform;
            c0 * m[0][j] + c1 * m[1][j] + c2 * m[2][j] + h.color_mean[j]
        }),
        4 => mul(&YCOCG, c),
        9 => mul(&YUV, [c0.exp() - DRR_EPS, c1, c2]),
        10 => {
            let unlog = |x: f32| x.signum() * (x.abs() + DRR_EPS.ln()).exp();
            mul(&YUV, [c0.exp() - DRR_EPS, unlog(c1), unlog(c2)])
        }
        11 => {
            let y = c0.exp() - DRR_EPS;
            mul(&YUV, [y, c1 * (y + DRR_EPS), c2 * (y + DRR_EPS)])
        }
        12 => c.map(|x| x.exp() - DRR_EPS),
        _ => c,
    };
    if h.dynamic_range_reduction {
        rgb.map(|x| x.exp() - DRR_EPS)
    } else {
        rgb
    }
}

/// Opens `path` and imports the texels of `rect` (default: all) as a BTF named `name`.
pub fn import_path(path: &Path, name: &str, rect: Option<TexelRect>) -> Result<Btf, UboError> {
    let mut f = Ubo2014::open_path(path)?;
    let provenance = format!(
        "meso btf import {} ({}{})",
        path.display(),
        f.header().signature,
        rect.map(|r| format!(", texels {r}")).unwrap_or_default()
    );
    f.to_btf(name, &provenance, rect).map_err(|kind| UboError {
        path: path.to_path_buf(),
        kind: Box::new(kind),
    })
}

/// Parses a whole UBO2014 file held in memory (the fuzz target's entry).
pub fn decode(bytes: &[u8]) -> Result<Btf, UboErrorKind> {
    Ubo2014::open(io::Cursor::new(bytes))?.to_btf("decoded", "bytes", None)
}

/// Writes `btf` as a `!DFMF08FCR` file: colour model 0 (RGB), the cosine flag set
/// (Meso's values include the light's cosine), half floats, rows bottom first, and
/// per channel the exact factorisation M = U (S x V)^T with k = min(pairs, texels)
/// components and the smaller side the identity (S holds ones). Reading it back gives
/// every value rounded once to a half float.
pub fn write_dfmf(path: &Path, btf: &Btf) -> Result<(), UboError> {
    let at = |kind: UboErrorKind| UboError {
        path: path.to_path_buf(),
        kind: Box::new(kind),
    };
    check_writable(btf).map_err(at)?;
    write_atomic(path, |w| encode_dfmf(btf, w)).map_err(|e| at(e.into()))
}

/// Why `btf` cannot be written as DFMF, if it cannot.
pub fn check_writable(btf: &Btf) -> Result<(), UboErrorKind> {
    let (nl, nv) = (btf.light_dirs().len(), btf.view_dirs().len());
    if nl != nv || u32::try_from(btf.pairs()).is_err() || u32::try_from(btf.texels()).is_err() {
        return Err(UboErrorKind::Directions {
            side: if nl != nv { "light and view" } else { "pair" },
            count: btf.pairs(),
            lights: nl,
            views: nv,
        });
    }
    if let Some(i) = btf.data().iter().position(|x| x.abs() > F16_MAX) {
        let p = btf.pairs();
        return Err(UboErrorKind::HalfRange {
            texel: i / (p * 3),
            light: i / (nv * 3) % nl,
            view: i / 3 % nv,
            channel: i % 3,
            value: btf.data()[i],
        });
    }
    Ok(())
}

/// Streams the DFMF bytes of `btf` (checked by `check_writable`) to `w`.
pub fn encode_dfmf(btf: &Btf, w: &mut dyn Write) -> io::Result<()> {
    let (nl, nv) = (btf.light_dirs().len(), btf.view_dirs().len());
    let (width, height) = (btf.width() as usize, btf.height() as usize);
    let (pairs, texels) = (nl * nv, width * height);
    let u32le = |w: &mut dyn Write, v: u32| w.write_all(&v.to_le_bytes());
    let f32le = |w: &mut dyn Write, v: f32| w.write_all(&v.to_le_bytes());
    let half = |w: &mut dyn Write, v: f32| w.write_all(&half::f16::from_f32(v).to_le_bytes());
    w.write_all(b"!DFMF08FCR")?;
    // Meta data, version 4 (btflib's write_meta_data).
    let channel_names = ["R", "G", "B"];
    let size = 4 + 4 + 240 + 4 + 12 + 4 + 4 + 4 + channel_names.len() * 5;
    u32le(w, size as u32)?;
    u32le(w, 4)?;
    for text in ["Meso", "", ""] {
        let mut field = [0u8; 80];
        field[..text.len()].copy_from_slice(text.as_bytes());
        w.write_all(&field)?;
    }
    f32le(w, 0.0)?; // ppmm: unknown
    for _ in 0..3 {
        f32le(w, 1.0)?;
    }
    u32le(w, 1)?; // cosine flag
    u32le(w, 0)?; // no XML
    u32le(w, 3)?;
    for n in channel_names {
        u32le(w, 1)?;
        w.write_all(n.as_bytes())?;
    }
    // Sampling: each view followed by the light list.
    let lights: Vec<[f32; 2]> = btf.light_dirs().iter().map(|&d| angles(d)).collect();
    u32le(w, nv as u32)?;
    for &d in btf.view_dirs() {
        let [t, p] = angles(d);
        f32le(w, t)?;
        f32le(w, p)?;
        u32le(w, nl as u32)?;
        for [t, p] in &lights {
            f32le(w, *t)?;
            f32le(w, *p)?;
        }
    }
    u32le(w, width as u32)?;
    u32le(w, height as u32)?;
    u32le(w, 0)?; // no rotations
    let k = pairs.min(texels);
    u32le(w, k as u32)?;
    w.write_all(&0i32.to_le_bytes())?; // colour model 0: RGB
    for _ in 0..3 {
        f32le(w, 0.0)?;
    }
    for r in 0..3 {
        for c in 0..3 {
            f32le(w, if r == c { 1.0 } else { 0.0 })?;
        }
    }
    // Meso's index of Bonn's pair `p` (light fastest) and file texel `j` (bottom row first).
    let value = |j: usize, p: usize, ch: usize| {
        let t = (height - 1 - j / width) * width + j % width;
        btf.value(t, p % nl, p / nl)[ch]
    };
    let zero = half::f16::ZERO.to_le_bytes();
    let one = half::f16::ONE.to_le_bytes();
    let identity = |w: &mut dyn Write, n: usize| -> io::Result<()> {
        for r in 0..n {
            for c in 0..n {
                w.write_all(if r == c { &one } else { &zero })?;
            }
        }
        Ok(())
    };
    for ch in 0..3 {
        w.write_all(&[2])?;
        u32le(w, k as u32)?;
        u32le(w, pairs as u32)?;
        u32le(w, texels as u32)?;
        for _ in 0..k {
            w.write_all(&one)?;
        }
        if texels <= pairs {
            // U = M (pairs x texels), S x V = identity.
            for p in 0..pairs {
                for j in 0..texels {
                    half(w, value(j, p, ch))?;
                }
            }
            identity(w, texels)?;
        } else {
            // U = identity, S x V = M^T (texels x pairs).
            identity(w, pairs)?;
            for j in 0..texels {
                for p in 0..pairs {
                    half(w, value(j, p, ch))?;
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
#[path = "ubo2014_tests.rs"]
pub(crate) mod tests;
