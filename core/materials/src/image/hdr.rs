//! Radiance `.hdr` (RGBE, Ward 1991 "Real pixels", Graphics Gems II) through the `image`
//! crate: read only, as linear radiance. The EXPOSURE and COLORCORR header lines are not
//! applied, and the orientation is whatever the `image` crate supports (-Y +X).

use std::path::Path;

use image::ImageFormat;

use super::{Image, ImageError, checked_size, read_bytes};

/// Reads a Radiance HDR file as linear radiance.
pub fn read_hdr(path: &Path) -> Result<Image, ImageError> {
    let bytes = read_bytes(path)?;
    let decoded = image::load_from_memory_with_format(&bytes, ImageFormat::Hdr).map_err(|e| {
        ImageError::Decode {
            path: path.to_path_buf(),
            format: "Radiance HDR",
            reason: e.to_string(),
        }
    })?;
    let (width, height) = checked_size(path, decoded.width() as usize, decoded.height() as usize)?;
    let pixels = decoded.to_rgb32f().pixels().map(|p| p.0).collect();
    Ok(Image::from_pixels(width, height, pixels)
        .expect("the decoder returns width * height pixels"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::ImageEncoder;
    use image::codecs::hdr::HdrEncoder;

    #[test]
    fn reads_what_the_image_crate_writes() {
        let dir = tempfile::tempdir().expect("temp dir");
        // Powers of two and simple fractions are exact in RGBE's shared-exponent form.
        let pixels: Vec<f32> = vec![1.0, 0.5, 0.25, 8.0, 4.0, 2.0, 0.0, 0.0, 0.0];
        let raw: Vec<u8> = pixels.iter().flat_map(|v| v.to_ne_bytes()).collect();
        let mut bytes = Vec::new();
        HdrEncoder::new(&mut bytes)
            .write_image(&raw, 3, 1, image::ExtendedColorType::Rgb32F)
            .expect("encode");
        let path = dir.path().join("sky.hdr");
        std::fs::write(&path, &bytes).expect("write");
        let img = crate::image::read_image(&path).expect("read");
        assert_eq!(img.pixels(), &[[1.0, 0.5, 0.25], [8.0, 4.0, 2.0], [0.0; 3]]);

        std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("truncate");
        let err = read_hdr(&path).expect_err("truncated");
        assert!(err.to_string().contains("sky.hdr"), "{err}");
    }
}
