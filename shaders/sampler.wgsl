// A sample's random numbers (core/materials/src/rng/: `SampleStream`, `sobol.rs`):
// Owen-scrambled Sobol points along the sample index, one padded pair of dimensions
// per 2-D draw, or independent hashed numbers (`[render] sampler`). The dimension
// layout is the CPU integrator's: each draw advances the stream as its draw there
// does, so the same pixel integrals are stratified. The scramble seeds are 32-bit
// hashes of the CPU's keys, not the CPU's 64-bit ones: the same distribution of
// points, not the same numbers; `sobol_point` itself is the CPU's `point_2d` bit for
// bit for given seeds (tested).

const SAMPLER_SOBOL: u32 = 0u;
const SAMPLER_INDEPENDENT: u32 = 1u;

struct Rng {
    // The sample's index along the pixel's sequence (wraps at 2^32, as the CPU's).
    index: u32,
    // The pixel's scramble key (Sobol) and the sample's key (independent numbers).
    scramble: u32,
    key: u32,
    // The next dimension.
    dim: u32,
    sobol: u32,
}

// One 2-D step drawn several times in a sample (`PairSet`): its first dimension and
// the number of draws.
struct PairSet {
    dim: u32,
    n: u32,
}

fn pcg(v: u32) -> u32 {
    let s = v * 747796405u + 2891336453u;
    let w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

// The numbers of sample `index` (64 bits as lo, hi) of `pixel` under `seed`.
fn rng_for_sample(sampler: u32, seed: u32, index_lo: u32, index_hi: u32, pixel: u32) -> Rng {
    let scramble = pcg(pixel ^ pcg(seed ^ 0x736f626fu));
    let key = pcg(pixel + pcg(index_lo + pcg(seed ^ pcg(index_hi))));
    return Rng(index_lo, scramble, key, 0u, u32(sampler == SAMPLER_SOBOL));
}

// `laine_karras`: each bit depends only on the bits below it; on bit-reversed values
// a nested uniform (Owen) scramble.
fn laine_karras(v: u32, seed: u32) -> u32 {
    var x = v + seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

// Sobol dimension 1 of an index given bit-reversed, reversed (`sobol1_reversed`): the
// XOR over set bits p of reverse(DIM1[31 - p]), DIM1[k] = DIM1[k-1] ^ (DIM1[k-1] >> 1)
// from the top bit. That matrix is Pascal's triangle mod 2, which splits into halves
// as [[S, 0], [S, S]]: on the index in its own order, each block's low half takes the
// XOR of its high half, halving the blocks five times. No loop, no branch.
fn sobol1_reversed(reversed: u32) -> u32 {
    var x = reverseBits(reversed);
    x ^= (x >> 16u) & 0x0000ffffu;
    x ^= (x >> 8u) & 0x00ff00ffu;
    x ^= (x >> 4u) & 0x0f0f0f0fu;
    x ^= (x >> 2u) & 0x33333333u;
    x ^= (x >> 1u) & 0x55555555u;
    return x;
}

// `point_2d` as 32-bit fractions: the index shuffled, the first two Sobol dimensions,
// each nested-uniform scrambled (Burley 2020).
fn sobol_point_bits(index: u32, s0: u32, s1: u32) -> vec2<u32> {
    let reversed = laine_karras(reverseBits(index), s0 ^ 0x5bd1e995u);
    let x = reverseBits(laine_karras(reverseBits(reversed), s0));
    let y = reverseBits(laine_karras(sobol1_reversed(reversed), s1));
    return vec2<u32>(x, y);
}

// 32 bits to [0, 1): the top 24, exact in f32 and below one.
fn unit_f32(bits: u32) -> f32 {
    return f32(bits >> 8u) * (1.0 / 16777216.0);
}

// The independent number of dimension `dim` of the sample, with `salt` mixed in.
fn independent_at(rng: ptr<function, Rng>, dim: u32, salt: u32) -> u32 {
    return pcg((*rng).key ^ pcg(dim * 0x9e3779b9u + 0x632be59bu + salt));
}

// The pair of dimensions starting at `dim`, Sobol point `index`.
fn pair_at(rng: ptr<function, Rng>, dim: u32, index: u32, salt: u32) -> vec2<f32> {
    if (*rng).sobol != 0u {
        let s0 = pcg((*rng).scramble ^ pcg(dim * 0x9e3779b9u + 0x632be59bu));
        let s1 = pcg(s0 ^ 0x68e31da4u);
        let p = sobol_point_bits(index, s0, s1);
        return vec2<f32>(unit_f32(p.x), unit_f32(p.y));
    }
    return vec2<f32>(unit_f32(independent_at(rng, dim, salt)), unit_f32(independent_at(rng, dim + 1u, salt)));
}

// The next 2-D draw (`next_2d`).
fn rand2(rng: ptr<function, Rng>) -> vec2<f32> {
    let u = pair_at(rng, (*rng).dim, (*rng).index, 0u);
    (*rng).dim += 2u;
    return u;
}

// The next dimension's number (`next`): one coordinate of its own Sobol pair.
fn rand(rng: ptr<function, Rng>) -> f32 {
    let u = pair_at(rng, (*rng).dim, (*rng).index, 0u).x;
    (*rng).dim += 1u;
    return u;
}

// The next dimension's independent 32 bits, whatever the sampler (`next_32_16_16`):
// hot loops that need many numbers of one candidate.
fn rand_bits(rng: ptr<function, Rng>) -> u32 {
    let bits = independent_at(rng, (*rng).dim, 0u);
    (*rng).dim += 1u;
    return bits;
}

// One 2-D step drawn `n` times (`next_2d_set`); advances the stream by one pair.
fn rand2_set(rng: ptr<function, Rng>, n: u32) -> PairSet {
    let pairs = PairSet((*rng).dim, max(n, 1u));
    (*rng).dim += 2u;
    return pairs;
}

// Draw `r` of a set: Sobol point n x index + r of the step's pair, so the draws of
// all samples together are one stratified sequence.
fn set_draw(rng: ptr<function, Rng>, pairs: PairSet, r: u32) -> vec2<f32> {
    return pair_at(rng, pairs.dim, (*rng).index * pairs.n + r, r * 0xd1b54a33u);
}
