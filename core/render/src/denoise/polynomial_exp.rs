//! The exponential the vectorised filter uses: a polynomial with no branch, so a loop
//! of it vectorises where the library's `exp` would be a call per lane.

/// `exp(-x)` for `x >= 0` within 1e-5 relative (the polynomial 2e-7 in f32, the rest
/// the f32 product `x log2 e` at large x); NaN and infinity give 0. 2^(-x log2 e) split
/// into a power of two, set in the exponent bits, and a degree-5 polynomial of the
/// fraction; no branch, so a loop of it vectorises. Below 2^-127 the result is 0
/// (such weights are below any f32 image's rounding).
#[inline(always)]
pub(super) fn exp_neg(x: f32) -> f32 {
    // `max` returns -127 for NaN too (`clamp` would keep the NaN); `min` keeps a
    // negative x's t at 0.
    #[allow(clippy::manual_clamp)]
    let t = (-x * std::f32::consts::LOG2_E).max(-127.0).min(0.0);
    // floor(t) by truncation (t <= 0): `f32::floor` is a library call on the x86-64
    // baseline and would not vectorise, nor would `as` (its saturation and NaN rule
    // make the compiler convert one lane at a time).
    // SAFETY: t is finite and within [-127, 0], so it fits an i32.
    let i = unsafe { t.to_int_unchecked::<i32>() };
    let i = i - i32::from(i as f32 > t);
    let f = t - i as f32;
    // 2^f on [0, 1): coefficients fitted for the least largest relative error with
    // the constant 1, so exp(-0) is 1 (8.2e-8 in exact arithmetic), evaluated in
    // Estrin's form, whose dependency chain is half Horner's.
    const C: [f32; 6] = [
        1.0,
        0.693_151_3,
        0.240_164_46,
        0.055_799_91,
        0.009_017_038,
        0.001_867_126_3,
    ];
    let f2 = f * f;
    let p = (C[0] + C[1] * f) + f2 * ((C[2] + C[3] * f) + f2 * (C[4] + C[5] * f));
    // i = -127 gives the bits of 0.0.
    f32::from_bits(((i + 127) as u32) << 23) * p
}
