//! A fast `atan2` for the hot paths that turn directions into table coordinates (the
//! MERL lookup's three Rusinkiewicz angles and its sampler's azimuths): a polynomial
//! within 2e-13 rad of the correctly rounded one (`tests`), where a MERL bin is about
//! 0.017 rad wide, at a fraction of libm's cost (docs/performance.md, "The MERL
//! lookup's angles").

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// tan(pi / 8): arguments above it are reduced by atan(t) = pi/4 + atan((t-1)/(t+1)).
const TAN_PI_8: f64 = 0.414_213_562_373_095_03;

/// atan(u) / u as a polynomial in u^2 for |u| <= tan(pi/8): a weighted least-squares
/// fit on Chebyshev nodes, made for this module (largest error of u P(u^2) against
/// atan: 1.4e-13).
const ATAN_POLY: [f64; 8] = [
    9.999_999_999_941_744e-1,
    -3.333_333_316_748_859e-1,
    1.999_998_620_833_774e-1,
    -1.428_519_751_883_061e-1,
    1.110_077_465_055_570_7e-1,
    -8.972_156_680_448_537e-2,
    6.895_172_027_662_846e-2,
    -3.642_985_109_659_655e-2,
];

/// atan(u) for |u| <= tan(pi/8).
#[inline]
fn atan_reduced(u: f64) -> f64 {
    let z = u * u;
    let mut p = ATAN_POLY[7];
    for c in ATAN_POLY[..7].iter().rev() {
        p = p * z + c;
    }
    u * p
}

/// atan2(y, x) in (-pi, pi], with std's signs at zeros and its NaN; within 2e-13 rad of
/// `f64::atan2` for finite arguments (infinite ones are handed to it).
#[inline]
pub fn atan2(y: f64, x: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ay > ax { (ax, ay) } else { (ay, ax) };
    if hi == 0.0 || !hi.is_finite() {
        // Both zero (the answer is a signed 0 or pi) or an infinity: rare, exact.
        return y.atan2(x);
    }
    let t = lo / hi;
    let mut a = if t > TAN_PI_8 {
        FRAC_PI_4 + atan_reduced((t - 1.0) / (t + 1.0))
    } else {
        atan_reduced(t)
    };
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x.is_sign_negative() {
        a = PI - a;
    }
    if y.is_sign_negative() { -a } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SampleStream;

    #[test]
    fn agrees_with_libm_everywhere() {
        let rng = SampleStream::new(&[0xA7A2]);
        let mut worst = 0.0f64;
        for k in 0..400_000u64 {
            // Angles all round the circle at magnitudes from 1e-300 to 1e300, and a
            // share near the axes and the diagonals where the branches meet.
            let phi = (rng.at(2 * k) - 0.5) * 2.0 * PI;
            let r = 10f64.powf((rng.at(2 * k + 1) - 0.5) * 600.0);
            let phi = match k % 4 {
                0 => phi,
                1 => (phi / FRAC_PI_4).round() * FRAC_PI_4 + (phi - phi.round()) * 1e-9,
                2 => (phi / FRAC_PI_2).round() * FRAC_PI_2 + (phi - phi.round()) * 1e-15,
                _ => (phi / (PI / 8.0)).round() * (PI / 8.0) + (phi - phi.round()) * 1e-12,
            };
            let (y, x) = (r * phi.sin(), r * phi.cos());
            let err = (atan2(y, x) - y.atan2(x)).abs();
            worst = worst.max(err);
        }
        assert!(worst < 2e-13, "largest error {worst:e} rad");
    }

    #[test]
    fn keeps_the_signs_and_special_values_of_std() {
        for (y, x) in [
            (0.0, 0.0),
            (0.0, -0.0),
            (-0.0, 0.0),
            (-0.0, -0.0),
            (0.0, 1.0),
            (0.0, -1.0),
            (-0.0, -1.0),
            (1.0, 0.0),
            (-1.0, 0.0),
            (1.0, f64::INFINITY),
            (f64::INFINITY, 1.0),
            (f64::INFINITY, f64::NEG_INFINITY),
            (1e-320, 1.0),
            (1.0, 1e-320),
        ] {
            let (ours, std) = (atan2(y, x), y.atan2(x));
            assert!(
                (ours - std).abs() < 1e-15 && ours.is_sign_negative() == std.is_sign_negative(),
                "atan2({y:e}, {x:e}): {ours} against {std}"
            );
        }
        assert!(atan2(f64::NAN, 1.0).is_nan() && atan2(1.0, f64::NAN).is_nan());
        // Exactly the quadrant's values on the axes and the diagonals.
        assert_eq!(atan2(1.0, 1.0), FRAC_PI_4);
        assert_eq!(atan2(2.0, 0.0), FRAC_PI_2);
        assert_eq!(atan2(0.0, -3.0), PI);
    }
}
