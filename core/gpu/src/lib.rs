//! The `spmm` mode on the GPU (wgpu compute; WGSL in the workspace's `shaders/`):
//! the device and its adapter, its own or one shared with the studio's window
//! (`context.rs`), the WGSL sources and how they are put
//! together (`shaders.rs`), the words a shader reads (`data.rs`: BRDFs, SPMM packs,
//! materials; `reach.rs`: the clusters of each pack the scene can reach, the only
//! ones uploaded), the scene's geometry on the device (`geometry.rs`: the obvhs CWBVH's
//! nodes as they are, the leaf-ordered triangles and their shading data), the
//! environment map with its sampling tables and the background image
//! (`environment.rs`), one compute dispatch with its buffers (`kernel.rs`), the film
//! kept on the device (`film.rs`), the adaptive mode's plan and up-sampling (`adaptive.rs`) and its bandwidth pass
//! (`adaptive_pass.rs`), a resolved image and the texture a window shows it
//! in (`display.rs`), the viewport denoiser on the device (`denoise.rs`), and the mode
//! itself (`mode.rs`). The CPU's
//! `trace::SpmmMode` is the reference every part here is tested against.

mod adaptive;
mod adaptive_pass;
mod biscale;
mod context;
mod data;
mod denoise;
mod display;
mod environment;
mod film;
mod geometry;
mod kernel;
mod mode;
mod reach;
mod shaders;

pub use adaptive::{AdaptiveKnobs, PassPixel};
pub use adaptive_pass::{PassRules, PassTables};
pub use biscale::{BiscaleBlock, BiscaleBytes, BiscaleInputs, BiscaleTable, LEAF_BIT, SpmmRows};
pub use context::{GpuContext, GpuError, Sharing, hardware_adapter, is_hardware};
pub use display::{DeviceImage, DisplayTexture};
pub use mode::{DeviceBytes, GpuSpmmMode};
pub use reach::{Reach, reachable_clusters};

#[cfg(test)]
mod film_tests;
#[cfg(test)]
mod tests;
