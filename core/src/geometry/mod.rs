//! Geometry every render mode and the editor share: the scene's triangles in a BVH
//! (closest-hit and occlusion queries, refitting), the pinhole camera's primary rays,
//! picking (what surface, texel and cluster lie under an image position) and the
//! weight brush built on it (which texels a dab covers).
//! Nothing here knows about films, layers or modes.

pub mod brush;
pub mod bvh;
pub mod camera;
pub mod pick;

pub use brush::{Brush, BrushUnits};
pub use bvh::{Hit, SceneBvh};
pub use camera::{PinholeCamera, Ray};
pub use pick::{Pick, pick};
