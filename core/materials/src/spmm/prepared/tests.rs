use super::cells::*;
use super::*;
use crate::rng::SampleStream;

/// Nine cells of a 40-cell table of `values`-value cells for `trial`: every fourth
/// weight zero (skipped), the last cell of the table among them.
fn test_cells(trial: usize, values: usize, wild: &mut impl FnMut() -> f64) -> [(usize, f64); 9] {
    std::array::from_fn(|i| {
        let start = if i == 8 { 39 } else { (trial * 7 + i * 5) % 40 };
        let w = if (trial + i).is_multiple_of(4) {
            0.0
        } else {
            wild().abs()
        };
        (start * values, w)
    })
}

#[test]
fn cells_are_padded_to_lines_only_when_that_costs_a_quarter_or_less() {
    use Precision::{Half, Single};
    // f32, 16 a line. (1 + k) x 3 values: 27 -> 32 (+19%), 12 and 18 and 51 stay
    // (+33%, +78%, +25.5%).
    assert_eq!(cell_stride(8, Single), 32);
    assert_eq!(cell_stride(3, Single), 12);
    assert_eq!(cell_stride(5, Single), 18);
    assert_eq!(cell_stride(16, Single), 51);
    assert_eq!(cell_stride(0, Single), 3);
    // 15 components: 48 values, already three lines.
    assert_eq!(cell_stride(15, Single), 48);
    // Halves, 32 a line: 27 -> 32 (one line), 30 -> 32; 18, 33 and 51 stay
    // (+78%, +94%, +25.5%).
    assert_eq!(cell_stride(8, Half), 32);
    assert_eq!(cell_stride(9, Half), 32);
    assert_eq!(cell_stride(5, Half), 18);
    assert_eq!(cell_stride(10, Half), 33);
    assert_eq!(cell_stride(16, Half), 51);
    assert_eq!(cell_stride(21, Half), 66);
    // Half tables end with a spare line (the 4-wide read of the last triple).
    assert_eq!(table_lines(20, 8, Single), 40);
    assert_eq!(table_lines(20, 8, Half), 21);
    assert_eq!(
        table_lines(20, 5, Half),
        (20 * 18 * 2usize).div_ceil(64) + 1
    );
}

/// The half-float cell sums give the bits of `add_cells_portable` on the same
/// values held as f32, portable and (where the CPU has AVX and F16C) 4-wide, with
/// the last cell of a table that ends with its spare line, and more components than
/// the 4-wide sum broadcasts ahead (20).
#[test]
fn the_half_cell_sums_equal_the_f32_one_bit_for_bit() {
    for k in [0usize, 1, 5, 8, 16, 20] {
        let values = (1 + k) * 3;
        let mut s = SampleStream::new(&[6, k as u64]);
        let mut wild = || {
            let u = s.next();
            (u - 0.4) * 10f64.powf(6.0 * s.next() - 3.0)
        };
        let halves: Vec<half::f16> = (0..40 * values)
            .map(|_| half::f16::from_f64(wild()))
            .collect();
        let single: Vec<f32> = halves.iter().map(|h| h.to_f32()).collect();
        let mut bits: Vec<u16> = halves.iter().map(|h| h.to_bits()).collect();
        bits.extend([0x7c00; 32]); // the spare line, here infinities: never read
        let coef: Vec<f32> = (0..k).map(|_| wild() as f32).collect();
        for trial in 0..200 {
            let cells = test_cells(trial, values, &mut wild);
            let rgb = DVec3::new(wild(), wild(), wild());
            let want = add_cells_portable(rgb, &single, &cells, &coef).to_array();
            let portable = add_cells_portable(rgb, &bits, &cells, &coef);
            assert_eq!(
                portable.to_array().map(f64::to_bits),
                want.map(f64::to_bits)
            );
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx")
                && std::arch::is_x86_feature_detected!("f16c")
            {
                // SAFETY: the CPU has AVX and F16C (checked above).
                let avx = unsafe { add_half_cells_avx(rgb, &bits, &cells, &coef) };
                assert_eq!(
                    avx.to_array().map(f64::to_bits),
                    want.map(f64::to_bits),
                    "k {k}, trial {trial}"
                );
            }
        }
    }
}

/// The 4-wide cell sum gives the portable sum's bits: the same products and sums
/// per channel in the same order, with skipped zero weights, values of mixed
/// signs and magnitudes, the last cell of the table (no float after it), and more
/// components than it broadcasts ahead (20).
#[test]
fn the_avx_cell_sum_equals_the_portable_one_bit_for_bit() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        for k in [0usize, 1, 5, 8, 16, 20] {
            let values = (1 + k) * 3;
            let mut s = SampleStream::new(&[5, k as u64]);
            let mut wild = || {
                let u = s.next();
                (u - 0.4) * 10f64.powf(8.0 * s.next() - 4.0)
            };
            let table: Vec<f32> = (0..40 * values).map(|_| wild() as f32).collect();
            let coef: Vec<f32> = (0..k).map(|_| wild() as f32).collect();
            for trial in 0..200 {
                let cells = test_cells(trial, values, &mut wild);
                let rgb = DVec3::new(wild(), wild(), wild());
                let portable = add_cells_portable(rgb, &table, &cells, &coef);
                // SAFETY: the CPU has AVX (checked above).
                let avx = unsafe { add_cells_avx(rgb, &table, &cells, &coef) };
                assert_eq!(
                    avx.to_array().map(f64::to_bits),
                    portable.to_array().map(f64::to_bits),
                    "k {k}, trial {trial}"
                );
            }
        }
    }
}
