//! Display encoding: exposure (a scale of 2^stops) and the sRGB transfer curve of
//! IEC 61966-2-1:1999, section 4.7 (encode) and 5.2 (decode), then 8-bit quantisation.
//! No tone curve beyond clamping to [0, 1]: what exceeds the display range clips, so a
//! PNG shows radiance faithfully up to its exposure. No colour-space conversion.

use super::Image;

/// Linear values at or below this are encoded by the straight segment (IEC 61966-2-1).
const ENCODE_KNEE: f64 = 0.003_130_8;
/// Encoded values at or below this are decoded by the straight segment.
const DECODE_KNEE: f64 = 0.040_45;

/// The scale `2^exposure_stops` that exposure applies to radiance.
pub fn exposure_scale(exposure_stops: f64) -> f64 {
    exposure_stops.exp2()
}

/// sRGB encoding of a linear value: `12.92 L` up to 0.0031308, `1.055 L^(1/2.4) - 0.055`
/// above. Not clamped: negative inputs follow the straight segment, inputs above 1
/// the power segment. Computed in f64 so that encode/decode round-trip to f32 precision.
pub fn srgb_encode(linear: f32) -> f32 {
    let l = f64::from(linear);
    let e = if l <= ENCODE_KNEE {
        12.92 * l
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    };
    e as f32
}

/// Inverse of `srgb_encode`: `V / 12.92` up to 0.04045, `((V + 0.055) / 1.055)^2.4` above.
pub fn srgb_decode(encoded: f32) -> f32 {
    let v = f64::from(encoded);
    let l = if v <= DECODE_KNEE {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    };
    l as f32
}

/// Quantises a display value in [0, 1] to 8 bits, rounding to nearest.
fn quantise8(encoded: f32) -> u8 {
    // `encoded` is already clamped to [0, 1], so the product lies in [0, 255].
    (encoded * 255.0).round() as u8
}

/// One linear value to its 8-bit sRGB code after scaling: clamp to [0, 1], encode,
/// quantise. NaN maps to 0 (black); +inf to 255.
fn linear_to_srgb8(linear: f32, scale: f64) -> u8 {
    let scaled = f64::from(linear) * scale;
    // `f64::clamp` keeps NaN; a NaN pixel is shown black rather than as an arbitrary code.
    let clamped = if scaled.is_nan() {
        0.0
    } else {
        scaled.clamp(0.0, 1.0)
    };
    quantise8(srgb_encode(clamped as f32))
}

/// The image as 8-bit sRGB, row-major from the top row: radiance scaled by
/// `2^exposure_stops`, clamped to [0, 1], sRGB-encoded, rounded to the nearest code.
/// This is what PNG files hold and what the app displays.
pub fn to_srgb8(image: &Image, exposure_stops: f64) -> Vec<[u8; 3]> {
    let scale = exposure_scale(exposure_stops);
    image
        .pixels()
        .iter()
        .map(|p| p.map(|c| linear_to_srgb8(c, scale)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_and_decode_are_inverse() {
        for i in 0..=4096 {
            let l = i as f32 / 4096.0;
            let back = srgb_decode(srgb_encode(l));
            assert!((back - l).abs() <= 1e-6 * l.max(1e-3), "{l} -> {back}");
            let v = i as f32 / 4096.0;
            let again = srgb_encode(srgb_decode(v));
            assert!((again - v).abs() <= 1e-6, "{v} -> {again}");
        }
    }

    #[test]
    fn curve_is_continuous_at_the_knee_and_hits_the_ends() {
        let knee = ENCODE_KNEE as f32;
        let below = srgb_encode(knee);
        let above = srgb_encode(f32::from_bits(knee.to_bits() + 1));
        // The standard's two segments meet within 1e-7 (the constants are rounded).
        assert!((above - below).abs() < 1e-6, "{below} vs {above}");
        assert!((below - 0.04045).abs() < 1e-6, "{below}");
        let dk = DECODE_KNEE as f32;
        let (lo, hi) = (
            srgb_decode(dk),
            srgb_decode(f32::from_bits(dk.to_bits() + 1)),
        );
        assert!((hi - lo).abs() < 1e-7, "{lo} vs {hi}");
        assert_eq!(srgb_encode(0.0), 0.0);
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-7);
        assert!((srgb_decode(1.0) - 1.0).abs() < 1e-7);
        // Middle grey: the textbook value 0.2140 encodes to about 0.5.
        assert!((srgb_encode(0.214_041_14) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn srgb8_applies_exposure_clamps_and_blackens_nan() {
        let img = Image::from_pixels(
            5,
            1,
            vec![
                [0.5, 0.25, 2.0],
                [-1.0, f32::NAN, f32::INFINITY],
                [0.0; 3],
                [1.0; 3],
                [0.05; 3],
            ],
        )
        .expect("5 pixels");
        let codes = to_srgb8(&img, 1.0);
        // 0.5 * 2 = 1 -> 255; 0.25 * 2 = 0.5 -> 188 (0.7354 * 255); 4 clamps to 255.
        assert_eq!(codes[0], [255, 188, 255]);
        assert_eq!(codes[1], [0, 0, 255]);
        assert_eq!(codes[2], [0, 0, 0]);
        let plain = to_srgb8(&img, 0.0);
        assert_eq!(plain[3], [255; 3]);
        // 1.055 * 0.05^(1/2.4) - 0.055 = 0.2478 -> 63.19.
        assert_eq!(plain[4], [63; 3]);
    }
}
