//! UBO2003 and ATRIUM BTFs (University of Bonn): zip archives of rectified JPEG images,
//! one per light and view direction, named by the directions' angles in whole degrees,
//! `tl015 pl060 tv030 pv120.jpg` (theta and phi of the light, then of the view), in any
//! folder of the archive. The archive is read directly: entries are listed, grouped
//! into a light set and a view set (each sorted by theta, then phi: the database's
//! ring order), checked complete, and decoded in batches straight into the BTF, so
//! memory holds the BTF and one batch of images. Format: docs/formats/ubo.md.

use std::io::{Read, Seek};
use std::path::{Path, PathBuf};

use glam::DVec3;
use image::{ImageFormat, ImageReader, Limits};
use rayon::prelude::*;

use super::crop::{self, CropError, TexelRect};
use super::{Btf, BtfError, MAX_SIDE, directions};

/// Largest JPEG entry read (the database's are well under 1 MB).
const MAX_ENTRY_BYTES: u64 = 64 << 20;
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
        "entry `{entry}`: a JPEG named `tlTTT plPPP tvTTT pvPPP.jpg` (whole degrees) was expected: {problem}"
    )]
    Name { entry: String, problem: String },
    #[error("no `tl.. pl.. tv.. pv...jpg` images in the archive")]
    Empty,
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
    Jpeg { entry: String, problem: String },
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

/// The angles `[theta_l, phi_l, theta_v, phi_v]` in degrees of an entry's file name
/// (the part after the last `/`), or why it is not one. `Ok(None)`: not a JPEG.
pub fn parse_name(entry: &str) -> Result<Option<[u32; 4]>, String> {
    let file = entry.rsplit('/').next().unwrap_or(entry);
    let lower = file.to_ascii_lowercase();
    let Some(stem) = lower
        .strip_suffix(".jpg")
        .or_else(|| lower.strip_suffix(".jpeg"))
    else {
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
    Ok(Some(out))
}

/// One listed image.
struct Listed {
    index: usize,
    name: String,
    angles: [u32; 4],
}

fn jpeg_reader(bytes: &[u8]) -> ImageReader<std::io::Cursor<&[u8]>> {
    let mut reader = ImageReader::with_format(std::io::Cursor::new(bytes), ImageFormat::Jpeg);
    let mut limits = Limits::default();
    limits.max_image_width = Some(MAX_SIDE);
    limits.max_image_height = Some(MAX_SIDE);
    limits.max_alloc = Some(512 << 20);
    reader.limits(limits);
    reader
}

/// Reads entry `index` whole, refusing more than `MAX_ENTRY_BYTES`.
fn entry_bytes<R: Read + Seek>(
    zip: &mut zip::ZipArchive<R>,
    l: &Listed,
) -> Result<Vec<u8>, ZipImportErrorKind> {
    let file = zip
        .by_index(l.index)
        .map_err(|e| ZipImportErrorKind::Jpeg {
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
        .map_err(|e| ZipImportErrorKind::Jpeg {
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

/// Imports the archive at `path` (texels of `rect`, default all) as a BTF named `name`.
pub fn import_zip(path: &Path, name: &str, rect: Option<TexelRect>) -> Result<Btf, ZipImportError> {
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
    read_zip(std::io::BufReader::new(file), name, &provenance, rect).map_err(at)
}

/// Imports a UBO2003/ATRIUM archive from any reader (see `import_zip`).
pub fn read_zip<R: Read + Seek>(
    reader: R,
    name: &str,
    provenance: &str,
    rect: Option<TexelRect>,
) -> Result<Btf, ZipImportErrorKind> {
    let mut zip =
        zip::ZipArchive::new(reader).map_err(|e| ZipImportErrorKind::Zip(e.to_string()))?;
    let mut listed = Vec::new();
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
        match parse_name(&entry) {
            Ok(Some(angles)) => listed.push(Listed {
                index,
                name: entry,
                angles,
            }),
            Ok(None) => {}
            Err(problem) => return Err(ZipImportErrorKind::Name { entry, problem }),
        }
    }
    if listed.is_empty() {
        return Err(ZipImportErrorKind::Empty);
    }
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
    // The first image's size fixes the grid; check the crop and the budget before
    // allocating the BTF.
    // It is decoded whole, so a size only its header claims is refused by the decoder.
    let first = order[0];
    let (w, h) = jpeg_reader(&entry_bytes(&mut zip, first)?)
        .decode()
        .map(|img| (img.width(), img.height()))
        .map_err(|e| ZipImportErrorKind::Jpeg {
            entry: first.name.clone(),
            problem: e.to_string(),
        })?;
    let rect = rect.unwrap_or(TexelRect::full(w, h));
    rect.check_inside(w, h)?;
    let pairs = nl * nv;
    crop::check_budget(rect.texels() as u64, pairs as u64)?;
    let lut: Vec<f32> = (0..=255u8)
        .map(|v| crate::image::srgb_decode(f32::from(v) / 255.0))
        .collect();
    let mut data = vec![0.0f32; rect.texels() * pairs * 3];
    for (b, batch) in order.chunks(BATCH).enumerate() {
        let raw: Vec<Vec<u8>> = batch
            .iter()
            .map(|l| entry_bytes(&mut zip, l))
            .collect::<Result<_, _>>()?;
        let decoded: Vec<Vec<[f32; 3]>> = raw
            .par_iter()
            .zip(batch.par_iter())
            .map(|(bytes, l)| {
                let jpeg = |problem: String| ZipImportErrorKind::Jpeg {
                    entry: l.name.clone(),
                    problem,
                };
                let img = jpeg_reader(bytes)
                    .decode()
                    .map_err(|e| jpeg(e.to_string()))?
                    .to_rgb8();
                if (img.width(), img.height()) != (w, h) {
                    return Err(ZipImportErrorKind::Size {
                        entry: l.name.clone(),
                        found_w: img.width(),
                        found_h: img.height(),
                        first: first.name.clone(),
                        w,
                        h,
                    });
                }
                let mut px = Vec::with_capacity(rect.texels());
                for y in rect.y..rect.y + rect.height {
                    for x in rect.x..rect.x + rect.width {
                        px.push(img.get_pixel(x, y).0.map(|c| lut[usize::from(c)]));
                    }
                }
                Ok(px)
            })
            .collect::<Result<_, _>>()?;
        let base = b * BATCH;
        data.par_chunks_mut(pairs * 3)
            .enumerate()
            .for_each(|(t, out)| {
                for (k, img) in decoded.iter().enumerate() {
                    let p = base + k;
                    out[p * 3..p * 3 + 3].copy_from_slice(&img[t]);
                }
            });
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
