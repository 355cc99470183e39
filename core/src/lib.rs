//! Meso's core library: everything that works without a window.
//!
//! Modules depend downwards only: regression runs (`regress`) on the registry, the
//! registry (`modes`) on the modes (`trace`), modes
//! on the seam (`render`), geometry, environment and materials, materials on the BRDF
//! dictionary, everything on `rng`, `atomic` and `image`. `docs/ARCHITECTURE.md`
//! is the map; the `meso` binary (`src/bin/meso`) and the `meso-studio` app use this
//! crate through its public API only.

pub mod adaptive;
pub mod atomic;
pub mod biscale;
pub mod brdf;
pub mod btf;
pub mod container;
pub mod environment;
pub mod fit;
pub mod geometry;
pub mod gpu;
pub mod image;
pub mod merl;
pub mod metrics;
pub mod modes;
pub mod regress;
pub mod render;
pub mod rng;
pub mod scene;
pub mod spmm;
pub mod trace;
