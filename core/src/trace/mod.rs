//! The progressive ray tracer of the `spmm` mode (Silva & Santos 2013, section 4) —
//! being built: so far the film that accumulates frames, the pinhole camera that
//! generates primary rays, and the BVH (obvhs) for closest-hit and occlusion queries.
//! The integrator and `meso render` follow.

pub mod bvh;
pub mod camera;
pub mod film;
pub mod integrator;

pub use bvh::{Hit, SceneBvh};
pub use camera::{PinholeCamera, Ray};
pub use film::Film;
pub use integrator::{RayCounts, Renderer};
