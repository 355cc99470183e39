//! The GPU path against the CPU reference: BRDFs, basis functions and SPMM texels in
//! WGSL against core's f64 evaluation, closest hits against the CPU's traversal, and
//! the mode's images against the CPU mode's. They need a wgpu adapter (CI: Mesa's
//! lavapipe with WGPU_BACKEND=vulkan) and fail without one, naming the cause.

use std::sync::OnceLock;

use glam::DVec3;

use super::GpuContext;
use super::data::Words;
use super::kernel::{Kernel, Slot, encoder, storage, submit_and_read, zeroed};
use super::shaders;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel, warp::spherical};
use meso_materials::rng::SampleStream;
use meso_render::RenderModeExt;

pub(super) fn context() -> &'static GpuContext {
    static CONTEXT: OnceLock<GpuContext> = OnceLock::new();
    CONTEXT.get_or_init(|| {
        GpuContext::new().unwrap_or_else(|e| {
            panic!("the GPU tests need a wgpu adapter (CI: lavapipe, WGPU_BACKEND=vulkan): {e}")
        })
    })
}

const CASE_WORDS: usize = 10;

/// f32's unit roundoff, 2^-24: the relative error of one rounded operation.
const UNIT_ROUNDOFF: f64 = 5.960_464_477_539_063e-8;

/// One evaluation request of the test kernel.
#[derive(Clone, Copy)]
struct Case {
    kind: u32,
    record: u32,
    wi: DVec3,
    wo: DVec3,
    texel: u32,
    residual: bool,
}

fn f32s(v: DVec3) -> [u32; 3] {
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

fn test_module() -> String {
    shaders::module(&[
        shaders::TEST_KERNELS,
        shaders::TRAVERSAL,
        shaders::BRDF,
        shaders::SPMM,
        shaders::MERL,
        shaders::CDF,
        shaders::BTF_TABLE,
    ])
}

const TEST_SLOTS: [Slot; 7] = [
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::Read,
];

/// Runs `eval_cases` over `cases` with `data`; RGB per case.
fn evaluate(data: &[u32], cases: &[Case]) -> Vec<[f32; 3]> {
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
fn direction_pairs(seed: u64, count: usize) -> Vec<(DVec3, DVec3)> {
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
fn random_brdf(model: BrdfModel, s: &mut SampleStream) -> AnalyticBrdf {
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
fn excess(g: f32, c: f64, rel: f64, floor: f64) -> f64 {
    let g = g as f64;
    (g - c).abs() / (rel * c.abs() + floor)
}

#[test]
fn every_brdf_model_matches_the_f64_reference() {
    let pairs = direction_pairs(1, 600);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    for (mi, model) in BrdfModel::ALL.into_iter().enumerate() {
        for set in 0..6u64 {
            let mut s = SampleStream::new(&[2, mi as u64, set]);
            let brdf = if set == 0 {
                AnalyticBrdf::with_defaults(model)
            } else {
                random_brdf(model, &mut s)
            };
            let record = words.push_brdf(&brdf);
            for &(wi, wo) in &pairs {
                cases.push(Case {
                    kind: 0,
                    record,
                    wi,
                    wo,
                    texel: 0,
                    residual: false,
                });
                reference.push((model, brdf, brdf.eval(wi, wo), wi, wo));
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst: Vec<(f64, String)> = vec![(0.0, String::new()); BrdfModel::ALL.len()];
    for (g, (model, brdf, c, wi, wo)) in got.iter().zip(&reference) {
        let g = g[0];
        assert!(
            g.is_finite() && g >= 0.0,
            "{model:?} {brdf:?} at {wi} {wo}: {g}"
        );
        // f32 carries 6e-8 relative; 1e-4 leaves room for the transcendental functions
        // of WGSL (a few ulp). Lafortune's s^n is exp2(n log2 s): the rounding of
        // log2 s (|s| up to 1e3 x 3) is amplified by n up to 1e4, so its tolerance grows
        // with n |log2 s|. And s itself is a dot product whose terms can cancel (C_x,
        // C_y and C_z of opposite signs): its f32 rounding, at most 4 unit roundoffs of
        // the terms' absolute sum (two products and two sums a term), is amplified by
        // that sum over |s| and by n. Mesa's lavapipe stayed within the first two
        // terms; the H200 did not (1.27 of them at a 220-fold cancellation).
        let rel = match brdf {
            AnalyticBrdf::Lafortune(b) => {
                let terms = DVec3::new(b.cx(), b.cy(), b.cz()) * *wi * *wo;
                let s = terms.element_sum();
                let cancellation = terms.abs().element_sum() / s.abs();
                1e-4 + 1e-6 * b.n() * s.abs().log2().abs().max(1.0)
                    + b.n() * 4.0 * UNIT_ROUNDOFF * cancellation
            }
            _ => 1e-4,
        };
        if *c > f32::MAX as f64 {
            continue;
        }
        let e = excess(g, *c, rel, 1e-6 * (1.0 + c.abs()));
        let slot = &mut worst[BrdfModel::ALL
            .iter()
            .position(|m| m == model)
            .expect("a model")];
        if e > slot.0 {
            *slot = (e, format!("{brdf:?} at wi {wi} wo {wo}: gpu {g}, f64 {c}"));
        }
    }
    for (model, (e, at)) in BrdfModel::ALL.iter().zip(&worst) {
        eprintln!("{model:?}: worst error {e:.3} of the tolerance ({at})");
    }
    for (model, (e, at)) in BrdfModel::ALL.iter().zip(&worst) {
        assert!(*e <= 1.0, "{model:?}: {e:.3} x the tolerance at {at}");
    }
}

#[test]
fn basis_functions_and_spmm_texels_match_the_f64_reference() {
    let pairs = direction_pairs(3, 400);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference: Vec<(String, DVec3)> = Vec::new();
    // Basis functions with tilted normals (the spec's frame rule, both branches).
    for normal in [
        DVec3::Z,
        DVec3::new(0.3, -0.2, 0.9).normalize(),
        DVec3::new(0.0, 0.999, 0.0447).normalize(),
        DVec3::new(0.6, 0.0, 0.8),
    ]
    .into_iter()
    {
        for model in BrdfModel::ALL {
            // The models' own ranges are covered above; here the tilt and the cosine.
            let basis = BasisFunction::new(AnalyticBrdf::with_defaults(model), normal)
                .expect("unit normal");
            let record = words.push_basis(&basis);
            for &(wi, wo) in &pairs {
                cases.push(Case {
                    kind: 1,
                    record,
                    wi,
                    wo,
                    texel: 0,
                    residual: false,
                });
                reference.push((format!("{basis:?}"), DVec3::splat(basis.eval(wi, wo))));
            }
        }
    }
    // SPMM texels: the basis sum, with and without the interpolated residual, whose
    // tables go up as f32 or, when every value is a half float (a pack read from an F16
    // file), as halves two to a word; and with the first `MOVING_NPCA` of its 6
    // components (the moving camera: kind 11).
    let material = meso_materials::spmm::testing::sample_material(4, 3, 3, Some(6));
    let half_material =
        meso_materials::spmm::pack::decode_pack(&meso_materials::spmm::pack::encode_pack(
            &material,
            meso_materials::spmm::pack::ResidualPrecision::F16,
        ))
        .expect("an F16 pack reads back");
    for (material, residual, halves) in [
        (&material, false, false),
        (&material, true, false),
        (&half_material, true, true),
    ] {
        let prepared = material.prepare(&meso_materials::spmm::PrepareRequest {
            used_clusters: None,
            residual,
            max_npca: usize::MAX,
        });
        assert_eq!(prepared.has_residual(), residual);
        if let Some(r) = prepared.parts().residual {
            let held_as_halves = matches!(r.cells, meso_materials::spmm::ResidualCells::F16(_));
            assert_eq!(held_as_halves, halves, "the tables' precision");
        }
        let record = words.push_spmm(&prepared, glam::DVec2::ONE, None);
        for t in 0..12u32 {
            for &(wi, wo) in pairs.iter().step_by(4) {
                let texel_case = |kind| Case {
                    kind,
                    record,
                    wi,
                    wo,
                    texel: t,
                    residual: true,
                };
                cases.push(texel_case(2));
                reference.push((
                    format!("texel {t}, residual {residual}, halves {halves}"),
                    prepared.eval_texel(t as usize, wi, wo),
                ));
                if residual {
                    let moving = meso_materials::spmm::MOVING_NPCA;
                    cases.push(texel_case(11));
                    reference.push((
                        format!("texel {t}, {moving} components, halves {halves}"),
                        material.eval_texel(t as usize, wi, wo, true, moving),
                    ));
                }
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst = (0.0f64, String::new());
    for (g, (what, c)) in got.iter().zip(&reference) {
        for ch in 0..3 {
            assert!(g[ch].is_finite(), "{what}: {g:?}");
            // The residual may be negative; the scale of the texel's value sets the floor.
            let e = excess(g[ch], c[ch], 1e-4, 1e-5 * (1.0 + c.abs().max_element()));
            if e > worst.0 {
                worst = (e, format!("{what}: gpu {g:?}, f64 {c}"));
            }
        }
    }
    eprintln!(
        "basis functions and SPMM texels: worst {:.3} of the tolerance ({})",
        worst.0, worst.1
    );
    assert!(
        worst.0 <= 1.0,
        "{:.3} x the tolerance: {}",
        worst.0,
        worst.1
    );
}

pub(super) fn test_scene(name: &str) -> meso_render::scene::Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/scenes")
        .join(name);
    meso_render::scene::load_scene(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every pixel centre's primary ray on the device and on the CPU: the same hit or
/// miss, the same distance, the same triangle (or one at the same distance: a tie),
/// and no traversal past the stack or step bounds. A hardware GPU need not round as
/// the CPU does (its compiler may fuse multiply-adds; Vulkan allows a division 2.5 ulp
/// off), so a ray through a triangle's edge may fall on either side of it: a
/// disagreement passes only where the nearer of the two hits is within `EDGE` of an
/// edge of its triangle (barycentrics in f64), and on at most half of the rays whose
/// hit on either device lies that near an edge (a device whose edge rule left a crack
/// along every edge would disagree on nearly all of them). Lavapipe rounds as the CPU does and has none; the
/// H200 had 12 in the Cornell box, whose camera on the symmetry plane sends 106 pixel
/// centres exactly through the walls' diagonals.
fn primary_hits_match(scene_file: &str, size: u32) {
    const EDGE: f64 = 1e-5;
    let scene = test_scene(scene_file);
    let bvh = meso_render::geometry::SceneBvh::build(&scene.meshes);
    let camera = meso_render::geometry::PinholeCamera::new(&scene.camera, size, size);
    let rays: Vec<_> = (0..size * size)
        .map(|p| camera.ray(p % size, p / size, glam::DVec2::splat(0.5)))
        .collect();
    let mut words = Vec::with_capacity(rays.len() * 8);
    for r in &rays {
        words.extend(f32s(r.origin));
        words.extend(f32s(r.dir));
        // The shader clamps its rays at 3e38 ("infinity"; WGSL may assume no inf).
        words.extend([0f32.to_bits(), 3.0e38f32.to_bits()]);
    }
    let ctx = context();
    let kernel = Kernel::new(ctx, &test_module(), "trace_rays", &TEST_SLOTS);
    let geometry = super::geometry::GeometryBuffers::upload(ctx, &bvh, &scene.meshes);
    let cases = storage(ctx, "rays", bytemuck::cast_slice(&words));
    let out_size = (rays.len() * 8) as u64;
    let out = zeroed(ctx, "results", out_size);
    let data = zeroed(ctx, "data", 16);
    let counters = zeroed(ctx, "counters", 16);
    let bind = kernel.bind(
        ctx,
        &[
            &data,
            &cases,
            &out,
            &geometry.nodes,
            &geometry.tris,
            &counters,
            &data,
        ],
    );
    let mut enc = encoder(ctx);
    kernel.record(&mut enc, &bind, rays.len() as u32);
    let bytes =
        submit_and_read(ctx, enc, &[(&out, out_size), (&counters, 16)]).expect("the device works");
    let results: &[[f32; 2]] = bytemuck::cast_slice(&bytes[0]);
    let overflows: &[u32] = bytemuck::cast_slice(&bytes[1]);
    assert_eq!(
        &overflows[..2],
        &[0, 0],
        "{scene_file}: stack and step overflows"
    );
    let prims: Vec<(&obvhs::triangle::Triangle, (u32, u32))> = bvh.primitives().collect();
    let by_index: std::collections::HashMap<(usize, usize), &obvhs::triangle::Triangle> = prims
        .iter()
        .map(|&(t, (m, i))| ((m as usize, i as usize), t))
        .collect();
    let (mut hits, mut ties, mut edges, mut edge_rays) = (0, 0, 0, 0);
    for (i, (r, g)) in rays.iter().zip(results).enumerate() {
        let cpu = bvh.closest_hit(r.origin, r.dir, 0.0, f64::INFINITY);
        let gpu = (g[1] >= 0.0).then(|| (g[0] as f64, g[1] as usize));
        hits += usize::from(cpu.is_some());
        // A ray through an edge: either device's hit lies at one.
        let cpu_triangle = cpu.as_ref().map(|h| by_index[&(h.mesh, h.triangle)]);
        let gpu_triangle = gpu.map(|(_, prim)| prims[prim].0);
        edge_rays += usize::from(
            [cpu_triangle, gpu_triangle]
                .into_iter()
                .flatten()
                .any(|t| barycentric_margin(t, r.origin, r.dir) <= EDGE),
        );
        let agree = match (&cpu, gpu) {
            (None, None) => true,
            (Some(h), Some((t, prim))) => {
                let (m, tri) = prims[prim].1;
                let same = (m as usize, tri as usize) == (h.mesh, h.triangle);
                // A tie: another triangle at the same distance (a shared edge).
                ties += usize::from(!same && t as f32 == h.t as f32);
                (t - h.t).abs() <= 1e-6 * h.t && (same || t as f32 == h.t as f32)
            }
            _ => false,
        };
        if agree {
            continue;
        }
        let gpu_t = gpu.map_or(f64::INFINITY, |(t, _)| t);
        let (edge_distance, nearer) = match &cpu {
            Some(h) if h.t <= gpu_t => ((1.0 - h.b1 - h.b2).min(h.b1).min(h.b2), "CPU"),
            _ => {
                let (_, prim) = gpu.expect("the GPU hit is the nearer");
                (barycentric_margin(prims[prim].0, r.origin, r.dir), "GPU")
            }
        };
        assert!(
            edge_distance <= EDGE,
            "{scene_file} pixel {i}: the CPU finds {cpu:?}, the GPU {gpu:?}, and the {nearer}'s \
             hit is {edge_distance:e} inside its triangle, not at an edge"
        );
        edges += 1;
    }
    eprintln!(
        "{scene_file}: {hits} of {} rays hit, {edge_rays} within {EDGE:e} of an edge, \
         {ties} ties, {edges} on an edge disagree",
        rays.len()
    );
    assert!(
        hits > rays.len() / 3,
        "{scene_file}: the camera sees the scene"
    );
    assert!(ties * 100 <= hits, "{scene_file}: {ties} ties of {hits}");
    assert!(
        edges <= edge_rays.div_ceil(2),
        "{scene_file}: {edges} disagreements of {edge_rays} rays through an edge"
    );
}

/// The smallest barycentric weight of the ray's intersection with the triangle's
/// plane, in f64: negative outside, near zero at an edge.
fn barycentric_margin(tri: &obvhs::triangle::Triangle, o: DVec3, d: DVec3) -> f64 {
    let [v0, v1, v2] = [tri.v0, tri.v1, tri.v2].map(|v| v.as_dvec3());
    let (e1, e2) = (v1 - v0, v2 - v0);
    let p = d.cross(e2);
    let inv_det = 1.0 / e1.dot(p);
    let s = o - v0;
    let b1 = s.dot(p) * inv_det;
    let b2 = d.dot(s.cross(e1)) * inv_det;
    (1.0 - b1 - b2).min(b1).min(b2)
}

#[test]
fn primary_hits_equal_the_cpus_on_the_bunny() {
    primary_hits_match("default.toml", 96);
}

#[test]
fn primary_hits_equal_the_cpus_in_the_cornell_box() {
    primary_hits_match("cornell.toml", 96);
}

fn rmse(a: &meso_materials::image::Image, b: &meso_materials::image::Image) -> f64 {
    let n = a.pixels().len() as f64 * 3.0;
    let sum: f64 = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum();
    (sum / n).sqrt()
}

fn mean(a: &meso_materials::image::Image) -> f64 {
    a.pixels().iter().flatten().map(|&v| v as f64).sum::<f64>() / (a.pixels().len() * 3) as f64
}

fn gpu_mode(scene: meso_render::scene::Scene, size: u32) -> super::GpuSpmmMode {
    super::GpuSpmmMode::prepare(
        context().clone(),
        scene,
        size,
        size,
        meso_render::Prepare::quietly(),
    )
    .expect("the GPU mode renders the scene")
}

/// The GPU image after `frames` frames against the CPU's converged one: an error no
/// larger than the CPU's own after as many frames (independent samples, as the GPU
/// draws them; packs sampled from their bases on both, the CPU's default)
/// times 1.25 plus a floor of 1% of the image's mean, the same mean within
/// 2% plus four standard errors of an image mean after `frames` frames (the CPU's own
/// RMSE over the square root of the pixel count: sharp MERL lobes make rare, large
/// samples, whose noise in the mean is far above 2% at 16 frames), no non-finite pixel
/// and no traversal past its bounds.
fn image_agrees_with_the_cpu(scene_file: &str, size: u32, frames: u32) {
    image_of_scene_agrees_with_the_cpu(scene_file, test_scene(scene_file), size, frames);
}

fn image_of_scene_agrees_with_the_cpu(
    scene_file: &str,
    scene: meso_render::scene::Scene,
    size: u32,
    frames: u32,
) {
    mode_agrees_with_the_cpu(scene_file, scene, size, frames, None);
}

/// The rule above for `gpu` (a fresh mode of `scene` if `None`) after `frames` more
/// frames: a mode with a history (edits that kept some layers' samples) has at least
/// as many samples per layer as a fresh one.
fn mode_agrees_with_the_cpu(
    scene_file: &str,
    mut scene: meso_render::scene::Scene,
    size: u32,
    frames: u32,
    gpu: Option<super::GpuSpmmMode>,
) {
    use meso_render::{RenderMode, run_frames};
    scene.render.sampler = meso_materials::rng::Sampler::Independent;
    let mut reference =
        meso_modes::trace::SpmmMode::new(scene.clone(), size, size).expect("CPU mode");
    run_frames(&mut reference, 16 * frames, |_, _| {});
    let reference = reference.image();
    // Another seed than the reference's, so the two are independent.
    let mut other = scene.clone();
    other.render.seed += 1;
    let mut cpu = meso_modes::trace::SpmmMode::new(other, size, size).expect("CPU mode");
    run_frames(&mut cpu, frames, |_, _| {});
    let mut gpu = gpu.unwrap_or_else(|| gpu_mode(scene, size));
    let run = run_frames(&mut gpu, frames, |_, _| {});
    let image = gpu.image();
    assert!(
        image.pixels().iter().flatten().all(|v| v.is_finite()),
        "{scene_file}: non-finite pixels"
    );
    assert_eq!(run.dropped, 0, "{scene_file}: non-finite samples");
    assert_eq!(gpu.overflows(), (0, 0), "{scene_file}: traversal overflows");
    assert!(run.counters.rays.shadow + run.counters.rays.environment > 0);
    let (e_gpu, e_cpu) = (rmse(&image, &reference), rmse(&cpu.image(), &reference));
    let (m_gpu, m_ref) = (mean(&image), mean(&reference));
    eprintln!(
        "{scene_file} {size}x{size}, {frames} frames: RMSE gpu {e_gpu:.5}, cpu {e_cpu:.5}; mean gpu {m_gpu:.5}, cpu {:.5}, reference {m_ref:.5}",
        mean(&cpu.image())
    );
    assert!(
        e_gpu <= 1.25 * e_cpu + 0.01 * m_ref,
        "{scene_file}: GPU RMSE {e_gpu} against the CPU's {e_cpu}"
    );
    let standard_error = e_cpu / f64::from(size);
    assert!(
        (m_gpu - m_ref).abs() <= 0.02 * m_ref + 4.0 * standard_error,
        "{scene_file}: mean {m_gpu} against {m_ref} (standard error {standard_error})"
    );
}

#[test]
fn the_default_scene_on_the_gpu_agrees_with_the_cpu() {
    image_agrees_with_the_cpu("default.toml", 40, 16);
}

#[test]
fn the_cornell_box_on_the_gpu_agrees_with_the_cpu() {
    image_agrees_with_the_cpu("cornell.toml", 40, 16);
}

/// A light-colour edit keeps every sample, as on the CPU: with the light alone
/// lighting the scene, doubling its radiance doubles the image exactly and the
/// sample count stays.
#[test]
fn a_light_colour_edit_keeps_the_gpus_samples() {
    use meso_render::{Invalidation, RenderMode, SceneEdit, run_frames};
    let mut scene = test_scene("cornell.toml");
    scene.ambient = None;
    scene.background = meso_render::scene::Background::Color(DVec3::ZERO);
    let mut gpu = gpu_mode(scene.clone(), 24);
    run_frames(&mut gpu, 3, |_, _| {});
    let before = gpu.image();
    let samples = gpu.progress().min_samples;
    let light = scene.lights[0].with_emission(scene.lights[0].emission() * 2.0);
    assert_eq!(
        gpu.apply(SceneEdit::Light { index: 0, light })
            .expect("edit"),
        Invalidation::Nothing
    );
    assert_eq!(gpu.progress().min_samples, samples);
    let after = gpu.image();
    assert!(mean(&before) > 0.0);
    for (a, b) in after.pixels().iter().zip(before.pixels()) {
        for c in 0..3 {
            assert!(
                (a[c] - 2.0 * b[c]).abs() <= 1e-6 * b[c].abs().max(1e-6),
                "{a:?} {b:?}"
            );
        }
    }
    // Moving the light restarts its layer only: the samples of the frame after it.
    let mut moved = light;
    if let meso_render::scene::Light::Area { corner, .. } = &mut moved {
        corner.y -= 0.1;
    }
    assert_eq!(
        gpu.apply(SceneEdit::Light {
            index: 0,
            light: moved
        })
        .expect("edit"),
        Invalidation::Layer(meso_render::layers::FIRST_LIGHT)
    );
    run_frames(&mut gpu, 1, |_, _| {});
    assert_eq!(gpu.progress().min_samples, 1);
}

/// The environment scene (the studio map with MIS, a fitted pack with its residual
/// on the bunny, a Ward floor; rays that leave see the map): the map's and the
/// BRDFs' samples on the device, weighted as on the CPU.
#[test]
fn the_environment_scene_on_the_gpu_agrees_with_the_cpu() {
    image_agrees_with_the_cpu("env.toml", 32, 16);
}

/// The environment lighting alone (no MIS), a lat-long background image seen by
/// primary rays and by a mirror floor, rotated: what `layers::escaped` adds.
#[test]
fn a_background_image_and_map_sampling_alone_agree_with_the_cpu() {
    let mut scene = test_scene("env.toml");
    let env = scene.environment.as_mut().expect("an environment");
    env.mis = false;
    env.rotate_y_deg = -75.0;
    let (w, h) = (24, 12);
    let pixels = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
            [0.2 + x, 0.5 * (1.0 - y), 0.1 + 0.8 * x * y]
        })
        .collect();
    let image = meso_materials::image::Image::from_pixels(w, h, pixels).expect("an image");
    scene.background = meso_render::scene::Background::Environment(std::sync::Arc::new(image));
    let floor = scene
        .material_names
        .iter()
        .position(|n| n == "floor")
        .expect("the floor");
    scene.materials[floor] = meso_render::scene::Material::Mirror {
        reflectance: DVec3::new(0.8, 0.7, 0.6),
    };
    image_of_scene_agrees_with_the_cpu("env.toml with a background image", scene, 32, 16);
}

/// The mode refuses by name what it does not render yet, and an edit that brings it.
/// Nothing the CPU mode renders is refused on the GPU: BTF materials and more than
/// 16 lights are accepted, and so is an edit that brings a BTF.
#[test]
fn btf_materials_and_many_lights_are_supported() {
    use meso_render::{RenderMode, SceneEdit};
    let mut scene = test_scene("cornell.toml");
    let btf = meso_render::scene::test_scenes::tabulated_btf(
        &AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        DVec3::splat(0.5),
        glam::DVec2::ONE,
    );
    let mut with_btf = scene.clone();
    with_btf.materials[0] = btf.clone();
    super::GpuSpmmMode::supports(&with_btf).expect("a BTF material");
    let light = scene.lights[0];
    scene.lights = vec![light; 17];
    super::GpuSpmmMode::supports(&scene).expect("17 lights");
    let mut gpu = gpu_mode(scene, 8);
    gpu.apply(SceneEdit::Material {
        index: 0,
        material: btf,
    })
    .expect("a BTF edit");
    assert!(matches!(
        gpu.scene().materials[0],
        meso_render::scene::Material::Btf { .. }
    ));
    assert!(gpu.device_bytes().btf_tables > 0);
    // A table no mesh carries goes up not at all.
    let mut bare = gpu.scene().clone();
    bare.meshes.retain(|m| m.material != 0);
    assert_eq!(gpu_mode(bare, 8).device_bytes().btf_tables, 0);
}

/// The code-built edit scene: an SPMM panel with a PCA residual under an area and a
/// point light with AO; while moving, the pixels that shaded the residual restart
/// and render without it, as on the CPU.
#[test]
fn the_residual_panel_and_the_moving_flag_agree_with_the_cpu() {
    use meso_render::{Invalidation, RenderMode, SceneEdit, run_frames};
    let scene = meso_render::scene::test_scenes::edit_test_scene();
    image_of_scene_agrees_with_the_cpu("edit_test_scene", scene.clone(), 24, 16);
    let mut gpu = gpu_mode(scene, 24);
    run_frames(&mut gpu, 2, |_, _| {});
    let still = gpu.image();
    let Invalidation::Pixels(n) = gpu.apply(SceneEdit::Moving(true)).expect("edit") else {
        panic!("moving restarts pixels")
    };
    assert!(n > 0 && n < 24 * 24, "{n} pixels shaded the residual");
    run_frames(&mut gpu, 2, |_, _| {});
    let moving = gpu.image();
    assert_ne!(rmse(&still, &moving), 0.0, "the residual changes the image");
    assert_eq!(
        gpu.apply(SceneEdit::Moving(true)).expect("edit"),
        Invalidation::Nothing
    );
}

/// Large images dispatch in rows of workgroups: every pixel gets one invocation.
#[test]
fn dispatch_grids_cover_every_pixel_within_the_limit() {
    use super::kernel::{MAX_GROUPS_X, WORKGROUP, groups};
    for pixels in [1, 64, 65, 2048 * 2048, 4096 * 4096, 16384 * 16384] {
        let (x, y) = groups(pixels);
        assert!(
            (1..=MAX_GROUPS_X).contains(&x) && y >= 1,
            "{pixels}: {x} x {y}"
        );
        let threads = u64::from(x) * u64::from(y) * u64::from(WORKGROUP);
        assert!(threads >= u64::from(pixels), "{pixels}: {threads}");
        // At most one partial row of workgroups beyond the pixels.
        assert!(threads - u64::from(pixels) < u64::from(x) * u64::from(WORKGROUP) + 64);
    }
}

/// A device lost while the mode renders (here destroyed on purpose, as a driver reset
/// would) is an error the mode reports, not a panic: the frame adds nothing, the
/// progress stays as it was, later frames add nothing either, and the image (its film
/// was on the device, gone with it) is black, not a panic or a read of freed memory.
#[test]
fn a_lost_device_is_reported_and_renders_nothing_more() {
    use meso_render::{ModeError, RenderMode, run_frames};
    // A device of its own: the other tests share `context()`.
    let ctx = GpuContext::new().expect("an adapter");
    let mut gpu = super::GpuSpmmMode::prepare(
        ctx.clone(),
        test_scene("cornell.toml"),
        16,
        16,
        meso_render::Prepare::quietly(),
    )
    .expect("prepares");
    run_frames(&mut gpu, 2, |_, _| {});
    assert!(gpu.failure().is_none());
    assert!(mean(&gpu.image()) > 0.0);
    assert_eq!(gpu.progress().min_samples, 2);
    ctx.device.destroy();
    let run = run_frames(&mut gpu, 3, |_, _| {});
    assert_eq!(run.frames, 1, "stops at the failed frame");
    assert_eq!(run.counters.samples, 0);
    let Some(ModeError::DeviceFailed(message)) = gpu.failure() else {
        panic!("a device failure, got {:?}", gpu.failure())
    };
    assert!(message.contains(&ctx.adapter_name()), "{message}");
    assert_eq!(gpu.progress().min_samples, 2, "the progress stays");
    assert!(gpu.image_on_device().is_none());
    assert_eq!(mean(&gpu.image()), 0.0);
    assert_eq!(gpu.render_frame().counters.samples, 0);
}

/// The adapter `GpuContext::new` picks, with a device made the way the studio's window
/// makes it (`needed_limits`, its own label): what `from_device` is given there.
fn window_device(
    limits: impl Fn(&wgpu::Adapter) -> wgpu::Limits,
) -> (wgpu::Adapter, wgpu::Device, wgpu::Queue) {
    let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    let instance = wgpu::Instance::new(desc);
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        ..Default::default()
    }))
    .expect("an adapter (CI: lavapipe, WGPU_BACKEND=vulkan)");
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("window"),
        required_limits: limits(&adapter),
        ..Default::default()
    }))
    .expect("a device");
    (adapter, device, queue)
}

/// A context on a device made elsewhere (the studio's window's) renders what a
/// context of its own renders, bit for bit: the same adapter, shader and samples, and
/// the device's limits only bound sizes. The shared device is the one given.
#[test]
fn a_shared_device_renders_what_an_own_device_renders() {
    use meso_render::{RenderMode, run_frames};
    let (adapter, device, queue) = window_device(GpuContext::needed_limits);
    let shared = GpuContext::from_device(&adapter, device.clone(), queue).expect("shareable");
    assert!(shared.is_shared() && !context().is_shared());
    assert_eq!(shared.sharing(), &super::Sharing::Shared);
    assert_eq!(shared.adapter_name(), context().adapter_name());
    assert!(
        shared.device == device,
        "the context renders on the device it was given"
    );
    let scene = test_scene("default.toml");
    let mut on_shared = super::GpuSpmmMode::prepare(
        shared,
        scene.clone(),
        24,
        24,
        meso_render::Prepare::quietly(),
    )
    .expect("prepares on the shared device");
    let mut on_own = gpu_mode(scene, 24);
    run_frames(&mut on_shared, 3, |_, _| {});
    run_frames(&mut on_own, 3, |_, _| {});
    assert!(on_shared.failure().is_none());
    assert!(
        on_shared
            .diagnostics()
            .summary()
            .is_some_and(|s| s.contains("shared with the window")),
        "{:?}",
        on_shared.diagnostics().summary()
    );
    let (a, b) = (on_shared.image(), on_own.image());
    assert!(a.pixels().iter().flatten().any(|v| *v > 0.0), "not black");
    assert_eq!(a.pixels(), b.pixels(), "bit for bit");
}

/// A device made with fewer storage buffers per stage than the integrator binds is
/// refused by name, whatever the adapter (so the studio makes a device of its own).
#[test]
fn a_device_with_too_low_limits_is_not_shared() {
    let (adapter, device, queue) = window_device(|_| wgpu::Limits::downlevel_defaults());
    let err = GpuContext::from_device(&adapter, device, queue).expect_err("too low");
    let message = err.to_string();
    assert!(
        message.contains("max_storage_buffers_per_shader_stage is 4"),
        "{message}"
    );
    assert!(message.contains("cannot be shared"), "{message}");
}

/// BRDF importance sampling in WGSL (the environment's MIS) against core's f64
/// `sample` and `pdf`: each model at its defaults and five random parameter sets, the
/// pdf on the pairs of `direction_pairs`, and directions drawn from the same uniform
/// numbers. f32 limits: the pdf within 1e-3 relative (plus 1e-6 absolute; Lafortune's
/// power grows it as in `every_brdf_model_matches_the_f64_reference`), the drawn
/// direction within 1e-4 per component, drawn or not alike except where the CPU's
/// direction is within 1e-3 of the horizon (the f32 rounding decides there).
#[test]
fn brdf_sampling_matches_the_f64_reference() {
    use glam::DVec2;
    let pairs = direction_pairs(5, 400);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    for (mi, model) in BrdfModel::ALL.into_iter().enumerate() {
        for set in 0..6u64 {
            let mut s = SampleStream::new(&[6, mi as u64, set]);
            let brdf = if set == 0 {
                AnalyticBrdf::with_defaults(model)
            } else {
                random_brdf(model, &mut s)
            };
            let record = words.push_brdf(&brdf);
            for (k, &(wi, wo)) in pairs.iter().enumerate() {
                let mut case = Case {
                    kind: 3,
                    record,
                    wi,
                    wo,
                    texel: 0,
                    residual: false,
                };
                cases.push(case);
                reference.push((brdf, wi, wo, None));
                let u = DVec2::new(s.next(), s.next()).as_vec2().as_dvec2();
                let u = u.min(DVec2::splat(1.0 - 1e-7));
                case.kind = 4;
                case.wi = DVec3::new(u.x, u.y, 0.0);
                cases.push(case);
                reference.push((brdf, wi, wo, Some((u, k))));
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst_pdf: f64 = 0.0;
    let mut worst_dir: f64 = 0.0;
    let mut drawn = 0;
    for (g, (brdf, wi, wo, sample)) in got.iter().zip(&reference) {
        match sample {
            None => {
                let c = brdf.pdf(*wo, *wi);
                let g = g[0];
                assert!(g.is_finite() && g >= 0.0, "{brdf:?} pdf at {wi} {wo}: {g}");
                if c > 1e30 {
                    continue;
                }
                let rel = match brdf {
                    AnalyticBrdf::Lafortune(b) => {
                        let s = wi.dot(DVec3::new(b.cx(), b.cy(), b.cz()) * *wo);
                        1e-3 + 1e-5 * b.n() * s.abs().log2().abs().max(1.0)
                    }
                    _ => 1e-3,
                };
                let e = excess(g, c, rel, 1e-6 * (1.0 + c));
                assert!(
                    e <= 1.0,
                    "{brdf:?} pdf at wi {wi} wo {wo}: gpu {g}, f64 {c}"
                );
                worst_pdf = worst_pdf.max(e);
            }
            Some((u, _)) => {
                let c = brdf.sample(*wo, *u).map(|s| s.wi);
                let gv = DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64);
                assert!(gv.is_finite(), "{brdf:?} sample at {wo} {u}: {gv}");
                match c {
                    Some(c) if gv != DVec3::ZERO => {
                        let e = (gv - c).abs().max_element();
                        assert!(
                            e <= 1e-4,
                            "{brdf:?} sample at wo {wo} u {u}: gpu {gv}, f64 {c}"
                        );
                        worst_dir = worst_dir.max(e);
                        drawn += 1;
                    }
                    Some(c) => assert!(
                        c.z < 1e-3,
                        "{brdf:?} at wo {wo} u {u}: only the CPU draws {c}"
                    ),
                    None if gv != DVec3::ZERO => assert!(
                        gv.z < 1e-3,
                        "{brdf:?} at wo {wo} u {u}: only the GPU draws {gv}"
                    ),
                    None => {}
                }
            }
        }
    }
    eprintln!(
        "pdf: worst {worst_pdf:.3} of the tolerance; directions: {drawn} drawn, worst {worst_dir:.2e}"
    );
    assert!(drawn > cases.len() / 4, "most samples are drawn: {drawn}");
}

/// A MERL table (a tabulated Cook-Torrance lobe with every 7th cell's red channel
/// marked "no data") with its sampling tables in the data words.
fn merl_test_table() -> (Words, u32, meso_materials::merl::MerlBrdf) {
    let lobe =
        AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.15), ("f0", 0.6)]).expect("a lobe");
    let tabulated =
        meso_materials::merl::tabulate(&lobe, DVec3::new(0.9, 0.6, 0.3)).expect("tabulates");
    let mut stored = tabulated.stored().to_vec();
    for cell in stored.iter_mut().step_by(7) {
        cell[0] = -1.0;
    }
    let brdf = meso_materials::merl::MerlBrdf::from_stored(stored).expect("a table");
    let mut words = Words::default();
    let record = words.push_merl(&brdf);
    (words, record, brdf)
}

/// The distance in index units from `c` to the nearest bin edge among `edges`.
fn edge_distance(c: f64, edges: std::ops::RangeInclusive<i64>) -> f64 {
    (c - (c.round() as i64).clamp(*edges.start(), *edges.end()) as f64).abs()
}

/// Where `HalfDiff` puts a pair, in index units: the distance to the nearest bin edge
/// (f32 directions may land on the other side of an edge closer than this). The
/// theta indices are clamped at their ends; phi_d's fold makes 0 and 180 edges too.
fn merl_edge_distance(wi: DVec3, wo: DVec3) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let h = meso_materials::merl::HalfDiff::from_directions(wi, wo);
    edge_distance((h.theta_h / FRAC_PI_2).sqrt() * 90.0, 1..=89)
        .min(edge_distance(h.theta_d / FRAC_PI_2 * 90.0, 1..=89))
        .min(edge_distance(h.phi_d / PI * 180.0, 0..=180))
}

/// The same for `MerlSampler::pdf`'s band of `wo`, row and column of `wi`.
fn merl_sampler_edge_distance(wi: DVec3, wo: DVec3) -> f64 {
    use std::f64::consts::{FRAC_PI_2, TAU};
    let theta_o = wo.x.hypot(wo.y).atan2(wo.z);
    let phi = (wi.y.atan2(wi.x) - wo.y.atan2(wo.x)).rem_euclid(TAU);
    edge_distance(theta_o / FRAC_PI_2 * 45.0, 1..=44)
        .min(edge_distance(wi.z * 64.0, 1..=63))
        .min(edge_distance(phi / TAU * 128.0, 0..=128))
}

/// MERL in WGSL against core: the nearest-cell value on random and grazing pairs
/// (equal to the f64 value rounded to f32, cells without data 0), except pairs within
/// 1e-3 of a bin edge in index units (at most 10% of them); the sampling pdf within
/// 1e-5 relative except within 1e-3 of a band, row or column edge (at most 15%), and
/// the drawn direction within 1e-4 per component from the CPU's own tables,
/// disagreeing on at most 1% of cases (an f32 CDF entry or band edge next to the
/// number drawn).
#[test]
fn merl_lookup_and_sampling_match_the_cpu() {
    use glam::DVec2;
    let (words, record, brdf) = merl_test_table();
    let pairs = direction_pairs(11, 4000);
    let mut cases = Vec::new();
    for &(wi, wo) in &pairs {
        let case = Case {
            kind: 5,
            record,
            wi,
            wo,
            texel: 0,
            residual: false,
        };
        cases.push(case);
        cases.push(Case { kind: 6, ..case });
    }
    let mut s = SampleStream::new(&[12]);
    let mut us = Vec::new();
    for &(_, wo) in &pairs {
        let u = DVec2::new(s.next(), s.next()).as_vec2().as_dvec2();
        us.push(u);
        cases.push(Case {
            kind: 7,
            record,
            wi: DVec3::new(u.x, u.y, 0.0),
            wo,
            texel: 0,
            residual: false,
        });
    }
    let got = evaluate(&words.words, &cases);
    let (mut near_edge, mut nonzero, mut pdf_off, mut dir_off, mut drawn) = (0, 0, 0, 0, 0);
    for (k, &(wi, wo)) in pairs.iter().enumerate() {
        let (g, gp) = (got[2 * k], got[2 * k + 1][0]);
        assert!(
            g.iter().all(|v| v.is_finite() && *v >= 0.0),
            "{wi} {wo}: {g:?}"
        );
        let c = brdf.eval(wi, wo);
        if merl_edge_distance(wi, wo) < 1e-3 {
            near_edge += 1;
        } else {
            for ch in 0..3 {
                assert_eq!(g[ch], c[ch] as f32, "channel {ch} at wi {wi} wo {wo}");
            }
            nonzero += usize::from(c.x > 0.0);
        }
        let cp = brdf.pdf(wo, wi);
        assert!(gp.is_finite() && gp >= 0.0, "pdf at {wi} {wo}: {gp}");
        if merl_sampler_edge_distance(wi, wo) < 1e-3 {
            pdf_off += 1;
        } else {
            assert!(
                (gp as f64 - cp).abs() <= 1e-5 * cp,
                "pdf at wi {wi} wo {wo}: gpu {gp}, f64 {cp}"
            );
        }
        let g = got[2 * pairs.len() + k];
        let g = DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64);
        match brdf.sample(wo, us[k]) {
            Some(c) => {
                drawn += 1;
                if (g - c.wi).abs().max_element() > 1e-4 {
                    dir_off += 1;
                }
            }
            None => assert_eq!(g, DVec3::ZERO, "only the GPU draws at wo {wo}"),
        }
    }
    eprintln!(
        "MERL: {near_edge} of {} pairs next to a bin edge, {nonzero} nonzero red values compared; {pdf_off} pdfs next to a sampler edge, direction off on {dir_off} of {drawn}",
        pairs.len()
    );
    // Both-grazing pairs put phi_d at pi/2 within f32 rounding (a bin edge): measured
    // 6.4% of the pairs.
    assert!(
        near_edge * 10 <= pairs.len(),
        "{near_edge} pairs near an edge"
    );
    assert!(nonzero > pairs.len() / 4, "red channel compared: {nonzero}");
    // The mirror pairs (every 8th) put phi_i - phi_o at pi exactly, a column edge.
    assert!(
        pdf_off * 100 <= pairs.len() * 15,
        "{pdf_off} pdfs near an edge"
    );
    assert!(
        drawn > pairs.len() / 2 && dir_off * 100 <= drawn,
        "direction off on {dir_off}"
    );
}

/// The MERL scene (two tabulated tables, the studio map with MIS, an area light).
#[test]
fn the_merl_scene_on_the_gpu_agrees_with_the_cpu() {
    image_agrees_with_the_cpu("merl_bunny.toml", 32, 16);
}

/// Only GPUs count as hardware for the studio's default device: the adapter CI has
/// (lavapipe, a CPU adapter) does not, so there the studio stays on the CPU.
#[test]
fn software_adapters_are_not_hardware() {
    use wgpu::DeviceType;
    assert!(super::is_hardware(DeviceType::DiscreteGpu));
    assert!(super::is_hardware(DeviceType::IntegratedGpu));
    assert!(!super::is_hardware(DeviceType::Cpu));
    assert!(!super::is_hardware(DeviceType::Other));
    assert_eq!(
        context().is_software(),
        !super::is_hardware(context().info_type())
    );
    if context().is_software() {
        assert_eq!(
            super::hardware_adapter(),
            None,
            "{}",
            context().adapter_name()
        );
    }
}

/// Diagnostics (not a check): means of the MERL scene's variants after many frames on
/// both devices. `cargo test -p meso-gpu --lib merl_means -- --ignored --nocapture`.
#[test]
#[ignore]
fn merl_means() {
    use meso_render::{RenderMode, run_frames};
    let base = test_scene("merl_bunny.toml");
    let mut lights_only = base.clone();
    lights_only.environment = None;
    let mut env_only = base.clone();
    env_only.lights.clear();
    for (name, scene) in [("all", base), ("lights", lights_only), ("env", env_only)] {
        let mut gpu = gpu_mode(scene.clone(), 32);
        run_frames(&mut gpu, 256, |_, _| {});
        let mut cpu = meso_modes::trace::SpmmMode::new(scene, 32, 32).expect("CPU mode");
        run_frames(&mut cpu, 256, |_, _| {});
        eprintln!(
            "{name}: gpu {:.5} cpu {:.5}",
            mean(&gpu.image()),
            mean(&cpu.image())
        );
    }
}

/// The pack sampler in WGSL (`spmm_sample_texel`, `spmm_texel_pdf`) against
/// `PreparedSpmm::sample_texel` / `texel_pdf` (the CPU's `PackSampling::Bases`) on
/// every texel of a pack of tilted Lambertian, Ward, Ashikhmin-Shirley, Lafortune and
/// Oren-Nayar bases (one texel's weights zeroed: the defensive mixture alone), on
/// random and grazing direction pairs. f32 limits: the pdf within 1e-3 relative plus
/// 1e-6 of its scale (as the BRDF samplers' pdfs); the direction drawn from the same
/// numbers within 1e-3 per component, drawn or not alike, except on at most 2% of
/// draws (a number within f32 rounding of a basis's selection interval edge picks the
/// neighbouring basis; the horizon decides near-grazing draws).
#[test]
fn pack_sampling_matches_the_cpus() {
    use glam::DVec2;
    let mut material = meso_materials::spmm::testing::sample_material(4, 3, 3, None);
    // Texel 5 without weight: the sampler falls back to the defensive mixture alone.
    {
        let w = material.weights().clone();
        let mut rgb = w.rgb.clone();
        for v in &mut rgb[w.offsets[5] as usize..w.offsets[6] as usize] {
            *v = [0.0; 3];
        }
        material = meso_materials::spmm::SpmmMaterial::new(
            material.name().to_string(),
            material.provenance().to_string(),
            material.width(),
            material.height(),
            material.clusters().to_vec(),
            material.texel_cluster().to_vec(),
            meso_materials::spmm::SparseWeights {
                offsets: w.offsets.clone(),
                basis: w.basis.clone(),
                rgb,
            },
            None,
        )
        .expect("valid material");
    }
    let prepared = material.prepare(&meso_materials::spmm::PrepareRequest {
        used_clusters: None,
        residual: false,
        max_npca: 0,
    });
    let mut words = Words::default();
    let record = words.push_spmm(&prepared, glam::DVec2::ONE, None);
    let pairs = direction_pairs(11, 240);
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    let mut s = SampleStream::new(&[12]);
    for t in 0..12u32 {
        for &(wi, wo) in &pairs {
            let case = Case {
                kind: 8,
                record,
                wi,
                wo,
                texel: t,
                residual: false,
            };
            cases.push(case);
            reference.push((t, wi, wo, None));
            let u = DVec2::new(s.next(), s.next()).as_vec2().as_dvec2();
            let u = u.min(DVec2::splat(1.0 - 1e-7));
            cases.push(Case {
                kind: 9,
                wi: DVec3::new(u.x, u.y, 0.0),
                ..case
            });
            reference.push((t, wi, wo, Some(u)));
        }
    }
    let got = evaluate(&words.words, &cases);
    let (mut worst_pdf, mut worst_dir, mut drawn, mut off, mut draws) = (0.0f64, 0.0f64, 0, 0, 0);
    for (g, &(t, wi, wo, u)) in got.iter().zip(&reference) {
        let t = t as usize;
        match u {
            None => {
                let c = prepared.texel_pdf(t, wi, wo);
                let g = g[0];
                assert!(g.is_finite() && g >= 0.0, "texel {t} pdf at {wi} {wo}: {g}");
                let e = excess(g, c, 1e-3, 1e-6 * (1.0 + c));
                assert!(
                    e <= 1.0,
                    "texel {t} pdf at wi {wi} wo {wo}: gpu {g}, f64 {c}"
                );
                worst_pdf = worst_pdf.max(e);
            }
            Some(u) => {
                draws += 1;
                let c = prepared.sample_texel(t, wo, u).map(|s| s.0);
                let gv = DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64);
                assert!(gv.is_finite(), "texel {t} sample at {wo} {u}: {gv}");
                match c {
                    Some(c) if gv != DVec3::ZERO => {
                        let e = (gv - c).abs().max_element();
                        if e > 1e-3 {
                            off += 1;
                        } else {
                            worst_dir = worst_dir.max(e);
                            drawn += 1;
                        }
                    }
                    None if gv == DVec3::ZERO => {}
                    _ => off += 1,
                }
            }
        }
    }
    eprintln!(
        "pack sampling: pdf worst {worst_pdf:.3} of the tolerance; {draws} draws, {drawn} alike (worst {worst_dir:.2e}), {off} off"
    );
    assert!(
        off * 50 <= draws,
        "{off} of {draws} draws differ from the CPU's"
    );
    assert!(
        drawn > draws / 2,
        "most samples are drawn: {drawn} of {draws}"
    );
}

/// More than 16 lights (40: point lights, one-sided area lights facing both ways, a
/// black one): the CPU's bounded film (two own layers and a shared one) and its
/// stochastic selection, on the GPU; the image rule above.
#[test]
fn forty_lights_on_the_gpu_agree_with_the_cpu() {
    let scene = meso_render::scene::test_scenes::many_lights_scene(40);
    image_of_scene_agrees_with_the_cpu("40 lights", scene, 24, 16);
}

/// Several light samples per frame on the GPU's two light paths: three per area light
/// at MERL surfaces (each with its MIS material sample; the environment off, so the
/// area light is the image) and two selections among 40 lights; the image rule above
/// against the CPU with the same setting.
#[test]
fn light_samples_on_the_gpu_agree_with_the_cpu() {
    let mut merl = test_scene("merl_bunny.toml");
    merl.environment = None;
    merl.render.light_samples = 3;
    image_of_scene_agrees_with_the_cpu("merl_bunny.toml, 3 light samples", merl, 32, 16);
    let mut many = meso_render::scene::test_scenes::many_lights_scene(40);
    many.render.light_samples = 2;
    image_of_scene_agrees_with_the_cpu("40 lights, 2 light samples", many, 24, 16);
}

/// Light edits among 40 lights invalidate on the GPU exactly as on the CPU (a shared
/// light's colour promotes it to an own layer, a colour edit of an own light keeps
/// everything, a move restarts its layer, added and removed lights, back to 16 lights
/// and one layer each), the sample counts follow, and the edited mode's image then
/// agrees with the CPU's for the edited scene.
#[test]
fn light_edits_among_many_lights_invalidate_as_on_the_cpu() {
    use meso_render::{RenderMode, SceneEdit, run_frames};
    let mut scene = meso_render::scene::test_scenes::many_lights_scene(40);
    scene.render.sampler = meso_materials::rng::Sampler::Independent;
    let size = 24;
    let mut cpu = meso_modes::trace::SpmmMode::new(scene.clone(), size, size).expect("CPU mode");
    let mut gpu = gpu_mode(scene.clone(), size);
    run_frames(&mut cpu, 2, |_, _| {});
    run_frames(&mut gpu, 2, |_, _| {});
    let own = |m: &meso_modes::trace::SpmmMode| m.light_layers().light_targets(m.scene());
    let targets = own(&cpu);
    let shared = (0..40)
        .find(|&k| targets[k].layer == meso_render::layers::SHARED_LIGHTS)
        .expect("a shared light");
    let mut brighter = scene.lights[shared];
    brighter = brighter.with_emission(brighter.emission() * 3.0);
    let moved = match brighter {
        meso_render::scene::Light::Point {
            position,
            intensity,
        } => meso_render::scene::Light::Point {
            position: position + DVec3::new(0.1, 0.0, 0.0),
            intensity,
        },
        l => l,
    };
    let mut edits = vec![
        SceneEdit::Light {
            index: shared,
            light: brighter,
        },
        SceneEdit::Light {
            index: shared,
            light: brighter.with_emission(brighter.emission() * 0.5),
        },
        SceneEdit::Light {
            index: shared,
            light: moved,
        },
        SceneEdit::AddLight(scene.lights[9]),
        SceneEdit::RemoveLight(3),
    ];
    // Down to 16 lights: the film lays its light layers out again, one per light.
    edits.extend((0..24).map(|_| SceneEdit::RemoveLight(0)));
    for edit in edits {
        let what = format!("{edit:?}");
        let a = cpu.apply(edit.clone()).expect("CPU edit");
        let b = gpu.apply(edit).expect("GPU edit");
        assert_eq!(a, b, "{what}");
        run_frames(&mut cpu, 1, |_, _| {});
        run_frames(&mut gpu, 1, |_, _| {});
        assert_eq!(cpu.film().layers(), gpu.film_layers(), "{what}");
        assert_eq!(
            cpu.progress().min_samples,
            gpu.progress().min_samples,
            "{what}"
        );
    }
    assert_eq!(gpu.scene().lights.len(), 16);
    // Back above 16, then the image of the edited scene.
    let extra = gpu.scene().lights[0];
    gpu.apply(SceneEdit::AddLight(extra)).expect("a 17th light");
    let edited = gpu.scene().clone();
    mode_agrees_with_the_cpu("40 lights, edited", edited, size, 16, Some(gpu));
}

/// Only the clusters the scene can reach go up: a panel whose UVs cover part of its
/// texture (one cluster of two) uploads fewer basis and residual bytes than a full
/// upload and renders the same image bit for bit; a mesh edit that widens the UVs to
/// the whole texture uploads the rest and again renders as a full upload; a pack no
/// mesh carries uploads nothing.
#[test]
fn a_scene_reaching_part_of_a_pack_uploads_less_and_renders_the_same() {
    use meso_render::{Prepare, RenderMode, SceneEdit, run_frames};
    let scene = super::reach::tests::partial_panel_scene();
    let size = 24;
    let make = |scene: &meso_render::scene::Scene, all| {
        super::GpuSpmmMode::prepare_uploading(
            context().clone(),
            scene.clone(),
            (size, size),
            Prepare::quietly(),
            all,
        )
        .expect("the GPU mode renders the scene")
    };
    let (mut partial, mut full) = (make(&scene, false), make(&scene, true));
    let (p, f) = (partial.device_bytes(), full.device_bytes());
    eprintln!("partial {p:?}\nfull {f:?}");
    assert!(
        p.residual_tables < f.residual_tables && p.spmm_bases < f.spmm_bases,
        "{p:?} against {f:?}"
    );
    run_frames(&mut partial, 3, |_, _| {});
    run_frames(&mut full, 3, |_, _| {});
    assert!(
        partial.image().pixels() == full.image().pixels(),
        "the images differ"
    );
    assert_eq!(partial.overflows(), (0, 0));

    // The panel's UVs over the whole texture: the edit uploads the other cluster.
    let mut meshes = scene.meshes.clone();
    for m in meshes.iter_mut().filter(|m| m.material == 1) {
        for uv in &mut m.uvs {
            *uv = (*uv - glam::DVec2::new(0.33, 0.15)) / glam::DVec2::new(0.06, 0.1);
        }
    }
    partial
        .apply(SceneEdit::Meshes(meshes))
        .expect("a mesh edit");
    assert_eq!(partial.device_bytes().residual_tables, f.residual_tables);
    let mut reference = make(partial.scene(), true);
    run_frames(&mut partial, 3, |_, _| {});
    run_frames(&mut reference, 3, |_, _| {});
    assert!(
        partial.image().pixels() == reference.image().pixels(),
        "the images differ after the edit"
    );

    let mut bare = scene.clone();
    bare.meshes.retain(|m| m.material != 1);
    let b = make(&bare, false).device_bytes();
    assert_eq!(
        (b.spmm_bases, b.spmm_weights, b.residual_tables),
        (0, 0, 0),
        "{b:?}"
    );
}

/// A material edit whose data would pass the adapter's buffer limit is refused with
/// the limit's message (bytes and adapter), not a device failure, and leaves the
/// material and the film as they were.
#[test]
fn a_material_edit_past_the_buffer_limit_is_refused_by_size() {
    use meso_render::{EditError, RenderMode, SceneEdit, run_frames};
    let scene = super::reach::tests::partial_panel_scene();
    let mut gpu = gpu_mode(scene.clone(), 8);
    run_frames(&mut gpu, 2, |_, _| {});
    gpu.limit_buffers(gpu.data_words_bytes() + 64);
    let meso_render::scene::Material::Spmm {
        material,
        residual,
        npca,
        ..
    } = &scene.materials[1]
    else {
        panic!("the panel is a pack");
    };
    // A finer tiling reaches every cluster: more residual tables than the limit.
    let finer = meso_render::scene::Material::Spmm {
        material: material.clone(),
        uv_scale: glam::DVec2::splat(40.0),
        residual: *residual,
        npca: *npca,
    };
    let err = gpu
        .apply(SceneEdit::Material {
            index: 1,
            material: finer,
        })
        .expect_err("past the limit");
    let EditError::Size(message) = &err else {
        panic!("not a size error: {err}");
    };
    assert!(
        message.contains("byte") && message.contains(&context().adapter_name()),
        "{message}"
    );
    assert!(matches!(
        gpu.scene().materials[1],
        meso_render::scene::Material::Spmm { uv_scale, .. } if uv_scale == glam::DVec2::splat(2.0)
    ));
    assert_eq!(gpu.progress().min_samples, 2);
    run_frames(&mut gpu, 1, |_, _| {});
    assert!(gpu.failure().is_none());
    assert_eq!(gpu.progress().min_samples, 3);
}

/// `btf` tables in WGSL against `BtfTable::eval_texel` (f64 over the same values): a
/// tabulated Ward BRDF on the Bonn 81 directions held as f32, and the same with its
/// values rounded to f16 (held as f16, two to a word), on random and grazing pairs
/// (outside the sets' hull too): within 1e-4 relative plus 1e-5 of the texel's scale.
#[test]
fn btf_tables_match_the_cpu() {
    use meso_materials::btf::table::{BtfTable, Storage};
    let dirs = meso_materials::btf::directions::bonn81();
    let brdf = AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.2), ("ay", 0.4)]).expect("valid");
    let f32_btf = meso_materials::btf::Btf::from_brdf(
        &brdf,
        DVec3::new(0.8, 0.5, 0.3),
        2,
        1,
        dirs.clone(),
        dirs.clone(),
    )
    .expect("valid BTF");
    let halves: Vec<f32> = f32_btf
        .data()
        .iter()
        .enumerate()
        .map(|(i, &v)| half::f16::from_f32(v * if i % 7 == 0 { 0.5 } else { 1.0 }).to_f32())
        .collect();
    let f16_btf = meso_materials::btf::Btf::new(
        "halves".into(),
        "test".into(),
        2,
        1,
        dirs.clone(),
        dirs,
        halves,
    )
    .expect("valid BTF");
    let tables = [
        BtfTable::new(&f32_btf).expect("shadeable"),
        BtfTable::new(&f16_btf).expect("shadeable"),
    ];
    assert_eq!(tables[0].storage(), Storage::F32);
    assert_eq!(tables[1].storage(), Storage::F16);
    let pairs = direction_pairs(21, 600);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    for table in &tables {
        let record = words.push_btf(table, glam::DVec2::ONE);
        for t in 0..2u32 {
            for &(wi, wo) in &pairs {
                cases.push(Case {
                    kind: 10,
                    record,
                    wi,
                    wo,
                    texel: t,
                    residual: false,
                });
                reference.push((
                    format!("{:?} texel {t}", table.storage()),
                    wi,
                    wo,
                    table.eval_texel(t as usize, wi, wo),
                ));
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst = 0.0f64;
    for (g, (what, wi, wo, c)) in got.iter().zip(&reference) {
        for ch in 0..3 {
            assert!(g[ch].is_finite(), "{what}: {g:?}");
            let e = excess(g[ch], c[ch], 1e-4, 1e-5 * (1.0 + c.abs().max_element()));
            assert!(e <= 1.0, "{what} at wi {wi} wo {wo}: gpu {g:?}, f64 {c}");
            worst = worst.max(e);
        }
    }
    eprintln!("btf tables: worst {worst:.3} of the tolerance");
}

/// A scene with a `btf` material (the residual panel's pack replaced by a tabulated
/// anisotropic Ward table, tiled 2 x 2) on the GPU against the CPU: the image rule.
#[test]
fn a_btf_scene_on_the_gpu_agrees_with_the_cpu() {
    let mut scene = meso_render::scene::test_scenes::edit_test_scene();
    scene.materials[1] = meso_render::scene::test_scenes::tabulated_btf(
        &AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.25), ("ay", 0.5)]).expect("valid"),
        DVec3::new(0.7, 0.5, 0.3),
        glam::DVec2::splat(2.0),
    );
    image_of_scene_agrees_with_the_cpu("btf panel", scene, 24, 16);
}
