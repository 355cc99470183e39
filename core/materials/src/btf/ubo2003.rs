//! UBO2003 and ATRIUM BTFs (University of Bonn): zip archives of rectified images, one
//! per light and view direction, named by the directions' angles in whole degrees,
//! `tl015 pl060 tv030 pv120.jpg` (theta and phi of the light, then of the view), in any
//! folder of the archive: 8-bit sRGB JPEGs, or for ATRIUM's HDR archives linear
//! Radiance RGBE images (`.hdr`). The archive is read directly: entries are listed,
//! grouped into a light set and a view set (each sorted by theta, then phi: the
//! database's ring order), checked complete, decoded in batches (each image held as
//! its kept texels, in the entry's own precision: 8-bit codes or f32) and only then
//! put into the BTF, so memory follows what has been decoded and a damaged archive is
//! refused before the BTF is allocated. Format: docs/formats/ubo.md.

use std::io::{Read, Seek};
use std::path::{Path, PathBuf};

use glam::DVec3;
use image::{ImageFormat, ImageReader, Limits};
use rayon::prelude::*;

use super::crop::{self, CropError, TexelRect};
use super::{Btf, BtfError, MAX_SIDE, directions};

/// Largest image entry read (the database's JPEGs are well under 1 MB; an 800 x 800
/// RGBE image is 2.6 MB).
const MAX_ENTRY_BYTES: u64 = 64 << 20;
/// `import_zip`'s default bound on the BTF it builds: the values as f32, as many as an
/// import builds at most (`crop::MAX_IMPORT_VALUES`, 8 GiB).
pub const DEFAULT_MAX_IMPORT_BYTES: u64 = crop::MAX_IMPORT_VALUES * 4;
/// Images decoded at once.
const BATCH: usize = 64;

#[derive(Debug, thiserror::Error)]
#[error("`{}`: {kind}", path.display())]
pub struct ZipImportError {
    pub path: PathBuf,
    pub kind: Box<ZipImportErrorKind>,
}

#[derive(Debug, thiserror::Error)]
pub enum ZipImportErrorKind {
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    #[error("not a readable zip archive: {0}")]
    Zip(String),
    #[error("entry {index}: {problem}")]
    Entry { index: usize, problem: String },
    #[error(
        "entry `{entry}`: an image named `tlTTT plPPP tvTTT pvPPP.jpg` or `.hdr` (whole degrees) was expected: {problem}"
    )]
    Name { entry: String, problem: String },
    #[error("no `tl.. pl.. tv.. pv...jpg` or `.hdr` images in the archive")]
    Empty,
    #[error(
        "entry `{second}` is a {second_kind} but `{first}` is a {first_kind}: an archive holds one kind of image"
    )]
    Mixed {
        first: String,
        first_kind: ImageKind,
        second: String,
        second_kind: ImageKind,
    },
    #[error(
        "`{entry}` is {w}x{h}, so the BTF would hold {texels} texels x {pairs} direction pairs x 3 values = {bytes} bytes as f32, more than the import's bound of {max_bytes} bytes (--max-memory); keep fewer texels with --texels X,Y,W,H (at most {max_texels} texels) or raise the bound"
    )]
    OverBound {
        entry: String,
        w: u32,
        h: u32,
        texels: u64,
        pairs: u64,
        bytes: u64,
        max_bytes: u64,
        max_texels: u64,
    },
    #[error("`{first}` and `{second}` both give light ({0}, {1}) deg with view ({2}, {3}) deg", angles[0], angles[1], angles[2], angles[3])]
    Duplicate {
        first: String,
        second: String,
        angles: [u32; 4],
    },
    #[error(
        "no image for light ({}, {}) deg with view ({}, {}) deg: the archive has {lights} lights and {views} views, so {expected} images are needed, found {found}",
        angles[0], angles[1], angles[2], angles[3]
    )]
    Missing {
        angles: [u32; 4],
        lights: usize,
        views: usize,
        expected: usize,
        found: usize,
    },
    #[error(
        "entry `{entry}` is {size} bytes uncompressed, more than a BTF image may be ({MAX_ENTRY_BYTES})"
    )]
    EntryTooLarge { entry: String, size: u64 },
    #[error("entry `{entry}`: {problem}")]
    Image { entry: String, problem: String },
    #[error(
        "entry `{entry}` is {found_w}x{found_h}, but `{first}` is {w}x{h}: all images must have one size"
    )]
    Size {
        entry: String,
        found_w: u32,
        found_h: u32,
        first: String,
        w: u32,
        h: u32,
    },
    #[error("{0}")]
    Crop(#[from] CropError),
    #[error("{0}")]
    Btf(#[from] BtfError),
}

/// What an archive's images are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageKind {
    /// 8-bit sRGB JPEG (UBO2003, ATRIUM).
    Jpeg,
    /// Radiance RGBE, linear (ATRIUM's HDR archives).
    RadianceHdr,
}

impl std::fmt::Display for ImageKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ImageKind::Jpeg => "JPEG",
            ImageKind::RadianceHdr => "Radiance HDR image",
        })
    }
}

/// The angles `[theta_l, phi_l, theta_v, phi_v]` in degrees of an entry's file name
/// (the part after the last `/`), or why it is not one. `Ok(None)`: not an image.
pub fn parse_name(entry: &str) -> Result<Option<[u32; 4]>, String> {
    Ok(parse_entry(entry)?.map(|(angles, _)| angles))
}

/// `parse_name` and the kind of image the name's extension gives.
pub fn parse_entry(entry: &str) -> Result<Option<([u32; 4], ImageKind)>, String> {
    let file = entry.rsplit('/').next().unwrap_or(entry);
    let lower = file.to_ascii_lowercase();
    let Some((stem, kind)) = [
        (".jpg", ImageKind::Jpeg),
        (".jpeg", ImageKind::Jpeg),
        (".hdr", ImageKind::RadianceHdr),
    ]
    .into_iter()
    .find_map(|(ext, kind)| lower.strip_suffix(ext).map(|stem| (stem, kind))) else {
        return Ok(None);
    };
    let parts: Vec<&str> = stem.split_whitespace().collect();
    let keys = ["tl", "pl", "tv", "pv"];
    if parts.len() != 4 {
        return Err(format!(
            "{} space-separated fields, expected 4",
            parts.len()
        ));
    }
    let mut out = [0u32; 4];
    for (k, (part, key)) in parts.iter().zip(keys).enumerate() {
        let digits = part
            .strip_prefix(key)
            .ok_or_else(|| format!("field {} is `{part}`, expected `{key}` and degrees", k + 1))?;
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.len() > 3 {
            return Err(format!(
                "`{part}`: `{key}` must be followed by 1 to 3 digits"
            ));
        }
        out[k] = digits.parse().expect("1 to 3 digits");
    }
    for (k, key) in [(0, "tl"), (2, "tv")] {
        if out[k] >= 90 {
            return Err(format!(
                "{key} = {} is not below the horizon's 90 degrees",
                out[k]
            ));
        }
    }
    // The pole has no azimuth; azimuths wrap at 360.
    for t in [0, 2] {
        out[t + 1] = if out[t] == 0 { 0 } else { out[t + 1] % 360 };
    }
    Ok(Some((out, kind)))
}

/// One listed image.
struct Listed {
    index: usize,
    name: String,
    angles: [u32; 4],
}

/// One decoded image's kept texels (row-major within the crop), in the entry's
/// precision: 8-bit sRGB codes (JPEG) or linear f32 (RGBE).
enum Decoded {
    Codes(Vec<[u8; 3]>),
    Linear(Vec<[f32; 3]>),
}

fn image_reader(bytes: &[u8], format: ImageFormat) -> ImageReader<std::io::Cursor<&[u8]>> {
    let mut reader = ImageReader::with_format(std::io::Cursor::new(bytes), format);
    let mut limits = Limits::default();
    limits.max_image_width = Some(MAX_SIDE);
    limits.max_image_height = Some(MAX_SIDE);
    limits.max_alloc = Some(512 << 20);
    reader.limits(limits);
    reader
}

/// A Radiance file's bytes as the `image` crate's decoder reads them, and whether its
/// rows are then bottom-up. The decoder reads the standard resolution line `-Y H +X W`
/// (rows top-down); ATRIUM's HDR images say `+X N -Y N`, which btf_extractor reads by
/// rewriting it to `-Y N +X N` and turning the rows upside down: done the same way
/// here, for square images only (the only ones seen); any other line is refused.
fn radiance_rows(bytes: &[u8]) -> Result<(std::borrow::Cow<'_, [u8]>, bool), String> {
    let header_end = bytes
        .windows(2)
        .position(|w| w == b"\n\n")
        .filter(|&p| p < 64 << 10)
        .ok_or("no end of the Radiance header (an empty line) in its first 64 KiB")?
        + 2;
    let line_end = bytes[header_end..]
        .iter()
        .take(256)
        .position(|&b| b == b'\n')
        .ok_or("no resolution line after the Radiance header")?
        + header_end;
    let line = String::from_utf8_lossy(&bytes[header_end..line_end]);
    let fields: Vec<&str> = line.split_whitespace().collect();
    match fields[..] {
        ["-Y", _, "+X", _] => Ok((bytes.into(), false)),
        ["+X", w, "-Y", h] if w == h => {
            let mut fixed = bytes[..header_end].to_vec();
            fixed.extend_from_slice(format!("-Y {h} +X {w}").as_bytes());
            fixed.extend_from_slice(&bytes[line_end..]);
            Ok((fixed.into(), true))
        }
        _ => Err(format!(
            "resolution line `{}`: only `-Y H +X W` and ATRIUM's `+X N -Y N` are read",
            line.trim()
        )),
    }
}

/// The pixels of `rect` (row-major) of an image of `size` read by `pixel(x, row)`,
/// rows counted from the bottom when `bottom_up`; `None` without a rect or when it
/// does not fit (the caller reports the size).
fn kept_texels<P>(
    size: (u32, u32),
    rect: Option<TexelRect>,
    bottom_up: bool,
    pixel: impl Fn(u32, u32) -> P,
) -> Option<Vec<P>> {
    let r = rect.filter(|r| r.check_inside(size.0, size.1).is_ok())?;
    let mut px = Vec::with_capacity(r.texels());
    for y in r.y..r.y + r.height {
        let row = if bottom_up { size.1 - 1 - y } else { y };
        for x in r.x..r.x + r.width {
            px.push(pixel(x, row));
        }
    }
    Some(px)
}

/// Decodes one image entry whole: its size, and its texels of `rect` (None: only the
/// size), or why not (naming nothing: the caller names the entry).
fn decode(
    bytes: &[u8],
    kind: ImageKind,
    rect: Option<TexelRect>,
) -> Result<((u32, u32), Option<Decoded>), String> {
    match kind {
        ImageKind::Jpeg => {
            let img = image_reader(bytes, ImageFormat::Jpeg)
                .decode()
                .map_err(|e| e.to_string())?
                .into_rgb8();
            let size = (img.width(), img.height());
            let kept = kept_texels(size, rect, false, |x, y| img.get_pixel(x, y).0);
            Ok((size, kept.map(Decoded::Codes)))
        }
        ImageKind::RadianceHdr => {
            let (fixed, bottom_up) = radiance_rows(bytes)?;
            let img = image_reader(&fixed, ImageFormat::Hdr)
                .decode()
                .map_err(|e| e.to_string())?
                .into_rgb32f();
            let size = (img.width(), img.height());
            let kept = kept_texels(size, rect, bottom_up, |x, y| img.get_pixel(x, y).0);
            Ok((size, kept.map(Decoded::Linear)))
        }
    }
}

/// Reads entry `index` whole, refusing more than `MAX_ENTRY_BYTES`.
fn entry_bytes<R: Read + Seek>(
    zip: &mut zip::ZipArchive<R>,
    l: &Listed,
) -> Result<Vec<u8>, ZipImportErrorKind> {
    let file = zip
        .by_index(l.index)
        .map_err(|e| ZipImportErrorKind::Image {
            entry: l.name.clone(),
            problem: e.to_string(),
        })?;
    if file.size() > MAX_ENTRY_BYTES {
        return Err(ZipImportErrorKind::EntryTooLarge {
            entry: l.name.clone(),
            size: file.size(),
        });
    }
    let mut bytes = Vec::new();
    file.take(MAX_ENTRY_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| ZipImportErrorKind::Image {
            entry: l.name.clone(),
            problem: format!("cannot decompress: {e}"),
        })?;
    if bytes.len() as u64 > MAX_ENTRY_BYTES {
        return Err(ZipImportErrorKind::EntryTooLarge {
            entry: l.name.clone(),
            size: bytes.len() as u64,
        });
    }
    Ok(bytes)
}

/// Imports the archive at `path` (texels of `rect`, default all) as a BTF named `name`,
/// its values (as f32) within `max_bytes` (`DEFAULT_MAX_IMPORT_BYTES` for no more
/// than any import builds).
pub fn import_zip(
    path: &Path,
    name: &str,
    rect: Option<TexelRect>,
    max_bytes: u64,
) -> Result<Btf, ZipImportError> {
    let at = |kind: ZipImportErrorKind| ZipImportError {
        path: path.to_path_buf(),
        kind: Box::new(kind),
    };
    let file = std::fs::File::open(path).map_err(|e| at(e.into()))?;
    let provenance = format!(
        "meso btf import {} (UBO2003 zip{})",
        path.display(),
        rect.map(|r| format!(", texels {r}")).unwrap_or_default()
    );
    read_zip_within(
        std::io::BufReader::new(file),
        name,
        &provenance,
        rect,
        max_bytes,
    )
    .map_err(at)
}

/// Imports a UBO2003/ATRIUM archive from any reader (see `import_zip`), within
/// `DEFAULT_MAX_IMPORT_BYTES`.
pub fn read_zip<R: Read + Seek>(
    reader: R,
    name: &str,
    provenance: &str,
    rect: Option<TexelRect>,
) -> Result<Btf, ZipImportErrorKind> {
    read_zip_within(reader, name, provenance, rect, DEFAULT_MAX_IMPORT_BYTES)
}

/// `read_zip` with the BTF's values (as f32) bounded by `max_bytes`.
pub fn read_zip_within<R: Read + Seek>(
    reader: R,
    name: &str,
    provenance: &str,
    rect: Option<TexelRect>,
    max_bytes: u64,
) -> Result<Btf, ZipImportErrorKind> {
    let mut zip =
        zip::ZipArchive::new(reader).map_err(|e| ZipImportErrorKind::Zip(e.to_string()))?;
    let mut listed = Vec::new();
    let mut kind: Option<(ImageKind, String)> = None;
    for index in 0..zip.len() {
        let entry = zip
            .name_for_index(index)
            .ok_or_else(|| ZipImportErrorKind::Entry {
                index,
                problem: "missing from the central directory".into(),
            })?
            .map_err(|e| ZipImportErrorKind::Entry {
                index,
                problem: e.to_string(),
            })?
            .into_owned();
        if entry.ends_with('/') {
            continue;
        }
        match parse_entry(&entry) {
            Ok(Some((angles, k))) => {
                match &kind {
                    None => kind = Some((k, entry.clone())),
                    Some((first_kind, first)) if *first_kind != k => {
                        return Err(ZipImportErrorKind::Mixed {
                            first: first.clone(),
                            first_kind: *first_kind,
                            second: entry,
                            second_kind: k,
                        });
                    }
                    Some(_) => {}
                }
                listed.push(Listed {
                    index,
                    name: entry,
                    angles,
                })
            }
            Ok(None) => {}
            Err(problem) => return Err(ZipImportErrorKind::Name { entry, problem }),
        }
    }
    let Some((kind, _)) = kind else {
        return Err(ZipImportErrorKind::Empty);
    };
    // Light and view sets, each in ring order (theta, then phi).
    let set = |pick: fn(&[u32; 4]) -> [u32; 2]| {
        let mut s: Vec<[u32; 2]> = listed.iter().map(|l| pick(&l.angles)).collect();
        s.sort_unstable();
        s.dedup();
        s
    };
    let lights = set(|a| [a[0], a[1]]);
    let views = set(|a| [a[2], a[3]]);
    let (nl, nv) = (lights.len(), views.len());
    let mut slot: Vec<Option<usize>> = vec![None; nl * nv];
    for (k, l) in listed.iter().enumerate() {
        let li = lights
            .binary_search(&[l.angles[0], l.angles[1]])
            .expect("listed");
        let vi = views
            .binary_search(&[l.angles[2], l.angles[3]])
            .expect("listed");
        if let Some(first) = slot[li * nv + vi] {
            return Err(ZipImportErrorKind::Duplicate {
                first: listed[first].name.clone(),
                second: l.name.clone(),
                angles: l.angles,
            });
        }
        slot[li * nv + vi] = Some(k);
    }
    if let Some(missing) = slot.iter().position(Option::is_none) {
        let (l, v) = (lights[missing / nv], views[missing % nv]);
        return Err(ZipImportErrorKind::Missing {
            angles: [l[0], l[1], v[0], v[1]],
            lights: nl,
            views: nv,
            expected: nl * nv,
            found: listed.len(),
        });
    }
    let order: Vec<&Listed> = slot.iter().map(|s| &listed[s.expect("complete")]).collect();
    // The first image's size fixes the grid; the crop and the bounds are checked
    // before anything else is decoded. It is decoded whole, so a size only its
    // header claims is refused by the decoder.
    let first = order[0];
    let (w, h) = decode(&entry_bytes(&mut zip, first)?, kind, None)
        .map_err(|problem| ZipImportErrorKind::Image {
            entry: first.name.clone(),
            problem,
        })?
        .0;
    let rect = rect.unwrap_or(TexelRect::full(w, h));
    rect.check_inside(w, h)?;
    let pairs = nl * nv;
    crop::check_budget(rect.texels() as u64, pairs as u64)?;
    let bytes = rect.texels() as u64 * pairs as u64 * 3 * 4;
    if bytes > max_bytes {
        return Err(ZipImportErrorKind::OverBound {
            entry: first.name.clone(),
            w,
            h,
            texels: rect.texels() as u64,
            pairs: pairs as u64,
            bytes,
            max_bytes,
            max_texels: max_bytes / (pairs as u64 * 12),
        });
    }
    // Every image decoded (each held as its kept texels, 3 bytes or 12 a texel) before
    // the BTF is allocated: an entry that does not decode is refused while memory
    // holds only the images before it, whatever sizes the entries claim.
    let mut images: Vec<Decoded> = Vec::with_capacity(order.len());
    for batch in order.chunks(BATCH) {
        let raw: Vec<Vec<u8>> = batch
            .iter()
            .map(|l| entry_bytes(&mut zip, l))
            .collect::<Result<_, _>>()?;
        let decoded: Vec<Decoded> = raw
            .par_iter()
            .zip(batch.par_iter())
            .map(|(bytes, l)| {
                let ((iw, ih), kept) = decode(bytes, kind, Some(rect)).map_err(|problem| {
                    ZipImportErrorKind::Image {
                        entry: l.name.clone(),
                        problem,
                    }
                })?;
                match kept {
                    Some(kept) if (iw, ih) == (w, h) => Ok(kept),
                    _ => Err(ZipImportErrorKind::Size {
                        entry: l.name.clone(),
                        found_w: iw,
                        found_h: ih,
                        first: first.name.clone(),
                        w,
                        h,
                    }),
                }
            })
            .collect::<Result<_, _>>()?;
        images.extend(decoded);
    }
    let lut: Vec<f32> = (0..=255u8)
        .map(|v| crate::image::srgb_decode(f32::from(v) / 255.0))
        .collect();
    // Zeroed pages are not resident until written, so the BTF's memory grows as the
    // batches fill it while theirs is freed.
    let mut data = vec![0.0f32; rect.texels() * pairs * 3];
    let mut images = images.into_iter();
    let mut base = 0;
    loop {
        let batch: Vec<Decoded> = images.by_ref().take(BATCH).collect();
        if batch.is_empty() {
            break;
        }
        data.par_chunks_mut(pairs * 3)
            .enumerate()
            .for_each(|(t, out)| {
                for (k, img) in batch.iter().enumerate() {
                    let p = (base + k) * 3;
                    match img {
                        Decoded::Codes(px) => {
                            for c in 0..3 {
                                out[p + c] = lut[usize::from(px[t][c])];
                            }
                        }
                        Decoded::Linear(px) => out[p..p + 3].copy_from_slice(&px[t]),
                    }
                }
            });
        base += batch.len();
    }
    let dirs = |s: &[[u32; 2]]| -> Vec<DVec3> {
        s.iter()
            .map(|a| directions::from_angles_deg(f64::from(a[0]), f64::from(a[1])))
            .collect()
    };
    Ok(Btf::new(
        name.to_string(),
        provenance.to_string(),
        rect.width,
        rect.height,
        dirs(&lights),
        dirs(&views),
        data,
    )?)
}

#[cfg(test)]
#[path = "ubo2003_tests.rs"]
mod tests;
