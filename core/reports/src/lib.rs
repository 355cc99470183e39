//! The reports above the registry: what measures a mode's speed against its error
//! (`convergence`, with the adaptive mode's study in `adaptive` and the biscale
//! precomputation's in `biscale`), a fitted pack against its BTF (`fidelity`), and
//! scripted regression renders against goldens (`regress`). They drive modes only
//! through `meso_modes`' registry and the `RenderMode` trait.

pub mod adaptive;
pub mod biscale;
pub mod convergence;
pub mod fidelity;
pub mod regress;
