//! Render modes (DESIGN.md, "The three render modes"): each is a type behind one small
//! trait — made for a scene, renders one progressive frame into its film, says what an
//! edit invalidates. `meso render`, the convergence report and the app's viewport all
//! drive modes through this trait, so nothing is rendered two different ways.
//! Only the `spmm` mode (`trace`) exists today; `biscale` and `adaptive` will join.

pub mod convergence;
pub mod edit;
pub mod film;

use std::time::Duration;

pub use edit::{EditError, Invalidation, SceneEdit};
pub use film::Film;

use crate::image::Image;
use crate::scene::Scene;
use crate::trace::RayCounts;

/// The modes that exist.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModeKind {
    /// Progressive ray tracing of SPMM and analytic materials (Silva & Santos 2013).
    Spmm,
}

impl ModeKind {
    pub const ALL: [ModeKind; 1] = [ModeKind::Spmm];

    pub fn name(self) -> &'static str {
        match self {
            ModeKind::Spmm => "spmm",
        }
    }

    /// Makes the mode for `scene` at `width` x `height`.
    pub fn create(
        self,
        scene: Scene,
        width: u32,
        height: u32,
    ) -> Result<Box<dyn RenderMode>, EditError> {
        match self {
            ModeKind::Spmm => Ok(Box::new(crate::trace::SpmmMode::new(scene, width, height)?)),
        }
    }
}

/// What one call of `render_frame` did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    pub rays: RayCounts,
    pub seconds: f64,
    /// Non-finite samples dropped in this frame.
    pub dropped: u64,
}

/// Where the accumulation stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Progress {
    /// Frames rendered since the last full restart.
    pub frames: u32,
    /// The fewest samples of any pixel in any active layer.
    pub min_samples: u32,
    /// Non-finite samples dropped since the mode was made.
    pub dropped: u64,
    pub width: u32,
    pub height: u32,
}

/// A progressive render mode.
pub trait RenderMode: Send {
    fn kind(&self) -> ModeKind;
    /// The scene as edited so far.
    fn scene(&self) -> &Scene;
    /// Adds one frame (`samples_per_frame` samples per pixel) to the film.
    fn render_frame(&mut self) -> FrameStats;
    /// The image accumulated so far, with the current emissions.
    fn image(&self) -> Image;
    fn progress(&self) -> Progress;
    /// Applies an edit and restarts only what it invalidates.
    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError>;
    /// Samples per pixel per frame (at least 1).
    fn set_samples_per_frame(&mut self, samples: u32);
    /// The BVH's last build or refit.
    fn geometry_update(&self) -> GeometryUpdate;
}

/// How the geometry was last made ready for tracing, and how long it took.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeometryUpdate {
    pub refit: bool,
    pub time: Duration,
    pub triangles: usize,
}

/// Totals of a run of frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RunStats {
    pub frames: u32,
    pub rays: RayCounts,
    /// Time spent in `render_frame`.
    pub seconds: f64,
    pub dropped: u64,
}

/// Renders `frames` more frames, calling `on_frame(done, stats)` after each (for
/// progress bars).
pub fn run_frames(
    mode: &mut dyn RenderMode,
    frames: u32,
    mut on_frame: impl FnMut(u32, &FrameStats),
) -> RunStats {
    let mut total = RunStats::default();
    for f in 0..frames {
        let s = mode.render_frame();
        total.frames += 1;
        total.rays = total.rays + s.rays;
        total.seconds += s.seconds;
        total.dropped += s.dropped;
        on_frame(f + 1, &s);
    }
    total
}
