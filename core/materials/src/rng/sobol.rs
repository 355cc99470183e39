//! Owen-scrambled Sobol points for the progressive renderers: a (0, 2)-sequence in
//! each pair of dimensions, drawn along the sample index, so that every power-of-two
//! run of frames stratifies a pixel's 2-D integrals (pixel footprint, area-light
//! point, AO and environment directions, BRDF samples) instead of scattering them at
//! random.
//!
//! Each draw is "padded" (Burley 2020, Practical Hash-based Owen Scrambling): the
//! first two Sobol dimensions, with the sample index shuffled and both coordinates
//! nested-uniform scrambled by hashes of a seed that is different for every pixel and
//! every dimension pair. Every point is uniformly distributed on [0, 1)^2 (the
//! scramble is a random nested uniform permutation), so estimators stay unbiased;
//! pairs are independent of one another, so the dimension layout needs no care
//! beyond being replayable.

/// Direction numbers of Sobol dimension 1 (primitive polynomial x + 1): column k is
/// the previous one XOR itself shifted right by one, starting from the top bit.
const DIM1: [u32; 32] = {
    let mut v = [0u32; 32];
    v[0] = 1 << 31;
    let mut k = 1;
    while k < 32 {
        v[k] = v[k - 1] ^ (v[k - 1] >> 1);
        k += 1;
    }
    v
};

/// Sobol dimension 0 (the van der Corput sequence in base 2) of `index`, as 32 bits.
#[cfg(test)]
fn sobol0(index: u32) -> u32 {
    index.reverse_bits()
}

/// The XOR of `columns[8k + bit]` over the bits set in byte value `b` at byte `k`, as
/// entry [k][b]: a linear map over GF(2) of a 32-bit value by four lookups instead of
/// a loop with a branch per bit (shuffled indices use all 32 bits).
const fn byte_tables(columns: [u32; 32]) -> [[u32; 256]; 4] {
    let mut t = [[0u32; 256]; 4];
    let mut k = 0;
    while k < 4 {
        let mut b = 0;
        while b < 256 {
            let mut x = 0;
            let mut bit = 0;
            while bit < 8 {
                if b & (1 << bit) != 0 {
                    x ^= columns[8 * k + bit];
                }
                bit += 1;
            }
            t[k][b] = x;
            b += 1;
        }
        k += 1;
    }
    t
}

/// The linear map of `tables` (`byte_tables`) applied to `x`.
#[inline]
fn by_bytes(tables: &[[u32; 256]; 4], x: u32) -> u32 {
    let [b0, b1, b2, b3] = x.to_le_bytes();
    tables[0][b0 as usize]
        ^ tables[1][b1 as usize]
        ^ tables[2][b2 as usize]
        ^ tables[3][b3 as usize]
}

/// Sobol dimension 1 by bytes of the index.
#[cfg(test)]
const DIM1_BYTES: [[u32; 256]; 4] = byte_tables(DIM1);

/// `DIM1_BYTES` for an index given with its bits reversed, each entry reversed: the
/// column of bit p is `reverse(DIM1[31 - p])`. Bit reversal distributes over XOR, so
/// `sobol1_reversed` needs no reversal.
const DIM1_REVERSED_BYTES: [[u32; 256]; 4] = byte_tables({
    let mut v = [0u32; 32];
    let mut p = 0;
    while p < 32 {
        v[p] = DIM1[31 - p].reverse_bits();
        p += 1;
    }
    v
});

/// `sobol1(reversed.reverse_bits()).reverse_bits()`, by bytes of `reversed`.
#[inline]
fn sobol1_reversed(reversed: u32) -> u32 {
    by_bytes(&DIM1_REVERSED_BYTES, reversed)
}

/// Sobol dimension 1 of `index`, as 32 bits (the definition `point_2d` is tested
/// against).
#[cfg(test)]
fn sobol1(index: u32) -> u32 {
    by_bytes(&DIM1_BYTES, index)
}

/// A hash that only lets each bit depend on the bits below it (Laine and Karras 2011,
/// with Burley's constants): applied to bit-reversed values it is a nested uniform
/// (Owen) scramble, each bit flipped by a random function of the bits above it.
#[inline]
fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x
}

/// Nested uniform scramble of the 32-bit fraction `x` under `seed`.
#[cfg(test)]
fn owen_scramble(x: u32, seed: u32) -> u32 {
    laine_karras(x.reverse_bits(), seed).reverse_bits()
}

/// 32 bits to [0, 1).
#[inline]
fn unit(x: u32) -> f64 {
    f64::from(x) * (1.0 / 4_294_967_296.0)
}

/// The scrambled point of sample `index` in the pair of dimensions keyed by `seed`
/// (64 well-mixed bits: the pixel's key and the dimension).
#[inline]
pub fn point_2d(index: u32, seed: u64) -> [f64; 2] {
    let (s0, s1) = (seed as u32, (seed >> 32) as u32);
    // The shuffle reorders samples within every aligned power-of-two block, so each
    // pair sees a different order of the same nets (the padding's decorrelation).
    // `point_2d_by_definition` written with the reversals that cancel taken out:
    // `reversed` is the shuffled index's bits reversed, `sobol0` of the index.
    let reversed = laine_karras(index.reverse_bits(), s0 ^ 0x5bd1_e995);
    let x = laine_karras(reversed.reverse_bits(), s0).reverse_bits();
    let y = laine_karras(sobol1_reversed(reversed), s1).reverse_bits();
    [unit(x), unit(y)]
}

/// `point_2d` as defined: shuffle, the first two Sobol dimensions, a nested uniform
/// scramble of each.
#[cfg(test)]
fn point_2d_by_definition(index: u32, seed: u64) -> [f64; 2] {
    let (s0, s1) = (seed as u32, (seed >> 32) as u32);
    let i = owen_scramble(index, s0 ^ 0x5bd1_e995);
    let x = owen_scramble(sobol0(i), s0);
    let y = owen_scramble(sobol1(i), s1);
    [unit(x), unit(y)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reversals taken out of `point_2d` change no bit: every index of the first
    /// 2^16, and indices spread over all 32 bits, under many seeds.
    #[test]
    fn the_point_is_its_definition_bit_for_bit() {
        for k in 0..64u64 {
            let seed = crate::rng::mix64(k);
            let indices = (0..1u32 << 16).chain((0..4096u32).map(|i| i.wrapping_mul(0x9e37_79b9)));
            for index in indices {
                let (a, b) = (point_2d(index, seed), point_2d_by_definition(index, seed));
                assert_eq!(
                    a.map(f64::to_bits),
                    b.map(f64::to_bits),
                    "index {index}, seed {seed}"
                );
            }
        }
    }

    /// Sobol's first points in dimensions 0 and 1, as published tables list them.
    #[test]
    fn the_unscrambled_sequence_starts_as_published() {
        let first: Vec<(f64, f64)> = (0..8).map(|i| (unit(sobol0(i)), unit(sobol1(i)))).collect();
        assert_eq!(
            first,
            [
                (0.0, 0.0),
                (0.5, 0.5),
                (0.25, 0.75),
                (0.75, 0.25),
                (0.125, 0.625),
                (0.625, 0.125),
                (0.375, 0.375),
                (0.875, 0.875)
            ]
        );
    }

    /// The byte tables equal the definition: the XOR of the columns of the set bits.
    #[test]
    fn dimension_one_by_bytes_equals_the_bitwise_definition() {
        let bitwise = |i: u32| {
            (0..32)
                .filter(|k| i & (1 << k) != 0)
                .fold(0, |x, k| x ^ DIM1[k])
        };
        for i in (0..4096u32).chain([u32::MAX, 0x8000_0001, 0xdead_beef, 0x1234_5678]) {
            assert_eq!(sobol1(i), bitwise(i), "{i:#x}");
        }
    }

    /// A (0, m, 2)-net in base 2: every elementary interval of area 2^-m, of any
    /// shape 2^-a x 2^-(m-a), holds exactly one of the first 2^m points. Scrambling
    /// and shuffling must keep that for every seed and every aligned block.
    #[test]
    fn scrambled_blocks_are_0_m_2_nets() {
        for seed in [0u64, 1, 0xdead_beef_cafe_f00d, u64::MAX] {
            for m in 1..=8u32 {
                let n = 1u32 << m;
                for block in [0u32, 3] {
                    let pts: Vec<[f64; 2]> = (block * n..(block + 1) * n)
                        .map(|i| point_2d(i, seed))
                        .collect();
                    for a in 0..=m {
                        let (cx, cy) = (1u32 << a, 1u32 << (m - a));
                        let mut count = vec![0u32; n as usize];
                        for p in &pts {
                            let (ix, iy) =
                                ((p[0] * f64::from(cx)) as u32, (p[1] * f64::from(cy)) as u32);
                            count[(iy * cx + ix) as usize] += 1;
                        }
                        assert!(
                            count.iter().all(|&c| c == 1),
                            "seed {seed:#x}, m {m}, a {a}, block {block}"
                        );
                    }
                }
            }
        }
    }

    /// Over random seeds a fixed index is uniform on the square: the mean of a
    /// smooth function matches its integral (unbiasedness of every sample).
    #[test]
    fn each_point_is_uniform_over_seeds() {
        let n = 200_000u64;
        for index in [0u32, 1, 7, 1000] {
            let (mut sx, mut sxy, mut sx2) = (0.0, 0.0, 0.0);
            for k in 0..n {
                let p = point_2d(index, crate::rng::mix64(k));
                sx += p[0];
                sxy += p[0] * p[1];
                sx2 += p[0] * p[0];
            }
            let nf = n as f64;
            // E[x] = 1/2, E[xy] = 1/4, E[x^2] = 1/3; standard errors below 7e-4.
            assert!((sx / nf - 0.5).abs() < 3e-3, "index {index}: {}", sx / nf);
            assert!(
                (sxy / nf - 0.25).abs() < 3e-3,
                "index {index}: {}",
                sxy / nf
            );
            assert!(
                (sx2 / nf - 1.0 / 3.0).abs() < 3e-3,
                "index {index}: {}",
                sx2 / nf
            );
        }
    }
}
