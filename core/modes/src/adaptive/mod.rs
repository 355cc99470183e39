//! The `adaptive` mode (Bagher, Soler, Subr, Belcour, Holzschuch 2013, "Interactive
//! rendering of acquired materials on dynamic geometry using frequency analysis"):
//! measured (MERL) and analytic BRDFs under environment and area lighting, with per-pixel
//! bandwidth and variance predicted by frequency analysis deciding where to shade and
//! how many samples to take. `wavelet` (eq. 7, the 95th percentile), `bandwidth`
//! (materials, environment, area lights), `operators` (Fig. 4, eq. 3-6, 9-11),
//! `gbuffer`, `upsample` (section 3.2), `preconvolved` (section 2.5), `mode` (the
//! `RenderMode`; with the `gpu` feature `mode/gpu.rs`, its frames on a wgpu device). No multi-sample anti-aliasing levels, no textures.

pub mod allocation;
pub mod bandwidth;
pub mod gbuffer;
pub mod mode;
pub mod operators;
pub mod overlay;
pub mod preconvolved;
pub mod upsample;
pub mod wavelet;

#[cfg(all(test, feature = "gpu"))]
mod gpu_tests;
#[cfg(test)]
mod tests;

#[cfg(feature = "gpu")]
pub use mode::GpuAdaptiveMode;
pub use mode::{AdaptiveMode, AdaptiveOptions, Buffers, Plan};
