//! The I8 residual encoding (docs/formats/spmm.md): components as signed 8-bit codes,
//! each run of `V x 3` values scaled by a power of two of its own. Its own module: the
//! quantisation rule both directions of the file must agree on, bit for bit.

use super::PackErrorKind;

/// Exponent range of an I8 residual run: a run holds `q * 2^e` with `|q| <= 127`. The
/// lowest step, 2^-24, is a half float's finest, so decoded values of runs under 1 in
/// magnitude are half floats (a render keeps its tables as halves, `spmm::prepared`).
pub const I8_EXPONENT_MIN: i32 = -24;
/// The highest: runs up to 127 x 2^100 in magnitude.
pub const I8_EXPONENT_MAX: i32 = 100;

/// The exponent of an I8 run whose largest magnitude is `max_abs`: the smallest `e` in
/// range with `max_abs <= 127 * 2^e`. A decoded run gets its own exponent back (its
/// largest `|q|` is then 64..=127, or the exponent is a bound of the range), so
/// encoding what was decoded gives the same bytes.
fn i8_exponent(max_abs: f64) -> i32 {
    let fits = |e: i32| max_abs <= 127.0 * 2f64.powi(e);
    let mut e = if max_abs > 0.0 {
        (max_abs.log2().ceil() as i32 - 7).clamp(I8_EXPONENT_MIN, I8_EXPONENT_MAX)
    } else {
        I8_EXPONENT_MIN
    };
    while e < I8_EXPONENT_MAX && !fits(e) {
        e += 1;
    }
    while e > I8_EXPONENT_MIN && fits(e - 1) {
        e -= 1;
    }
    e
}

/// `values` in runs of `run` values as I8 codes and one exponent per run (round to
/// nearest; a run beyond 127 x 2^100 saturates, far outside any fitted residual).
pub(super) fn quantize_i8(values: &[f32], run: usize) -> (Vec<u8>, Vec<u8>) {
    let mut codes = Vec::with_capacity(values.len());
    let mut exponents = Vec::with_capacity(values.len() / run.max(1));
    for chunk in values.chunks(run.max(1)) {
        let max_abs = chunk.iter().fold(0.0f64, |m, &x| m.max(f64::from(x).abs()));
        let e = i8_exponent(max_abs);
        let scale = 2f64.powi(-e);
        exponents.push(e as i8 as u8);
        codes.extend(
            chunk
                .iter()
                .map(|&x| (f64::from(x) * scale).round().clamp(-127.0, 127.0) as i8 as u8),
        );
    }
    (codes, exponents)
}

/// Decodes I8 runs: `q * 2^e`, exact in f32 over the exponent range. An exponent
/// outside the range, or a code of -128, is refused naming the run.
pub(super) fn dequantize_i8(
    codes: &[u8],
    exponents: &[u8],
    run: usize,
) -> Result<Vec<f32>, PackErrorKind> {
    let mut out = Vec::with_capacity(codes.len());
    for (i, (chunk, &e)) in codes.chunks(run.max(1)).zip(exponents).enumerate() {
        let e = i32::from(e as i8);
        if !(I8_EXPONENT_MIN..=I8_EXPONENT_MAX).contains(&e) {
            return Err(PackErrorKind::Quantized(format!(
                "tensor `residual_component_exponents`[{i}] = {e} is outside \
                 {I8_EXPONENT_MIN}..={I8_EXPONENT_MAX}"
            )));
        }
        if let Some(q) = chunk.iter().find(|&&q| q as i8 == i8::MIN) {
            return Err(PackErrorKind::Quantized(format!(
                "tensor `residual_components`: code {} in run {i} is outside -127..=127",
                *q as i8
            )));
        }
        let scale = 2f64.powi(e);
        out.extend(chunk.iter().map(|&q| (f64::from(q as i8) * scale) as f32));
    }
    Ok(out)
}
