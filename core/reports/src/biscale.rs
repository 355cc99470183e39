//! The precomputation report (`meso precompute --json`, docs/cli.md): the matrix's
//! size, the biclustering's FLOP ratio and bytes, its losslessness on a random
//! lighting vector, and the SH and CPCA baselines built from the same matrix, each
//! with its bytes, build time, product time and error against the exact product.

use std::time::Instant;

use serde::Serialize;

use meso_materials::rng::SampleStream;
use meso_modes::biscale::BiscaleSettings;
use meso_modes::biscale::cpca::Cpca;
use meso_modes::biscale::cubemap::CubeLayout;
use meso_modes::biscale::hemisphere::HemisphereGrid;
use meso_modes::biscale::precompute::{PrecomputeStats, Precomputed, precompute};
use meso_modes::biscale::sh::ShTransfer;
use meso_render::geometry::SceneBvh;
use meso_render::scene::Scene;
use meso_render::{Cancelled, Prepare};

/// SH order of the baseline (Sloan et al.: 25 coefficients).
pub const SH_ORDER: usize = 5;
/// CPCA size (Sun et al.'s comparison: 32 clusters x 8 components).
pub const CPCA_CLUSTERS: usize = 32;
pub const CPCA_COMPONENTS: usize = 8;

#[derive(Clone, Debug, Serialize)]
pub struct Baseline {
    pub bytes: u64,
    pub build_seconds: f64,
    /// One product with the scene's lighting.
    pub apply_ms: f64,
    pub flops: u64,
    /// RMS of (approximate - exact) L* over all entries, relative to the RMS of exact L*.
    pub relative_rms_error: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct PrecomputeReport {
    pub seconds: f64,
    pub bvh_seconds: f64,
    pub vertices: usize,
    pub local_dirs: usize,
    pub env_pixels: usize,
    pub dense_nonzeros: usize,
    pub biclusters: usize,
    pub flop_ratio: f64,
    pub flops_dense: u64,
    pub flops_biclustered: u64,
    /// The sparse matrix as stored uncompressed: a u32 column and an f32 value per
    /// nonzero, a u32 offset per row.
    pub bytes_dense: u64,
    /// The full rows x columns matrix of f32.
    pub bytes_full: u64,
    pub bytes_biclustered: u64,
    pub bytes_cpca: u64,
    pub bytes_sh: u64,
    /// Largest |biclustered - dense| entry of L* for a random lighting vector in
    /// [0, 1)^3 per pixel, and that relative to the largest |dense| entry.
    pub max_abs_error: f64,
    pub max_rel_error: f64,
    pub dense_apply_ms: f64,
    pub biclustered_apply_ms: f64,
    pub stages: PrecomputeStats,
    pub sh: Option<Baseline>,
    pub cpca: Option<Baseline>,
    pub cube_n: u32,
    pub local_res: u32,
    pub rays_per_side: u32,
}

fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let start = Instant::now();
    let v = f();
    (v, start.elapsed().as_secs_f64())
}

fn relative_rms(exact: &[[f64; 3]], got: &[[f32; 3]]) -> f64 {
    let (mut e2, mut x2) = (0.0, 0.0);
    for (x, g) in exact.iter().zip(got) {
        for c in 0..3 {
            e2 += (x[c] - g[c] as f64).powi(2);
            x2 += x[c] * x[c];
        }
    }
    (e2 / x2.max(1e-300)).sqrt()
}

/// Runs the precomputation (never from a cache) and, with `baselines`, the SH and
/// CPCA baselines; stages are reported through `prepare`.
pub fn precompute_report(
    scene: &Scene,
    settings: &BiscaleSettings,
    baselines: bool,
    prepare: &Prepare,
) -> Result<(Precomputed, PrecomputeReport), Cancelled> {
    let start = Instant::now();
    let (bvh, bvh_seconds) = timed(|| SceneBvh::build(&scene.meshes));
    let uncached = BiscaleSettings {
        cache_dir: None,
        ..settings.clone()
    };
    let pre = precompute(&scene.meshes, &bvh, &uncached, prepare)?;
    let cube = CubeLayout::new(settings.cube_n);
    let local = HemisphereGrid::new(settings.local_res);
    let t = &pre.transfer;
    // Losslessness on a random lighting vector.
    let rng = SampleStream::new(&[settings.seed, 0x4c]);
    let random: Vec<[f32; 3]> = (0..cube.len() as u64)
        .map(|k| {
            [
                rng.at(3 * k) as f32,
                rng.at(3 * k + 1) as f32,
                rng.at(3 * k + 2) as f32,
            ]
        })
        .collect();
    let exact_random = t.apply_f64(&random);
    let bic_random = pre.biclusters.apply(&random);
    let mut max_abs: f64 = 0.0;
    let mut max_val: f64 = 0.0;
    for (x, g) in exact_random.iter().zip(&bic_random) {
        for c in 0..3 {
            max_abs = max_abs.max((x[c] - g[c] as f64).abs());
            max_val = max_val.max(x[c].abs());
        }
    }
    let light = scene
        .environment
        .as_ref()
        .map_or_else(|| random.clone(), |e| cube.lighting(e));
    let exact = t.apply_f64(&light);
    let (_, dense_s) = timed(|| t.apply(&light));
    let (_, bic_s) = timed(|| pre.biclusters.apply(&light));
    let (sh, cpca) = if baselines {
        prepare.report("baselines", 0.0)?;
        let (sh, sh_build) = timed(|| ShTransfer::build(t, &pre.frames, cube, local, SH_ORDER));
        let (sh_l, sh_apply) = timed(|| sh.apply(&light));
        prepare.report("baselines", 0.3)?;
        let (cp, cp_build) =
            timed(|| Cpca::build(t, CPCA_CLUSTERS, CPCA_COMPONENTS, settings.seed));
        let (cp_l, cp_apply) = timed(|| cp.apply(&light));
        prepare.report("baselines", 1.0)?;
        (
            Some(Baseline {
                bytes: sh.bytes(),
                build_seconds: sh_build,
                apply_ms: sh_apply * 1e3,
                flops: sh.flops(),
                relative_rms_error: relative_rms(&exact, &sh_l),
            }),
            Some(Baseline {
                bytes: cp.bytes(),
                build_seconds: cp_build,
                apply_ms: cp_apply * 1e3,
                flops: cp.flops(),
                relative_rms_error: relative_rms(&exact, &cp_l),
            }),
        )
    } else {
        (None, None)
    };
    let report = PrecomputeReport {
        seconds: start.elapsed().as_secs_f64(),
        bvh_seconds,
        vertices: pre.frames.len(),
        local_dirs: local.len(),
        env_pixels: cube.len(),
        dense_nonzeros: t.nonzeros(),
        biclusters: pre.biclusters.len(),
        flop_ratio: pre.flop_ratio(),
        flops_dense: t.dense_flops(),
        flops_biclustered: pre.biclusters.flops(),
        bytes_dense: 8 * t.nonzeros() as u64 + 4 * (t.rows as u64 + 1),
        bytes_full: 4 * t.rows as u64 * t.cols as u64,
        bytes_biclustered: pre.biclusters.bytes(),
        bytes_cpca: cpca.as_ref().map_or(0, |b| b.bytes),
        bytes_sh: sh.as_ref().map_or(0, |b| b.bytes),
        max_abs_error: max_abs,
        max_rel_error: max_abs / max_val.max(1e-300),
        dense_apply_ms: dense_s * 1e3,
        biclustered_apply_ms: bic_s * 1e3,
        stages: pre.stats.clone(),
        sh,
        cpca,
        cube_n: settings.cube_n,
        local_res: settings.local_res,
        rays_per_side: settings.rays_per_side,
    };
    Ok((pre, report))
}
