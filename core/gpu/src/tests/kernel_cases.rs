//! The WGSL test kernel's harness: evaluation cases (BRDFs, bases, texels, samplers,
//! tables) run on the device in one dispatch, the direction pairs they are run on,
//! and the tolerance arithmetic the comparisons with core's f64 share.

use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel, warp::spherical};
use meso_materials::rng::SampleStream;

use crate::kernel::{Kernel, Slot, encoder, storage, submit_and_read, zeroed};
use crate::shaders;

use super::context;

/// Words per case in the kernel's input: kind, record, wi, wo, texel, residual.
const CASE_WORDS: usize = 10;

/// f32's unit roundoff, 2^-24: the relative error of one rounded operation.
pub(super) const UNIT_ROUNDOFF: f64 = 5.960_464_477_539_063e-8;

/// One evaluation request of the test kernel.
#[derive(Clone, Copy)]
pub(super) struct Case {
    pub(super) kind: u32,
    pub(super) record: u32,
    pub(super) wi: DVec3,
    pub(super) wo: DVec3,
    pub(super) texel: u32,
    pub(super) residual: bool,
}

/// A direction's components as f32 bits, as the kernels read them.
pub(super) fn f32s(v: DVec3) -> [u32; 3] {
    [
        (v.x as f32).to_bits(),
        (v.y as f32).to_bits(),
        (v.z as f32).to_bits(),
    ]
}

/// The directions as the GPU sees them (rounded to f32), back in f64 for the reference.
fn rounded(v: DVec3) -> DVec3 {
    DVec3::new(v.x as f32 as f64, v.y as f32 as f64, v.z as f32 as f64)
}

/// The test kernels with every WGSL part they call.
pub(super) fn test_module() -> String {
    shaders::module(&[
        shaders::TEST_KERNELS,
        shaders::SAMPLER,
        shaders::TRAVERSAL,
        shaders::BRDF,
        shaders::SPMM,
        shaders::MERL,
        shaders::CDF,
        shaders::BTF_TABLE,
    ])
}

/// The test kernels' bindings: the results (slot 2) and the counters (slot 5) are
/// written, the rest only read.
pub(super) const TEST_SLOTS: [Slot; 7] = [
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::Read,
];

/// Runs `eval_cases` over `cases` with `data`; RGB per case.
pub(super) fn evaluate(data: &[u32], cases: &[Case]) -> Vec<[f32; 3]> {
    let ctx = context();
    let kernel = Kernel::new(ctx, &test_module(), "eval_cases", &TEST_SLOTS);
    let mut words = Vec::with_capacity(cases.len() * CASE_WORDS);
    for c in cases {
        words.extend([c.kind, c.record]);
        words.extend(f32s(c.wi));
        words.extend(f32s(c.wo));
        words.extend([c.texel, u32::from(c.residual)]);
    }
    let data_buf = storage(ctx, "data", bytemuck::cast_slice(data));
    let case_buf = storage(ctx, "cases", bytemuck::cast_slice(&words));
    let out_size = (cases.len() * 12) as u64;
    let out = zeroed(ctx, "results", out_size);
    let empty = zeroed(ctx, "empty", 16);
    let counters = zeroed(ctx, "counters", 16);
    let bind = kernel.bind(
        ctx,
        &[
            &data_buf, &case_buf, &out, &empty, &empty, &counters, &empty,
        ],
    );
    let mut enc = encoder(ctx);
    kernel.record(&mut enc, &bind, cases.len() as u32);
    let bytes = submit_and_read(ctx, enc, &[(&out, out_size)]).expect("the device works");
    bytemuck::cast_slice::<u8, [f32; 3]>(&bytes[0][..cases.len() * 12]).to_vec()
}

/// Direction pairs: random over the hemisphere, and grazing ones (cos down to 1e-7)
/// including mirror and retro-reflection configurations.
pub(super) fn direction_pairs(seed: u64, count: usize) -> Vec<(DVec3, DVec3)> {
    let mut pairs = Vec::with_capacity(count);
    for k in 0..count as u64 {
        let mut s = SampleStream::new(&[seed, k]);
        let phi_i = std::f64::consts::TAU * s.next();
        let phi_o = std::f64::consts::TAU * s.next();
        let (ci, co) = match k % 4 {
            // Random over the hemisphere.
            0 | 1 => (s.next().max(1e-3), s.next().max(1e-3)),
            // One grazing direction, cosines from 1e-7 to 1e-2.
            2 => (10f64.powf(-7.0 + 5.0 * s.next()), s.next().max(1e-3)),
            // Both grazing.
            _ => (
                10f64.powf(-7.0 + 5.0 * s.next()),
                10f64.powf(-7.0 + 5.0 * s.next()),
            ),
        };
        let wi = spherical(ci, phi_i);
        // Every 8th pair: the mirror direction (the peak of specular lobes).
        let wo = if k % 8 == 1 {
            DVec3::new(-wi.x, -wi.y, wi.z)
        } else {
            spherical(co, phi_o)
        };
        pairs.push((rounded(wi), rounded(wo)));
    }
    pairs
}

/// A model with parameters drawn across its whole spec range (log-uniform where the
/// editor's slider is).
pub(super) fn random_brdf(model: BrdfModel, s: &mut SampleStream) -> AnalyticBrdf {
    let params: Vec<(&str, f64)> = model
        .param_specs()
        .iter()
        .map(|p| {
            let u = s.next();
            let v = if p.log_scale && p.min > 0.0 {
                p.min * (p.max / p.min).powf(u)
            } else if p.log_scale {
                // Exponents from 0: log-uniform over [1, max], and 0 itself sometimes.
                if u < 0.05 { 0.0 } else { p.max.powf(u) }
            } else {
                p.min + (p.max - p.min) * u
            };
            (p.name, v.clamp(p.min, p.max))
        })
        .collect();
    AnalyticBrdf::new(model, &params).expect("parameters inside the spec ranges")
}

/// The error of a GPU value `g` against the f64 reference `c` in units of the
/// tolerance: within 1 passes. `rel` is the relative tolerance; `floor` an absolute
/// one for values near zero (where the f32 rounding of the inputs dominates).
pub(super) fn excess(g: f32, c: f64, rel: f64, floor: f64) -> f64 {
    let g = g as f64;
    (g - c).abs() / (rel * c.abs() + floor)
}
