//! The progressive ray tracer of the `spmm` mode (Silva & Santos 2013, section 4) —
//! being built: so far the film that accumulates frames and the pinhole camera that
//! generates primary rays. The BVH, the integrator and `meso render` follow.

pub mod camera;
pub mod film;

pub use camera::{PinholeCamera, Ray};
pub use film::Film;
