//! Importing a measured BTF from a folder of rectified images, one per (light, view)
//! pair, listed with their directions in `directions.csv` (`file,theta_i,phi_i,
//! theta_v,phi_v`, degrees) or `directions.toml` (`[[image]]` tables with the same
//! keys). Every pair of the listed light and view sets must appear exactly once; all
//! images must share one size and hold finite values. Format: docs/formats/btf.md.

use std::path::{Path, PathBuf};

use glam::DVec3;
use rayon::prelude::*;
use serde::Deserialize;

use super::{Btf, BtfError, directions};
use crate::image::{self, ImageError};

#[derive(Debug, thiserror::Error)]
#[error("`{}`: {kind}", path.display())]
pub struct ImportError {
    /// The listing, or the image at fault.
    pub path: PathBuf,
    pub kind: Box<ImportErrorKind>,
}

#[derive(Debug, thiserror::Error)]
pub enum ImportErrorKind {
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    #[error("no `directions.csv` or `directions.toml` in the folder")]
    NoListing,
    #[error("line {line}: {problem}")]
    Csv { line: usize, problem: String },
    #[error("{0}")]
    Toml(String),
    #[error("{entry}: `{key}` = {value}: {rule}")]
    Angle {
        entry: String,
        key: &'static str,
        value: f64,
        rule: &'static str,
    },
    #[error("the listing names no images")]
    Empty,
    #[error(
        "{first} and {second} both give light ({theta_i}, {phi_i}) deg with view ({theta_v}, {phi_v}) deg"
    )]
    DuplicatePair {
        first: String,
        second: String,
        theta_i: f64,
        phi_i: f64,
        theta_v: f64,
        phi_v: f64,
    },
    #[error(
        "no image for light ({theta_i:.2}, {phi_i:.2}) deg with view ({theta_v:.2}, {phi_v:.2}) deg: the listing has {lights} lights and {views} views, so {expected} images are needed, found {found}"
    )]
    MissingPair {
        theta_i: f64,
        phi_i: f64,
        theta_v: f64,
        phi_v: f64,
        lights: usize,
        views: usize,
        expected: usize,
        found: usize,
    },
    #[error("image listed on {entry}: {source}")]
    Image { entry: String, source: ImageError },
    #[error("image listed on {entry} is {found_w}x{found_h}, but `{}` is {w}x{h}: all images must have one size", first.display())]
    Size {
        entry: String,
        found_w: u32,
        found_h: u32,
        first: PathBuf,
        w: u32,
        h: u32,
    },
    #[error("image listed on {entry}: pixel ({x}, {y}) channel {channel} = {value} is not finite")]
    NonFinite {
        entry: String,
        x: u32,
        y: u32,
        channel: usize,
        value: f32,
    },
    #[error("{0}")]
    Btf(#[from] BtfError),
}

/// One listed image and where it was listed.
#[derive(Debug, Clone)]
struct Entry {
    file: PathBuf,
    /// "line 3" (CSV) or "image 2" (TOML), for messages.
    place: String,
    angles: [f64; 4],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlListing {
    image: Vec<TomlEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlEntry {
    file: PathBuf,
    theta_i: f64,
    phi_i: f64,
    theta_v: f64,
    phi_v: f64,
}

const KEYS: [&str; 4] = ["theta_i", "phi_i", "theta_v", "phi_v"];

fn parse_csv(text: &str) -> Result<Vec<Entry>, ImportErrorKind> {
    let mut out = Vec::new();
    let mut header_seen = false;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let row = raw.trim();
        if row.is_empty() || row.starts_with('#') {
            continue;
        }
        let cols: Vec<&str> = row.split(',').map(str::trim).collect();
        if !header_seen {
            header_seen = true;
            let want = ["file", "theta_i", "phi_i", "theta_v", "phi_v"];
            if cols != want {
                return Err(ImportErrorKind::Csv {
                    line,
                    problem: format!("header is `{row}`, expected `{}`", want.join(",")),
                });
            }
            continue;
        }
        if cols.len() != 5 {
            return Err(ImportErrorKind::Csv {
                line,
                problem: format!(
                    "{} columns, expected 5 (file,theta_i,phi_i,theta_v,phi_v)",
                    cols.len()
                ),
            });
        }
        let mut angles = [0.0; 4];
        for k in 0..4 {
            angles[k] = cols[k + 1].parse().map_err(|_| ImportErrorKind::Csv {
                line,
                problem: format!("`{}` = `{}` is not a number", KEYS[k], cols[k + 1]),
            })?;
        }
        out.push(Entry {
            file: PathBuf::from(cols[0]),
            place: format!("line {line}"),
            angles,
        });
    }
    Ok(out)
}

fn parse_toml(text: &str) -> Result<Vec<Entry>, ImportErrorKind> {
    let l: TomlListing = toml::from_str(text).map_err(|e| ImportErrorKind::Toml(e.to_string()))?;
    Ok(l.image
        .into_iter()
        .enumerate()
        .map(|(k, e)| Entry {
            place: format!("[[image]] {k} (`{}`)", e.file.display()),
            file: e.file,
            angles: [e.theta_i, e.phi_i, e.theta_v, e.phi_v],
        })
        .collect())
}

/// Index of `d` in `set` (within 1e-6), adding it when new.
fn index_of(set: &mut Vec<DVec3>, d: DVec3) -> usize {
    match set.iter().position(|e| e.distance_squared(d) < 1e-12) {
        Some(i) => i,
        None => {
            set.push(d);
            set.len() - 1
        }
    }
}

/// Reads the listing in `dir` and its images into a BTF named `name`.
pub fn import_dir(dir: &Path, name: &str) -> Result<Btf, ImportError> {
    let csv = dir.join("directions.csv");
    let toml_path = dir.join("directions.toml");
    let (listing, entries) = if csv.exists() {
        let text = std::fs::read_to_string(&csv).map_err(|e| err(&csv, e.into()))?;
        (csv.clone(), parse_csv(&text).map_err(|k| err(&csv, k))?)
    } else if toml_path.exists() {
        let text = std::fs::read_to_string(&toml_path).map_err(|e| err(&toml_path, e.into()))?;
        (
            toml_path.clone(),
            parse_toml(&text).map_err(|k| err(&toml_path, k))?,
        )
    } else {
        return Err(err(dir, ImportErrorKind::NoListing));
    };
    let at = |kind| err(&listing, kind);
    if entries.is_empty() {
        return Err(at(ImportErrorKind::Empty));
    }
    let (mut lights, mut views) = (Vec::new(), Vec::new());
    let mut pairs = Vec::with_capacity(entries.len());
    for e in &entries {
        for (k, &a) in e.angles.iter().enumerate() {
            let polar = k % 2 == 0;
            if !a.is_finite() || (polar && !(0.0..90.0).contains(&a)) {
                return Err(at(ImportErrorKind::Angle {
                    entry: e.place.clone(),
                    key: KEYS[k],
                    value: a,
                    rule: if polar {
                        "polar angles are in [0, 90) degrees"
                    } else {
                        "azimuths must be finite"
                    },
                }));
            }
        }
        let l = index_of(
            &mut lights,
            directions::from_angles_deg(e.angles[0], e.angles[1]),
        );
        let v = index_of(
            &mut views,
            directions::from_angles_deg(e.angles[2], e.angles[3]),
        );
        pairs.push((l, v));
    }
    let (nl, nv) = (lights.len(), views.len());
    let mut slot: Vec<Option<usize>> = vec![None; nl * nv];
    for (k, &(l, v)) in pairs.iter().enumerate() {
        if let Some(first) = slot[l * nv + v] {
            let a = entries[k].angles;
            return Err(at(ImportErrorKind::DuplicatePair {
                first: entries[first].place.clone(),
                second: entries[k].place.clone(),
                theta_i: a[0],
                phi_i: a[1],
                theta_v: a[2],
                phi_v: a[3],
            }));
        }
        slot[l * nv + v] = Some(k);
    }
    if let Some(missing) = slot.iter().position(Option::is_none) {
        let (ti, pi) = directions::to_angles_deg(lights[missing / nv]);
        let (tv, pv) = directions::to_angles_deg(views[missing % nv]);
        return Err(at(ImportErrorKind::MissingPair {
            theta_i: ti,
            phi_i: pi,
            theta_v: tv,
            phi_v: pv,
            lights: nl,
            views: nv,
            expected: nl * nv,
            found: entries.len(),
        }));
    }
    // Read the first image for the size, then all in parallel.
    let first_path = dir.join(&entries[0].file);
    let first = image::read_image(&first_path).map_err(|source| {
        at(ImportErrorKind::Image {
            entry: entries[0].place.clone(),
            source,
        })
    })?;
    let (w, h) = (first.width(), first.height());
    let texels = (w * h) as usize;
    let images: Vec<image::Image> = entries
        .par_iter()
        .map(|e| {
            let path = dir.join(&e.file);
            let img = image::read_image(&path).map_err(|source| ImportErrorKind::Image {
                entry: e.place.clone(),
                source,
            })?;
            if img.width() != w || img.height() != h {
                return Err(ImportErrorKind::Size {
                    entry: e.place.clone(),
                    found_w: img.width(),
                    found_h: img.height(),
                    first: first_path.clone(),
                    w,
                    h,
                });
            }
            for (i, px) in img.pixels().iter().enumerate() {
                if let Some(channel) = px.iter().position(|x| !x.is_finite()) {
                    return Err(ImportErrorKind::NonFinite {
                        entry: e.place.clone(),
                        x: i as u32 % w,
                        y: i as u32 / w,
                        channel,
                        value: px[channel],
                    });
                }
            }
            Ok(img)
        })
        .collect::<Result<_, _>>()
        .map_err(at)?;
    let mut data = vec![0.0f32; texels * nl * nv * 3];
    data.par_chunks_mut(nl * nv * 3)
        .enumerate()
        .for_each(|(t, out)| {
            for (k, &(l, v)) in pairs.iter().enumerate() {
                let px = images[k].pixels()[t];
                out[(l * nv + v) * 3..(l * nv + v) * 3 + 3].copy_from_slice(&px);
            }
        });
    Btf::new(
        name.to_string(),
        format!("meso btf import {}", dir.display()),
        w,
        h,
        lights,
        views,
        data,
    )
    .map_err(|e| at(e.into()))
}

fn err(path: &Path, kind: ImportErrorKind) -> ImportError {
    ImportError {
        path: path.to_path_buf(),
        kind: Box::new(kind),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::btf::file;
    use crate::image::{Image, write_image};

    /// Writes a 3x2-texel image set of 2 lights x 2 views as EXR, value = pair index.
    fn image_set(dir: &Path) -> String {
        let mut csv = String::from("file,theta_i,phi_i,theta_v,phi_v\n");
        let dirs = [(0.0, 0.0), (45.0, 90.0)];
        for (l, (ti, pi)) in dirs.iter().enumerate() {
            for (v, (tv, pv)) in dirs.iter().enumerate() {
                let mut img = Image::new(3, 2);
                for y in 0..2 {
                    for x in 0..3 {
                        img.set(x, y, [(l * 2 + v) as f32, x as f32, y as f32]);
                    }
                }
                let f = format!("l{l}v{v}.exr");
                write_image(&dir.join(&f), &img, 0.0).expect("write exr");
                csv.push_str(&format!("{f},{ti},{pi},{tv},{pv}\n"));
            }
        }
        csv
    }

    #[test]
    fn imports_and_round_trips_through_the_file() {
        let dir = tempfile::tempdir().expect("temp dir");
        let csv = image_set(dir.path());
        std::fs::write(dir.path().join("directions.csv"), &csv).expect("write csv");
        let btf = import_dir(dir.path(), "set").expect("import");
        assert_eq!((btf.width(), btf.height(), btf.pairs()), (3, 2, 4));
        assert_eq!(btf.value(4, 1, 0), [2.0, 1.0, 1.0]);
        assert!((btf.light_dirs()[1] - directions::from_angles_deg(45.0, 90.0)).length() < 1e-12);
        let path = dir.path().join("set.btf");
        file::write_btf(&path, &btf, file::BtfPrecision::F32).expect("write");
        assert_eq!(file::read_btf(&path).expect("read"), btf);
        // The same listing as TOML.
        let toml: String = csv
            .lines()
            .skip(1)
            .map(|l| {
                let c: Vec<&str> = l.split(',').collect();
                format!(
                    "[[image]]\nfile = \"{}\"\ntheta_i = {}.0\nphi_i = {}.0\ntheta_v = {}.0\nphi_v = {}.0\n",
                    c[0], c[1], c[2], c[3], c[4]
                )
            })
            .collect();
        std::fs::remove_file(dir.path().join("directions.csv")).expect("rm");
        std::fs::write(dir.path().join("directions.toml"), toml).expect("write toml");
        assert_eq!(
            import_dir(dir.path(), "set").expect("toml import").data(),
            btf.data()
        );
    }

    #[test]
    fn bad_image_sets_are_named() {
        let dir = tempfile::tempdir().expect("temp dir");
        let csv = image_set(dir.path());
        let check = |listing: &str, needles: &[&str]| {
            std::fs::write(dir.path().join("directions.csv"), listing).expect("write");
            let e = import_dir(dir.path(), "x")
                .expect_err("must fail")
                .to_string();
            for n in needles {
                assert!(e.contains(n), "`{e}` should mention `{n}`");
            }
        };
        // A missing file.
        check(
            &csv.replace("l1v1.exr", "gone.exr"),
            &["line 5", "gone.exr"],
        );
        // A missing pair.
        let three: String = csv.lines().take(4).map(|l| format!("{l}\n")).collect();
        check(
            &three,
            &[
                "no image for light (45.00, 90.00)",
                "4 images are needed, found 3",
            ],
        );
        // A duplicate pair.
        check(
            &csv.replace("l1v1.exr,45,90,45,90", "l1v1.exr,45,90,0,0"),
            &["line 4", "line 5"],
        );
        // A bad angle and a malformed row.
        check(
            &csv.replace("l1v1.exr,45,90", "l1v1.exr,95,90"),
            &["line 5", "theta_i", "[0, 90)"],
        );
        check(
            &csv.replace("l1v1.exr,45,90", "l1v1.exr,4x,90"),
            &["line 5", "theta_i", "4x"],
        );
        check("name,a\n", &["line 1", "header"]);
        // A mismatched size.
        write_image(&dir.path().join("l0v1.exr"), &Image::new(4, 2), 0.0).expect("write");
        check(&csv, &["line 3", "4x2", "3x2"]);
        // A non-finite value.
        let mut img = Image::new(3, 2);
        img.set(2, 1, [0.0, f32::NAN, 0.0]);
        write_image(&dir.path().join("l0v1.exr"), &img, 0.0).expect("write");
        check(&csv, &["line 3", "pixel (2, 1) channel 1", "NaN"]);
        std::fs::remove_file(dir.path().join("directions.csv")).expect("rm");
        let e = import_dir(dir.path(), "x")
            .expect_err("no listing")
            .to_string();
        assert!(e.contains("directions.csv"), "{e}");
    }
}
