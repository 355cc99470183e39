//! Replayable randomness: every random number is a pure function of a key
//! (seed, frame, pixel, dimension ...) so any sample can be recomputed alone.
//!
//! The mixer is SplitMix64's finaliser (Steele et al. 2014) applied to a running hash
//! of the key words; it is a counter-based generator, not a sequential state, so the
//! result never depends on thread count or evaluation order.
//!
//! Renderers draw a sample's numbers through a `Sampler`: independent hashed numbers,
//! or Owen-scrambled Sobol points along the sample index (`sobol.rs`), which stratify
//! each pixel's integrals across frames.

mod sobol;

/// The scrambled Sobol point of a sample index under a 64-bit seed (the GPU's
/// sampler is tested against it bit for bit).
pub use sobol::point_2d as sobol_point;

use serde::{Deserialize, Serialize};

/// How a renderer draws the numbers of its samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Sampler {
    /// Owen-scrambled Sobol points: a (0, 2)-sequence along the sample index in each
    /// pair of dimensions, scrambled per pixel and pair.
    #[default]
    Sobol,
    /// Independent uniform numbers hashed from (seed, sample, pixel, dimension).
    Independent,
}

impl Sampler {
    pub const ALL: [Sampler; 2] = [Sampler::Sobol, Sampler::Independent];

    pub fn name(self) -> &'static str {
        match self {
            Sampler::Sobol => "sobol",
            Sampler::Independent => "independent",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// SplitMix64 finaliser: a bijective 64-bit mix with full avalanche.
#[inline]
pub const fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// What a dimension number adds to a stream's key: `mix64(dim + C)`, looked up for
/// the dimensions a path uses (a table made at compile time), computed beyond them.
#[inline]
fn dimension_key(dim: u64) -> u64 {
    const C: u64 = 0x632b_e59b_d9b4_e019;
    const KEYS: [u64; 256] = {
        let mut t = [0u64; 256];
        let mut d = 0;
        while d < 256 {
            t[d] = mix64((d as u64).wrapping_add(C));
            d += 1;
        }
        t
    };
    match KEYS.get(dim as usize) {
        Some(&key) => key,
        None => mix64(dim.wrapping_add(C)),
    }
}

/// Hashes a key of any length into 64 well-mixed bits.
#[inline]
pub fn hash_key(key: &[u64]) -> u64 {
    let mut h = 0x9e37_79b9_7f4a_7c15_u64;
    for &k in key {
        h = mix64(h ^ k.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    }
    h
}

/// Maps 64 random bits to a double in [0, 1) using the top 53 bits.
#[inline]
pub fn unit_f64(bits: u64) -> f64 {
    (bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A stream of uniform numbers in [0, 1) for one key, indexed by dimension.
///
/// `SampleStream::new(&[seed, frame, pixel])` then `next()` gives dimensions 0, 1, 2 ...;
/// `at(d)` gives dimension `d` directly, so a consumer can skip dimensions and stay
/// replayable.
#[derive(Clone, Copy, Debug)]
pub struct SampleStream {
    key_hash: u64,
    next_dim: u64,
    /// Sobol points instead of independent numbers: the sample's index in the
    /// sequence and the pixel's scramble key.
    sobol: Option<(u32, u64)>,
}

impl SampleStream {
    /// Independent numbers for `key`.
    pub fn new(key: &[u64]) -> Self {
        Self {
            key_hash: hash_key(key),
            next_dim: 0,
            sobol: None,
        }
    }

    /// The numbers of sample `index` of `pixel` under `seed`, drawn by `sampler`.
    /// Independent: exactly `new(&[seed, index, pixel])`. Sobol: the pixel's own
    /// scramble, point `index` of the sequence (indices wrap at 2^32); its
    /// independent numbers (`at`, `next_32_16_16`) are those of `new(&[seed, index,
    /// pixel])`, so they still change with every sample.
    pub fn for_sample(sampler: Sampler, seed: u64, index: u64, pixel: u64) -> Self {
        let independent = Self::new(&[seed, index, pixel]);
        match sampler {
            Sampler::Independent => independent,
            Sampler::Sobol => Self {
                sobol: Some((index as u32, hash_key(&[seed, 0x0073_6f62_6f6c, pixel]))),
                ..independent
            },
        }
    }

    /// The Sobol point of the pair of dimensions starting at `dim`.
    #[inline]
    fn sobol_at((index, scramble): (u32, u64), dim: u64) -> [f64; 2] {
        sobol::point_2d(index, mix64(scramble ^ dimension_key(dim)))
    }

    /// The independent uniform number of dimension `dim`, whatever the sampler,
    /// independent of the stream position.
    #[inline]
    pub fn at(&self, dim: u64) -> f64 {
        self.at_salted(dim, 0)
    }

    /// `at(dim)` with `salt` mixed in (zero: `at` itself); a set's further draws.
    #[inline]
    fn at_salted(&self, dim: u64, salt: u64) -> f64 {
        unit_f64(mix64(self.key_hash ^ dimension_key(dim) ^ salt))
    }

    /// Three uniform numbers in [0, 1) from one dimension: 32 bits, then 16 and 16,
    /// for hot loops that need many numbers (a many-light candidate: which light, with
    /// the alias table's keep test at 2^-32 / lights, and a point on it). Always
    /// independent numbers: a Sobol coordinate has 32 bits, not 64.
    #[inline]
    pub fn next_32_16_16(&mut self) -> [f64; 3] {
        let bits = mix64(self.key_hash ^ dimension_key(self.next_dim));
        self.next_dim += 1;
        [
            (bits >> 32) as f64 * (1.0 / (1u64 << 32) as f64),
            ((bits >> 16) & 0xffff) as f64 * (1.0 / 65536.0),
            (bits & 0xffff) as f64 * (1.0 / 65536.0),
        ]
    }

    /// The next dimension's uniform number.
    #[inline]
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> f64 {
        let u = match self.sobol {
            // One coordinate of its own padded pair: a scrambled van der Corput sequence.
            Some(sobol) => Self::sobol_at(sobol, self.next_dim)[0],
            None => self.at(self.next_dim),
        };
        self.next_dim += 1;
        u
    }

    /// One 2-D step drawn `n` times in a sample (several points on one light per
    /// frame): draw `r` of the set is Sobol point `n x index + r` of the step's pair,
    /// so the sub-samples of all frames together are one stratified sequence, not `n`
    /// sequences scrambled apart; independent: pair `r` of the step's own numbers.
    /// Draw 0 of a set of one is `next_2d`'s. Advances the stream by one pair.
    #[inline]
    pub fn next_2d_set(&mut self, n: u32) -> PairSet {
        let set = PairSet {
            stream: *self,
            n: n.max(1),
        };
        self.next_dim += 2;
        set
    }

    /// Two consecutive dimensions, for 2-D warps; one Sobol pair.
    #[inline]
    pub fn next_2d(&mut self) -> glam::DVec2 {
        match self.sobol {
            Some(sobol) => {
                let [x, y] = Self::sobol_at(sobol, self.next_dim);
                self.next_dim += 2;
                glam::DVec2::new(x, y)
            }
            None => glam::DVec2::new(self.next(), self.next()),
        }
    }
}

/// The `n` draws of one 2-D step (`SampleStream::next_2d_set`).
#[derive(Clone, Copy, Debug)]
pub struct PairSet {
    /// The stream positioned at the step's pair.
    stream: SampleStream,
    n: u32,
}

impl PairSet {
    /// How many draws the set has.
    pub fn count(&self) -> u32 {
        self.n
    }

    /// Draw `r` (below `count`).
    #[inline]
    pub fn get(&self, r: u32) -> glam::DVec2 {
        debug_assert!(r < self.n);
        let s = &self.stream;
        let dim = s.next_dim;
        match s.sobol {
            Some((index, scramble)) => {
                let [x, y] = SampleStream::sobol_at(
                    (index.wrapping_mul(self.n).wrapping_add(r), scramble),
                    dim,
                );
                glam::DVec2::new(x, y)
            }
            None => {
                // Draw 0 is `at(dim), at(dim + 1)`; the others mix their number in.
                let salt = u64::from(r).wrapping_mul(0xd1b5_4a32_d192_ed03);
                glam::DVec2::new(s.at_salted(dim, salt), s.at_salted(dim + 1, salt))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dimension_keys_table_is_the_mix_it_stands_for() {
        for dim in (0..300).chain([u64::MAX - 1, u64::MAX]) {
            assert_eq!(
                dimension_key(dim),
                mix64(dim.wrapping_add(0x632b_e59b_d9b4_e019)),
                "{dim}"
            );
        }
    }

    #[test]
    fn replayable_and_order_independent() {
        let mut a = SampleStream::new(&[7, 3, 1024]);
        let first: Vec<f64> = (0..8).map(|_| a.next()).collect();
        let b = SampleStream::new(&[7, 3, 1024]);
        for (d, u) in first.iter().enumerate() {
            assert_eq!(*u, b.at(d as u64));
        }
        // A different pixel gives a different sequence.
        let c = SampleStream::new(&[7, 3, 1025]);
        assert_ne!(first[0], c.at(0));
    }

    #[test]
    fn uniform_moments_and_range() {
        // Mean 1/2 and variance 1/12 of U[0,1); with n = 1e6 the standard error of the
        // mean is 2.9e-4, so 5 sigma is 1.5e-3.
        let n = 1_000_000u64;
        let (mut sum, mut sum2) = (0.0, 0.0);
        for i in 0..n {
            let u = SampleStream::new(&[1, i]).at(0);
            assert!((0.0..1.0).contains(&u));
            sum += u;
            sum2 += u * u;
        }
        let mean = sum / n as f64;
        let var = sum2 / n as f64 - mean * mean;
        assert!((mean - 0.5).abs() < 1.5e-3, "mean {mean}");
        assert!((var - 1.0 / 12.0).abs() < 1.0e-3, "var {var}");
    }

    #[test]
    fn neighbouring_keys_are_uncorrelated() {
        // Lag-1 correlation between consecutive pixels' first dimension.
        let n = 200_000u64;
        let xs: Vec<f64> = (0..n)
            .map(|i| SampleStream::new(&[0, 0, i]).at(0) - 0.5)
            .collect();
        let cov: f64 = xs.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (n - 1) as f64;
        let corr = cov / (1.0 / 12.0);
        assert!(corr.abs() < 0.01, "lag-1 correlation {corr}");
    }

    #[test]
    fn sobol_streams_change_with_the_sample_in_every_kind_of_draw() {
        // Every kind of draw (1-D, 2-D, the independent 32/16/16 split) must differ
        // between samples of one pixel, or an estimator repeats one number each frame.
        let stream = |i| SampleStream::for_sample(Sampler::Sobol, 3, i, 77);
        let (mut a, mut b) = (stream(0), stream(1));
        assert_ne!(a.next(), b.next());
        assert_ne!(a.next_2d(), b.next_2d());
        assert_ne!(a.next_32_16_16(), b.next_32_16_16());
        assert_ne!(stream(0).at(5), stream(1).at(5));
        // Independent streams are the hashed key exactly, as before samplers existed.
        let mut i = SampleStream::for_sample(Sampler::Independent, 3, 1, 77);
        let mut j = SampleStream::new(&[3, 1, 77]);
        assert_eq!(i.next_2d(), j.next_2d());
    }

    #[test]
    fn a_set_of_one_is_the_plain_pair_and_any_set_takes_one_step() {
        for sampler in Sampler::ALL {
            let mut plain = SampleStream::for_sample(sampler, 5, 9, 321);
            let mut set = plain;
            plain.next();
            set.next();
            assert_eq!(set.next_2d_set(1).get(0), plain.next_2d(), "{sampler:?}");
            // The next step is the same dimension whatever the set's size.
            let mut wide = SampleStream::for_sample(sampler, 5, 9, 321);
            wide.next();
            let draws = wide.next_2d_set(4);
            assert_eq!(draws.count(), 4);
            assert_eq!(wide.next_2d(), set.next_2d(), "{sampler:?}");
            // Its draws differ from each other.
            for r in 1..4 {
                assert_ne!(draws.get(r), draws.get(r - 1), "{sampler:?} draw {r}");
            }
        }
    }

    /// Sets of `n` over the frames 0 .. 2^m / n: the Sobol draws of one pixel and step
    /// are one (0, m, 2)-net, every elementary interval of area 2^-m holding exactly
    /// one point (what keeps the sub-samples stratified against each other).
    #[test]
    fn sobol_sets_over_frames_are_one_net() {
        for n in [2u32, 4] {
            for m in 2..=8u32 {
                let frames = (1u32 << m) / n;
                if frames == 0 {
                    continue;
                }
                let pts: Vec<glam::DVec2> = (0..frames)
                    .flat_map(|f| {
                        let mut s =
                            SampleStream::for_sample(Sampler::Sobol, 11, u64::from(f), 4242);
                        s.next_2d();
                        let set = s.next_2d_set(n);
                        (0..n).map(move |r| set.get(r))
                    })
                    .collect();
                for a in 0..=m {
                    let (cx, cy) = (1u32 << a, 1u32 << (m - a));
                    let mut hits = vec![0u32; 1 << m];
                    for p in &pts {
                        let (ix, iy) = ((p.x * f64::from(cx)) as u32, (p.y * f64::from(cy)) as u32);
                        hits[(iy * cx + ix) as usize] += 1;
                    }
                    assert!(hits.iter().all(|&h| h == 1), "n {n}, m {m}, a {a}");
                }
            }
        }
    }
}
