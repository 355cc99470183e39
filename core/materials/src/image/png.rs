//! PNG files through the `image` crate: read 8- or 16-bit grey/RGB(A), taken as sRGB and
//! decoded to linear (IEC 61966-2-1) with alpha dropped (not composited); write 8-bit RGB
//! sRGB after exposure (`tonemap::to_srgb8`). gAMA, cHRM, sRGB and iCCP chunks are neither
//! read nor written: every PNG is assumed to be, and written as, plain sRGB.

use std::path::Path;

use image::{ExtendedColorType, ImageEncoder, ImageFormat, codecs::png::PngEncoder};

use super::tonemap::{srgb_decode, to_srgb8};
use super::{Image, ImageError, check_writable, checked_size, read_bytes};
use crate::atomic::write_atomic;

const FORMAT: &str = "PNG";

/// Reads a PNG as linear radiance: each 8- or 16-bit code `v` becomes
/// `srgb_decode(v / max)`, grey is replicated to RGB, alpha is ignored.
pub fn read_png(path: &Path) -> Result<Image, ImageError> {
    let bytes = read_bytes(path)?;
    let decoded = image::load_from_memory_with_format(&bytes, ImageFormat::Png).map_err(|e| {
        ImageError::Decode {
            path: path.to_path_buf(),
            format: FORMAT,
            reason: e.to_string(),
        }
    })?;
    let (width, height) = checked_size(path, decoded.width() as usize, decoded.height() as usize)?;
    // `to_rgb32f` maps an n-bit code to code / (2^n - 1) and drops alpha without compositing.
    let pixels = decoded
        .to_rgb32f()
        .pixels()
        .map(|p| p.0.map(srgb_decode))
        .collect();
    Ok(Image::from_pixels(width, height, pixels)
        .expect("the decoder returns width * height pixels"))
}

/// Encodes the image as an 8-bit RGB PNG in memory, exposed by `2^exposure_stops`
/// (`to_srgb8`). Used by `write_png` and by callers that need the bytes (clipboard, tests).
pub fn encode_png(image: &Image, exposure_stops: f64) -> Result<Vec<u8>, image::ImageError> {
    let codes: Vec<u8> = to_srgb8(image, exposure_stops)
        .into_iter()
        .flatten()
        .collect();
    let mut bytes = Vec::new();
    PngEncoder::new(&mut bytes).write_image(
        &codes,
        image.width(),
        image.height(),
        ExtendedColorType::Rgb8,
    )?;
    Ok(bytes)
}

/// Writes an 8-bit sRGB PNG of the radiance scaled by `2^exposure_stops` and clamped to
/// [0, 1]. Whole file or nothing.
pub fn write_png(path: &Path, image: &Image, exposure_stops: f64) -> Result<(), ImageError> {
    check_writable(path, image, FORMAT)?;
    let bytes = encode_png(image, exposure_stops).map_err(|e| ImageError::Encode {
        path: path.to_path_buf(),
        format: FORMAT,
        reason: e.to_string(),
    })?;
    write_atomic(path, |w| w.write_all(&bytes))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{read_image, srgb_encode};

    fn gradient(width: u32, height: u32) -> Image {
        let mut img = Image::new(width, height);
        for y in 0..height {
            for x in 0..width {
                let u = x as f32 / (width - 1).max(1) as f32;
                let v = y as f32 / (height - 1).max(1) as f32;
                img.set(x, y, [u, v, u * v]);
            }
        }
        img
    }

    #[test]
    fn round_trip_is_within_one_code() {
        let dir = tempfile::tempdir().expect("temp dir");
        for (w, h) in [(1, 1), (3, 7), (64, 48)] {
            let img = gradient(w, h);
            let path = dir.path().join(format!("{w}x{h}.png"));
            write_png(&path, &img, 0.0).expect("write");
            let back = read_png(&path).expect("read");
            assert_eq!((back.width(), back.height()), (w, h));
            for (a, b) in img.pixels().iter().zip(back.pixels()) {
                for c in 0..3 {
                    // Rounding to 8 bits moves the encoded value by at most half a code.
                    let err = (srgb_encode(a[c]) - srgb_encode(b[c])).abs();
                    assert!(err <= 0.5 / 255.0 + 1e-6, "{a:?} -> {b:?}");
                }
            }
        }
    }

    #[test]
    fn exposure_scales_before_clamping() {
        let dir = tempfile::tempdir().expect("temp dir");
        let img =
            Image::from_pixels(2, 1, vec![[0.125, 0.25, 1.0], [4.0, -1.0, 0.0]]).expect("2 pixels");
        let path = dir.path().join("exposed.png");
        write_png(&path, &img, 2.0).expect("write");
        let back = read_png(&path).expect("read");
        // 0.125 * 4 = 0.5 survives (to a code), 0.25 * 4 = 1 and 1 * 4 = 4 clip to 1.
        assert!(
            (back.get(0, 0)[0] - 0.5).abs() < 3e-3,
            "{:?}",
            back.get(0, 0)
        );
        assert_eq!(back.get(0, 0)[1], 1.0);
        assert_eq!(back.get(0, 0)[2], 1.0);
        assert_eq!(back.get(1, 0), [1.0, 0.0, 0.0]);
    }

    #[test]
    fn sixteen_bit_grey_and_alpha_are_read() {
        let dir = tempfile::tempdir().expect("temp dir");
        // 16-bit grey+alpha, native-endian samples as the encoder expects.
        let samples: [u16; 4] = [65535, 0, 32768, 65535];
        let raw: Vec<u8> = samples.iter().flat_map(|s| s.to_ne_bytes()).collect();
        let mut bytes = Vec::new();
        PngEncoder::new(&mut bytes)
            .write_image(&raw, 2, 1, ExtendedColorType::La16)
            .expect("encode test PNG");
        let path = dir.path().join("grey16.png");
        std::fs::write(&path, &bytes).expect("write");
        let img = read_image(&path).expect("read");
        // Fully transparent white stays white: alpha is dropped, not composited.
        assert_eq!(img.get(0, 0), [1.0; 3]);
        let mid = srgb_decode(32768.0 / 65535.0);
        assert!(
            img.get(1, 0).iter().all(|&c| (c - mid).abs() < 1e-7),
            "{:?}",
            img.get(1, 0)
        );
    }

    #[test]
    fn truncated_png_is_a_named_error() {
        let dir = tempfile::tempdir().expect("temp dir");
        let bytes = encode_png(&gradient(16, 16), 0.0).expect("encode");
        let cut = dir.path().join("cut.png");
        for len in [0, 8, 30, bytes.len() / 2, bytes.len() - 13] {
            std::fs::write(&cut, &bytes[..len]).expect("write truncated");
            let err = read_image(&cut).expect_err("truncated PNG must not decode");
            assert!(err.to_string().contains("cut.png"), "at {len}: {err}");
        }
    }

    #[test]
    fn failed_write_keeps_the_previous_file() {
        let dir = tempfile::tempdir().expect("temp dir");
        let err = write_png(&dir.path().join("missing/out.png"), &gradient(2, 2), 0.0)
            .expect_err("no folder");
        assert!(err.to_string().contains("missing/out.png"), "{err}");
        let path = dir.path().join("keep.png");
        write_png(&path, &gradient(4, 4), 0.0).expect("write");
        let before = std::fs::read(&path).expect("read");
        write_png(&path, &Image::new(4, 0), 0.0).expect_err("empty image");
        assert_eq!(std::fs::read(&path).expect("read"), before);
    }
}
