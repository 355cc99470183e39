//! The `spmm` render mode's progressive ray tracer (Silva & Santos 2013, section 4):
//! the BVH (obvhs) for closest-hit and occlusion queries with refitting, the pinhole
//! camera for primary rays, and the integrator (`SpmmMode`, a `render::RenderMode`).

pub mod bvh;
pub mod camera;
pub mod integrator;
pub mod pick;

pub use bvh::{Hit, SceneBvh};
pub use camera::{PinholeCamera, Ray};
pub use integrator::{RayCounts, SpmmMode};
pub use pick::{Pick, pick};

#[cfg(test)]
mod edit_tests;
/// A small scene with a Lambertian floor, an SPMM panel with a residual, an area and
/// a point light and AO, for tests of modes and reports.
#[cfg(test)]
pub(crate) use edit_tests::scene as edit_test_scene;
