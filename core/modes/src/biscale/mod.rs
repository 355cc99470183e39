//! The `biscale` mode: all-frequency bi-scale radiance transfer (Sun et al. 2010, over
//! Sloan et al. 2003). Macro scale: per vertex, a transfer matrix from the cube-map
//! environment (pixel basis, `cubemap.rs`) to M local incident cells of the vertex's
//! frame (`hemisphere.rs`, `transfer.rs`), compressed losslessly by biclustering and
//! applied by Algorithm 2 (`bicluster.rs`); meso scale: the material's BTF tabulated
//! at those cells (`btf_table.rs`); per pixel a dot product (`mode.rs`). The
//! precomputation (`precompute.rs`) is cached on disk (`cache.rs`); the SH bi-scale
//! and CPCA baselines (`sh.rs`, `cpca.rs`) are computed from the same matrix for the
//! reports. The environment is the precomputed part, but for its brightest pixels,
//! which are traced per pixel like a light (`meso_render::environment::EnvironmentSplit`); lights and the ambient term
//! are traced exactly on top (`mode.rs`). With the `gpu` feature, `gpu.rs` renders
//! the same frames on a wgpu device from the same preparation.

pub mod bicluster;
pub mod btf_table;
pub mod cache;
pub mod cpca;
pub mod cubemap;
#[cfg(feature = "gpu")]
mod gpu;
#[cfg(all(test, feature = "gpu"))]
mod gpu_tests;
pub mod hemisphere;
mod mode;
pub mod precompute;
pub mod refine;
pub mod sh;
#[cfg(test)]
mod tests;
pub mod transfer;

use std::path::PathBuf;

#[cfg(feature = "gpu")]
pub use gpu::GpuBiscaleMode;
pub use mode::{BiscaleMode, TransferSource};
pub use precompute::{PrecomputeStats, Precomputed, precompute};

/// The mode's resolutions (Sun et al.: n = 32, 8 x 8 local directions, 12 x 12 views,
/// 2 x 2 rays per cube pixel).
#[derive(Clone, Debug, PartialEq)]
pub struct BiscaleSettings {
    /// Cube map side: 6 x n x n environment pixels (16 for fast previews).
    pub cube_n: u32,
    /// Local incident directions per side: M = res^2 (8 or 12).
    pub local_res: u32,
    /// Tabulated view directions per side.
    pub view_res: u32,
    /// Visibility rays per cube pixel per side (s x s rays), at most 15.
    pub rays_per_side: u32,
    /// Seed of the biclustering's random starting elements.
    pub seed: u64,
    /// At most about this many vertices added where visibility varies, so receivers'
    /// shadows have vertices to live on (`refine.rs`; 0: transfer at the scene's own
    /// vertices only).
    pub refine_vertices: usize,
    /// Share of the sphere's solid angle whose brightest environment pixels are traced
    /// per pixel instead of carried by the transfer (`meso_render::environment::EnvironmentSplit`; 0: the transfer
    /// carries the whole map, as in Sun et al.). Not part of the precomputation.
    pub traced_share: f64,
    /// Where precomputations are cached (`None`: never read or written).
    pub cache_dir: Option<PathBuf>,
}

/// Vertices the refinement may add by default: a floor's shadow under an object
/// (docs/rendering.md, "Receivers' shadows").
pub const DEFAULT_REFINE_VERTICES: usize = 8_192;
/// The most it may add (each vertex costs 6 n^2 s^2 visibility rays).
pub const MAX_REFINE_VERTICES: usize = 1 << 20;

impl Default for BiscaleSettings {
    fn default() -> Self {
        Self {
            cube_n: 32,
            local_res: 8,
            view_res: 12,
            rays_per_side: 2,
            seed: 1,
            refine_vertices: DEFAULT_REFINE_VERTICES,
            traced_share: meso_render::environment::DEFAULT_TRACED_SHARE,
            cache_dir: default_cache_dir(),
        }
    }
}

impl BiscaleSettings {
    /// Why these settings cannot be used.
    pub fn problem(&self) -> Option<String> {
        if !(1..=256).contains(&self.cube_n) {
            Some(format!("cube map side {} is outside 1..=256", self.cube_n))
        } else if !(1..=32).contains(&self.local_res) {
            Some(format!(
                "local directions per side {} is outside 1..=32",
                self.local_res
            ))
        } else if !(1..=64).contains(&self.view_res) {
            Some(format!(
                "view directions per side {} is outside 1..=64",
                self.view_res
            ))
        } else if !(1..=15).contains(&self.rays_per_side) {
            Some(format!(
                "rays per side {} is outside 1..=15",
                self.rays_per_side
            ))
        } else if !(0.0..=1.0).contains(&self.traced_share) {
            Some(format!(
                "traced share {} of the sphere is outside 0..=1",
                self.traced_share
            ))
        } else if self.refine_vertices > MAX_REFINE_VERTICES {
            Some(format!(
                "refinement vertices {} is above {MAX_REFINE_VERTICES}",
                self.refine_vertices
            ))
        } else {
            None
        }
    }
}

/// `MESO_CACHE_DIR`, else `$XDG_CACHE_HOME/meso`, else `$HOME/.cache/meso`; none in
/// unit tests (they must not share state through the disk).
pub fn default_cache_dir() -> Option<PathBuf> {
    if cfg!(test) {
        return None;
    }
    if let Some(d) = std::env::var_os("MESO_CACHE_DIR") {
        return Some(PathBuf::from(d));
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
        return Some(PathBuf::from(d).join("meso"));
    }
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache").join("meso"))
}
