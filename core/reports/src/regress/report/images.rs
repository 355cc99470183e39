//! The report's pictures: sRGB PNG thumbnails of the golden and the new render (no
//! exposure change, as `meso render` writes PNGs), and a heat map of the per-pixel
//! error through the viridis colour map (perceptually uniform, readable in grey and by
//! the colour blind), black at 0 and yellow at its scale, the largest error.

use meso_materials::image::{Image, encode_png};

/// Viridis at 0, 0.1, ..., 1 (van der Walt and Smith's matplotlib map, the eleven
/// sRGB stops it is commonly quoted by); linear interpolation between them.
pub const VIRIDIS: [[u8; 3]; 11] = [
    [0x44, 0x01, 0x54],
    [0x48, 0x24, 0x75],
    [0x41, 0x44, 0x87],
    [0x35, 0x5f, 0x8d],
    [0x2a, 0x78, 0x8e],
    [0x21, 0x91, 0x8c],
    [0x22, 0xa8, 0x84],
    [0x44, 0xbf, 0x70],
    [0x7a, 0xd1, 0x51],
    [0xbd, 0xdf, 0x26],
    [0xfd, 0xe7, 0x25],
];

/// The colour of `t` in [0, 1] (clamped; NaN as 0).
pub fn viridis(t: f64) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (VIRIDIS.len() - 1) as f64;
    let i = (x.floor() as usize).min(VIRIDIS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    std::array::from_fn(|c| (a[c] as f64 + (b[c] as f64 - a[c] as f64) * f).round() as u8)
}

/// Per-pixel error: the root mean square over the three channels of `new - golden`
/// (the RMSE's own pixel term, so the map shows where the RMSE comes from).
pub fn pixel_errors(golden: &Image, new: &Image) -> Vec<f64> {
    golden
        .pixels()
        .iter()
        .zip(new.pixels())
        .map(|(g, n)| {
            let sq: f64 = (0..3).map(|c| (n[c] as f64 - g[c] as f64).powi(2)).sum();
            (sq / 3.0).sqrt()
        })
        .collect()
}

/// The heat map of `golden` vs `new` (same size) as a PNG, and its scale: the error
/// drawn in the top colour (the largest per-pixel error; 0 when identical, then the
/// map is uniformly the bottom colour).
pub fn heat_map_png(golden: &Image, new: &Image) -> (Vec<u8>, f64) {
    let errors = pixel_errors(golden, new);
    let scale = errors
        .iter()
        .copied()
        .filter(|e| e.is_finite())
        .fold(0.0, f64::max);
    let mut rgb = Vec::with_capacity(errors.len() * 3);
    for e in &errors {
        let t = if scale > 0.0 {
            e / scale
        } else if e.is_finite() {
            0.0
        } else {
            1.0
        };
        rgb.extend_from_slice(&viridis(t));
    }
    let img = image::RgbImage::from_raw(golden.width(), golden.height(), rgb)
        .expect("three bytes per pixel of the golden's size");
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .expect("encoding a PNG into memory cannot fail");
    (png, scale)
}

/// The image as an sRGB PNG (exposure 0).
pub fn thumbnail_png(image: &Image) -> Vec<u8> {
    encode_png(image, 0.0).expect("encoding a PNG into memory cannot fail")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_ends_at_its_stops_and_brightens_monotonically() {
        assert_eq!(viridis(0.0), VIRIDIS[0]);
        assert_eq!(viridis(1.0), VIRIDIS[10]);
        assert_eq!(viridis(0.5), VIRIDIS[5]);
        assert_eq!(viridis(-3.0), VIRIDIS[0]);
        assert_eq!(viridis(f64::NAN), VIRIDIS[0]);
        // Perceptually ordered: luma grows along the map.
        let luma = |c: [u8; 3]| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
        let mut last = -1.0;
        for i in 0..=100 {
            let l = luma(viridis(i as f64 / 100.0));
            assert!(l > last, "at {i}: {l} <= {last}");
            last = l;
        }
    }

    #[test]
    fn the_heat_map_marks_the_changed_pixel_at_the_top_of_its_scale() {
        let golden = Image::new(16, 16);
        let mut new = golden.clone();
        new.set(3, 5, [0.3, 0.0, 0.0]);
        new.set(10, 2, [0.1, 0.0, 0.0]);
        let (png, scale) = heat_map_png(&golden, &new);
        assert!((scale - 0.3 / 3f64.sqrt()).abs() < 1e-7, "{scale}");
        let decoded = image::load_from_memory(&png).expect("a PNG").to_rgb8();
        assert_eq!(decoded.get_pixel(3, 5).0, VIRIDIS[10]);
        assert_eq!(decoded.get_pixel(0, 0).0, VIRIDIS[0]);
        assert_eq!(decoded.get_pixel(10, 2).0, viridis(1.0 / 3.0));
        let (png, scale) = heat_map_png(&golden, &golden);
        assert_eq!(scale, 0.0);
        let decoded = image::load_from_memory(&png).expect("a PNG").to_rgb8();
        assert!(decoded.pixels().all(|p| p.0 == VIRIDIS[0]));
    }
}
