//! The biscale precomputation, stage by stage (visibility, binning, biclustering),
//! with progress and cancel, and the disk cache in front of it: a cache whose key
//! matches and that validates is used; a stale or corrupt one is rebuilt (and
//! overwritten), never trusted.

use std::time::Instant;

use serde::Serialize;

use super::BiscaleSettings;
use super::bicluster::{self, Biclustering, LevelMatrix};
use super::cache;
use super::cubemap::CubeLayout;
use super::hemisphere::HemisphereGrid;
use super::refine::{self, Refinement};
use super::transfer::{self, TransferMatrix, VertexFrames};
use meso_materials::hash::Fnv1a;
use meso_render::geometry::SceneBvh;
use meso_render::scene::TriangleMesh;
use meso_render::{Cancelled, Prepare};

/// What the precomputation produced.
#[derive(Clone, Debug)]
pub struct Precomputed {
    /// Where transfer is sampled: the scene's triangles refined where visibility
    /// varies; `frames` are its vertices'.
    pub refinement: Refinement,
    pub frames: VertexFrames,
    pub transfer: TransferMatrix,
    pub biclusters: Biclustering,
    pub key: u64,
    pub stats: PrecomputeStats,
}

/// Times and sizes of one precomputation (or cache load).
#[derive(Clone, Debug, Default, Serialize)]
pub struct PrecomputeStats {
    /// The refinement: its time and the vertices it added (the transfer's rows are
    /// M per vertex, the scene's and these).
    pub refine_seconds: f64,
    pub refined_vertices: usize,
    pub visibility_seconds: f64,
    pub binning_seconds: f64,
    pub biclustering_seconds: f64,
    pub cache_seconds: f64,
    pub from_cache: bool,
    /// Why an existing cache was not used, when one was found but rejected.
    pub cache_rejected: Option<String>,
    /// Why the cache could not be written, when it could not.
    pub cache_write_error: Option<String>,
    pub cache_path: Option<String>,
}

impl Precomputed {
    /// Biclustered / dense multiply-adds per lighting change.
    pub fn flop_ratio(&self) -> f64 {
        self.biclusters.flops() as f64 / self.transfer.dense_flops().max(1) as f64
    }
}

/// The cache key: every input the matrices depend on (world-space meshes, so their
/// transform is included; the resolutions; the seed; the format version).
pub fn cache_key(meshes: &[TriangleMesh], s: &BiscaleSettings) -> u64 {
    let mut h = Fnv1a::default();
    h.word(cache::VERSION.len() as u64);
    h.bytes(cache::VERSION.as_bytes());
    for v in [s.cube_n, s.local_res, s.rays_per_side] {
        h.word(u64::from(v));
    }
    h.word(s.seed);
    for m in meshes {
        h.word(m.positions.len() as u64);
        for p in m.positions.iter().chain(&m.normals) {
            for c in p.to_array() {
                h.word(c.to_bits());
            }
        }
        for uv in &m.uvs {
            h.word(uv.x.to_bits());
            h.word(uv.y.to_bits());
        }
        for t in &m.indices {
            for i in t {
                h.word(u64::from(*i));
            }
        }
    }
    h.finish()
}

/// Runs (or loads) the precomputation for `meshes` with `bvh` built from them: the
/// refinement (always run: it is cheap and deterministic, and the cache is keyed by
/// its result), then the transfer at the refined vertices and its biclusters.
pub fn precompute(
    meshes: &[TriangleMesh],
    bvh: &SceneBvh,
    settings: &BiscaleSettings,
    prepare: &Prepare,
) -> Result<Precomputed, Cancelled> {
    let mut stats = PrecomputeStats::default();
    prepare.report("refinement", 0.0)?;
    let start = Instant::now();
    let refinement = refine::refine(meshes, bvh, settings.refine_vertices);
    stats.refine_seconds = start.elapsed().as_secs_f64();
    stats.refined_vertices = refinement.added_vertices;
    let key = cache_key(&refinement.meshes, settings);
    let frames = VertexFrames::of(&refinement.meshes);
    let path = settings.cache_dir.as_ref().map(|d| cache::path_in(d, key));
    if let Some(path) = &path {
        stats.cache_path = Some(path.display().to_string());
        if path.exists() {
            let start = Instant::now();
            match cache::read(path, key, settings, frames.len()) {
                Ok((transfer, biclusters)) => {
                    stats.from_cache = true;
                    stats.cache_seconds = start.elapsed().as_secs_f64();
                    return Ok(Precomputed {
                        refinement,
                        frames,
                        transfer,
                        biclusters,
                        key,
                        stats,
                    });
                }
                Err(e) => stats.cache_rejected = Some(e.to_string()),
            }
        }
    }
    let cube = CubeLayout::new(settings.cube_n);
    let local = HemisphereGrid::new(settings.local_res);
    let start = Instant::now();
    let seen = transfer::visibility(&frames, bvh, cube, settings.rays_per_side, prepare)?;
    stats.visibility_seconds = start.elapsed().as_secs_f64();
    prepare.report("binning", 0.0)?;
    let start = Instant::now();
    let t = transfer::bin(&frames, &seen, cube, local, settings.rays_per_side);
    drop(seen);
    stats.binning_seconds = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let levels = LevelMatrix::from_transfer(&t);
    let found = bicluster::bicluster(&levels, settings.seed, prepare)?;
    let biclusters = bicluster::layout(&levels, &found);
    stats.biclustering_seconds = start.elapsed().as_secs_f64();
    if let Some(path) = &path {
        let start = Instant::now();
        if let Err(e) = cache::write(path, key, settings, &t, &biclusters) {
            stats.cache_write_error = Some(e.to_string());
        }
        stats.cache_seconds = start.elapsed().as_secs_f64();
    }
    Ok(Precomputed {
        refinement,
        frames,
        transfer: t,
        biclusters,
        key,
        stats,
    })
}
