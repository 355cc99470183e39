//! The `spmm` render mode on the CPU: progressive ray tracing of SPMM packs, analytic
//! BRDFs, MERL tables and mirrors (Silva & Santos 2013, section 4) under point and area lights,
//! ambient occlusion and environment lighting. One file per concept: the integrator
//! (the mode itself), light sampling, environment sampling, the denoiser's guides;
//! materials are shaded by the shading core (`meso_render::shading`).

mod environment;
mod guides;
mod integrator;

mod lights;

use integrator::Path;
pub use integrator::SpmmMode;
pub use meso_render::shading::PackSampling;

#[cfg(test)]
mod btf_tests;
#[cfg(test)]
mod edit_tests;
#[cfg(test)]
mod environment_tests;
#[cfg(test)]
mod hard_case_tests;
#[cfg(test)]
mod many_lights_tests;
#[cfg(test)]
mod merl_tests;
#[cfg(test)]
mod paint_tests;
#[cfg(test)]
mod tests;
