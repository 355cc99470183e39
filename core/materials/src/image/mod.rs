//! Images: an in-memory linear Rec. 709 RGB radiance buffer and its files.
//! Reads OpenEXR (float/half RGB or Y), PNG (8/16-bit sRGB) and Radiance HDR; writes
//! EXR (float32, no exposure: EXR holds radiance) and PNG (sRGB after exposure), always
//! through `atomic::write_atomic`. docs/formats/images.md is the user-facing contract.
//! It does no colour management: PNG gamma/ICC chunks and EXR chromaticities are ignored.

mod exr;
mod hdr;
mod png;
mod tonemap;

use std::path::{Path, PathBuf};

use crate::atomic::AtomicWriteError;

pub use self::exr::{read_exr, write_exr};
pub use self::hdr::read_hdr;
pub use self::png::{encode_png, read_png, write_png};
pub use self::tonemap::{exposure_scale, srgb_decode, srgb_encode, to_srgb8};

/// Extensions `read_image` understands, for error messages.
const READABLE: &str = ".exr, .png, .hdr";
/// Extensions `write_image` understands, for error messages.
const WRITABLE: &str = ".exr, .png";

/// Linear Rec. 709 RGB radiance, row-major, row 0 at the top, `[r, g, b]` per pixel.
/// Values are not restricted: they may exceed 1, be negative, or (when read from an
/// EXR that holds them) be non-finite; `metrics::compare` rejects the latter.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    width: u32,
    height: u32,
    pixels: Vec<[f32; 3]>,
}

impl Image {
    /// A black image. Zero sizes are allowed in memory; the file writers reject them.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 3]; pixel_count(width, height)],
        }
    }

    /// Wraps a row-major pixel buffer, checking that it holds `width * height` pixels.
    pub fn from_pixels(width: u32, height: u32, pixels: Vec<[f32; 3]>) -> Result<Self, ImageError> {
        let expected = pixel_count(width, height);
        if pixels.len() != expected {
            return Err(ImageError::PixelCount {
                width,
                height,
                expected,
                found: pixels.len(),
            });
        }
        Ok(Self {
            width,
            height,
            pixels,
        })
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// All pixels, row-major from the top row.
    pub fn pixels(&self) -> &[[f32; 3]] {
        &self.pixels
    }

    pub fn pixels_mut(&mut self) -> &mut [[f32; 3]] {
        &mut self.pixels
    }

    /// The pixel at column `x`, row `y` (row 0 at the top).
    ///
    /// # Panics
    /// If `(x, y)` lies outside the image: that is a bug in the caller, like a slice index.
    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        self.pixels[self.index(x, y)]
    }

    /// Sets the pixel at column `x`, row `y`.
    ///
    /// # Panics
    /// If `(x, y)` lies outside the image.
    pub fn set(&mut self, x: u32, y: u32, rgb: [f32; 3]) {
        let i = self.index(x, y);
        self.pixels[i] = rgb;
    }

    fn index(&self, x: u32, y: u32) -> usize {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside a {}x{} image",
            self.width,
            self.height
        );
        y as usize * self.width as usize + x as usize
    }
}

fn pixel_count(width: u32, height: u32) -> usize {
    // u32 * u32 fits u64; on 64-bit targets it fits usize too.
    usize::try_from(u64::from(width) * u64::from(height))
        .expect("pixel count fits usize on 64-bit targets")
}

/// Rec. 709 / sRGB relative luminance (ITU-R BT.709-6, item 3.2): 0.2126 R + 0.7152 G + 0.0722 B.
pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// Errors of image I/O. Every file-related message names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("a {width}x{height} image needs {expected} pixels, the buffer holds {found}")]
    PixelCount {
        width: u32,
        height: u32,
        expected: usize,
        found: usize,
    },
    #[error("cannot read `{path}`: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("`{path}`: unsupported image extension {extension}; Meso {action} {supported}")]
    UnsupportedExtension {
        path: PathBuf,
        /// The extension as found (with its dot), or "(none)".
        extension: String,
        action: &'static str,
        supported: &'static str,
    },
    #[error("`{path}` is not a readable {format} file: {reason}")]
    Decode {
        path: PathBuf,
        format: &'static str,
        reason: String,
    },
    #[error("`{path}`: no R,G,B or Y channel in the first layer (channels found: {found})")]
    NoColorChannels { path: PathBuf, found: String },
    #[error("`{path}`: layer size {width}x{height}; an image needs at least one pixel")]
    Empty {
        path: PathBuf,
        width: usize,
        height: usize,
    },
    #[error("`{path}`: layer size {width}x{height} exceeds the {max} pixel limit per side")]
    TooLarge {
        path: PathBuf,
        width: usize,
        height: usize,
        max: u32,
    },
    #[error("cannot encode `{path}` as {format}: {reason}")]
    Encode {
        path: PathBuf,
        format: &'static str,
        reason: String,
    },
    #[error(transparent)]
    Write(#[from] AtomicWriteError),
}

/// The lower-case extension of `path`, with its dot, or `None`.
fn extension(path: &Path) -> Option<String> {
    path.extension()
        .map(|e| format!(".{}", e.to_string_lossy().to_ascii_lowercase()))
}

fn unsupported(path: &Path, action: &'static str, supported: &'static str) -> ImageError {
    ImageError::UnsupportedExtension {
        path: path.to_path_buf(),
        extension: path.extension().map_or_else(
            || "(none)".to_owned(),
            |e| format!("`.{}`", e.to_string_lossy()),
        ),
        action,
        supported,
    }
}

/// Reads an image by its extension (case-insensitive): `.exr` (linear float or half; R,G,B
/// or Y-only as grey), `.png` (8/16-bit, sRGB decoded to linear, alpha ignored) or `.hdr`
/// (Radiance RGBE, linear). Non-finite EXR samples are kept as they are.
pub fn read_image(path: &Path) -> Result<Image, ImageError> {
    match extension(path).as_deref() {
        Some(".exr") => read_exr(path),
        Some(".png") => read_png(path),
        Some(".hdr") => read_hdr(path),
        _ => Err(unsupported(path, "reads", READABLE)),
    }
}

/// Writes an image by its extension (case-insensitive), whole or not at all: `.exr` holds
/// linear float32 radiance and ignores `exposure_stops`; `.png` holds 8-bit sRGB of the
/// radiance scaled by `2^exposure_stops` and clamped to [0, 1] (`to_srgb8`).
pub fn write_image(path: &Path, image: &Image, exposure_stops: f64) -> Result<(), ImageError> {
    match extension(path).as_deref() {
        Some(".exr") => write_exr(path, image),
        Some(".png") => write_png(path, image, exposure_stops),
        _ => Err(unsupported(path, "writes", WRITABLE)),
    }
}

/// Reads a whole file, naming it in the error.
fn read_bytes(path: &Path) -> Result<Vec<u8>, ImageError> {
    std::fs::read(path).map_err(|source| ImageError::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// Largest width or height Meso accepts from a file: beyond this a corrupt header would
/// make us allocate absurd buffers (and the pixel count would not fit `u32` coordinates).
const MAX_SIDE: u32 = 1 << 16;

/// Checks a decoded size and converts it to `u32`.
fn checked_size(path: &Path, width: usize, height: usize) -> Result<(u32, u32), ImageError> {
    if width == 0 || height == 0 {
        return Err(ImageError::Empty {
            path: path.to_path_buf(),
            width,
            height,
        });
    }
    match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if w <= MAX_SIDE && h <= MAX_SIDE => Ok((w, h)),
        _ => Err(ImageError::TooLarge {
            path: path.to_path_buf(),
            width,
            height,
            max: MAX_SIDE,
        }),
    }
}

/// Rejects zero-sized images before a writer sees them.
fn check_writable(path: &Path, image: &Image, format: &'static str) -> Result<(), ImageError> {
    if image.width == 0 || image.height == 0 {
        return Err(ImageError::Encode {
            path: path.to_path_buf(),
            format,
            reason: format!(
                "the image is {}x{}; a file needs at least one pixel",
                image.width, image.height
            ),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_pixels_checks_length_and_indexing_is_row_major() {
        let err = Image::from_pixels(3, 2, vec![[0.0; 3]; 5]).expect_err("5 != 6");
        assert!(
            err.to_string().contains("3x2") && err.to_string().contains('5'),
            "{err}"
        );
        let pixels: Vec<[f32; 3]> = (0..6).map(|i| [i as f32, 0.0, 0.0]).collect();
        let mut img = Image::from_pixels(3, 2, pixels).expect("6 pixels");
        assert_eq!(img.get(2, 0)[0], 2.0);
        assert_eq!(img.get(0, 1)[0], 3.0);
        img.set(1, 1, [9.0, 8.0, 7.0]);
        assert_eq!(img.pixels()[4], [9.0, 8.0, 7.0]);
        assert_eq!(Image::new(4, 3).pixels().len(), 12);
    }

    #[test]
    #[should_panic(expected = "outside a 3x2 image")]
    fn get_outside_panics_with_the_size() {
        Image::new(3, 2).get(3, 0);
    }

    #[test]
    fn luminance_weights_sum_to_one() {
        assert!((luminance([1.0, 1.0, 1.0]) - 1.0).abs() < 1e-6);
        assert_eq!(luminance([0.0, 1.0, 0.0]), 0.7152);
    }

    #[test]
    fn unsupported_extensions_are_named_errors() {
        let dir = tempfile::tempdir().expect("temp dir");
        for name in ["picture.tiff", "noext"] {
            let path = dir.path().join(name);
            std::fs::write(&path, b"whatever").expect("write");
            let err = read_image(&path).expect_err("unsupported");
            let msg = err.to_string();
            assert!(
                msg.contains(name) && msg.contains(".exr, .png, .hdr"),
                "{msg}"
            );
        }
        let err = write_image(&dir.path().join("out.hdr"), &Image::new(2, 2), 0.0)
            .expect_err("no HDR writer");
        let msg = err.to_string();
        assert!(
            msg.contains("out.hdr") && msg.contains("`.hdr`") && msg.contains(".exr, .png"),
            "{msg}"
        );
    }

    #[test]
    fn extension_dispatch_is_case_insensitive() {
        let dir = tempfile::tempdir().expect("temp dir");
        let img =
            Image::from_pixels(2, 1, vec![[0.25, 0.5, 2.0], [0.0, 1.0, 0.125]]).expect("2 pixels");
        let exr = dir.path().join("A.EXR");
        write_image(&exr, &img, 3.0).expect("write EXR");
        // Exposure is not applied to EXR: it holds radiance.
        assert_eq!(read_image(&exr).expect("read EXR"), img);
        let png = dir.path().join("b.Png");
        write_image(&png, &img, 0.0).expect("write PNG");
        assert_eq!(read_image(&png).expect("read PNG").width(), 2);
    }

    #[test]
    fn missing_files_are_named_errors() {
        let dir = tempfile::tempdir().expect("temp dir");
        for name in ["gone.exr", "gone.png", "gone.hdr"] {
            let err = read_image(&dir.path().join(name)).expect_err("missing");
            assert!(matches!(err, ImageError::Read { .. }), "{err:?}");
            assert!(err.to_string().contains(name), "{err}");
        }
    }

    #[test]
    fn zero_sized_images_are_not_written() {
        let dir = tempfile::tempdir().expect("temp dir");
        for name in ["empty.exr", "empty.png"] {
            let path = dir.path().join(name);
            let err = write_image(&path, &Image::new(0, 5), 0.0).expect_err("empty");
            assert!(
                err.to_string().contains(name) && err.to_string().contains("0x5"),
                "{err}"
            );
            assert!(!path.exists());
        }
    }
}
