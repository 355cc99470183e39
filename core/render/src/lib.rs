//! The seam every render mode plugs into (docs/rendering.md): the
//! `RenderMode` trait (prepared for a scene with progress and cancel, renders one
//! progressive frame into its film, says what an edit invalidates; `mode.rs`), the film and its
//! layers, edits, `Unsupported` (what a mode cannot render, by name) and mode-neutral
//! statistics. It knows no mode: the registry above the modes makes them by kind
//! (`modes`). `meso render`, the reports and the studio drive modes through it.

pub mod denoise;
pub mod edit;
pub mod environment;
pub mod film;
pub mod geometry;
pub mod layers;
pub mod light_selection;
mod mode;
mod mode_kind;
pub mod preview;
pub mod progressive;
pub mod reach;
pub mod scene;
pub mod shading;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

pub use denoise::{Denoiser, Guides};
pub use edit::{EditError, Invalidation, SceneEdit};
pub use film::{Film, FilmTooLarge};
pub use mode::{
    Diagnostic, Diagnostics, ImageOnDevice, MaterialBytes, Pass, RenderMode, RenderModeExt,
    RunStats, run_frames,
};

use crate::geometry::SceneBvh;
pub use crate::mode_kind::{Device, ModeKind};
use crate::scene::TriangleMesh;

/// Rays traced, by kind (zero for modes that trace none of a kind).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RayCounts {
    pub primary: u64,
    pub shadow: u64,
    pub ambient: u64,
    /// Rays towards the environment (its samples and the BRDF's samples of it).
    pub environment: u64,
    pub specular: u64,
}

impl std::ops::Add for RayCounts {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            primary: self.primary + o.primary,
            shadow: self.shadow + o.shadow,
            ambient: self.ambient + o.ambient,
            environment: self.environment + o.environment,
            specular: self.specular + o.specular,
        }
    }
}

impl RayCounts {
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.ambient + self.environment + self.specular
    }
}

/// Mode-neutral counters of some amount of rendering.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Counters {
    /// Pixel samples added to the film.
    pub samples: u64,
    /// Surface points whose material was evaluated.
    pub shading_points: u64,
    /// Rays traced, where the mode traces rays.
    pub rays: RayCounts,
}

impl std::ops::Add for Counters {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            samples: self.samples + o.samples,
            shading_points: self.shading_points + o.shading_points,
            rays: self.rays + o.rays,
        }
    }
}

/// What one call of `render_frame` did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    pub counters: Counters,
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
    /// Bytes the film's buffers hold (`Film::bytes`; 0 for modes without one).
    pub film_bytes: u64,
    /// Whether the image has a value at every pixel: each pixel's own samples
    /// (`min_samples > 0`), or (the adaptive mode) a value up-sampled from its
    /// neighbours'. The render thread then shows an edit that keeps samples at once
    /// and lets commands stop frames.
    pub shows_every_pixel: bool,
}

/// How a mode's preparation went: each stage and its time.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PreparationReport {
    pub stages: Vec<PreparationStage>,
}

#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PreparationStage {
    pub name: String,
    pub seconds: f64,
}

impl PreparationReport {
    /// Records stage `name`, which took `seconds`.
    pub fn record(&mut self, name: &str, seconds: f64) {
        self.stages.push(PreparationStage {
            name: name.into(),
            seconds,
        });
    }

    /// Records stage `name`, begun at `start` and ended now.
    pub fn record_since(&mut self, name: &str, start: Instant) {
        self.record(name, start.elapsed().as_secs_f64());
    }

    pub fn seconds(&self, stage: &str) -> Option<f64> {
        self.stages
            .iter()
            .find(|s| s.name == stage)
            .map(|s| s.seconds)
    }
    pub fn total_seconds(&self) -> f64 {
        self.stages.iter().map(|s| s.seconds).sum()
    }
}

/// The preparation was cancelled by its caller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the preparation was cancelled")]
pub struct Cancelled;

/// A long preparation's link to its caller: progress reports and a cancel flag that
/// the mode checks between steps.
#[derive(Clone, Copy)]
pub struct Prepare<'a> {
    on_progress: &'a (dyn Fn(&str, f32) + Sync),
    cancel: &'a AtomicBool,
}

static NEVER_CANCELLED: AtomicBool = AtomicBool::new(false);

impl<'a> Prepare<'a> {
    pub fn new(on_progress: &'a (dyn Fn(&str, f32) + Sync), cancel: &'a AtomicBool) -> Self {
        Self {
            on_progress,
            cancel,
        }
    }

    /// No progress shown, never cancelled (tests, benchmarks, quick scripts).
    pub fn quietly() -> Prepare<'static> {
        Prepare {
            on_progress: &|_, _| {},
            cancel: &NEVER_CANCELLED,
        }
    }

    /// The scene's BVH, built as the stage `bvh` of `report` (every mode's first).
    pub fn bvh(
        &self,
        meshes: &[TriangleMesh],
        report: &mut PreparationReport,
    ) -> Result<SceneBvh, Cancelled> {
        self.report("bvh", 0.0)?;
        let start = Instant::now();
        let bvh = SceneBvh::build(meshes);
        report.record_since("bvh", start);
        Ok(bvh)
    }

    /// Reports that `fraction` (0..=1) of `stage` is done; `Err` once cancelled.
    pub fn report(&self, stage: &str, fraction: f32) -> Result<(), Cancelled> {
        if self.cancel.load(Ordering::Relaxed) {
            return Err(Cancelled);
        }
        (self.on_progress)(stage, fraction.clamp(0.0, 1.0));
        Ok(())
    }
}

/// What a mode cannot render in a scene, each by name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Unrenderable {
    Material {
        index: usize,
        name: String,
        /// The material's kind in scene files (`merl`, `mirror`, ...).
        kind: &'static str,
    },
    Light {
        index: usize,
        kind: &'static str,
    },
    Ambient,
}

impl std::fmt::Display for Unrenderable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unrenderable::Material { name, kind, .. } => write!(f, "material `{name}` ({kind})"),
            Unrenderable::Light { index, kind } => write!(f, "light[{index}] ({kind})"),
            Unrenderable::Ambient => write!(f, "the [ambient] term"),
        }
    }
}

/// A scene a mode cannot render: every part at fault, so a caller can name them all
/// or offer to render without the lights among them.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the {} mode ({}) cannot render {}", .mode.name(), .device.name(), list(.parts))]
pub struct Unsupported {
    pub mode: ModeKind,
    pub device: Device,
    pub parts: Vec<Unrenderable>,
}

fn list(parts: &[Unrenderable]) -> String {
    parts
        .iter()
        .map(|p| p.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

impl Unsupported {
    /// `Ok` if nothing is at fault.
    pub fn check(mode: ModeKind, device: Device, parts: Vec<Unrenderable>) -> Result<(), Self> {
        if parts.is_empty() {
            Ok(())
        } else {
            Err(Self {
                mode,
                device,
                parts,
            })
        }
    }

    /// True if only lights or the ambient term are at fault: the scene renders in
    /// this mode with them left out.
    pub fn only_lights(&self) -> bool {
        self.parts
            .iter()
            .all(|p| matches!(p, Unrenderable::Light { .. } | Unrenderable::Ambient))
    }
}

/// Why a mode could not be made for a scene.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ModeError {
    #[error("the {} mode on the {} is not built yet", .mode.name(), .device.name())]
    NotBuilt { mode: ModeKind, device: Device },
    #[error(transparent)]
    Unsupported(#[from] Unsupported),
    #[error("{0}")]
    Size(String),
    /// The film would not fit in memory (refused before it is allocated).
    #[error(transparent)]
    TooLarge(#[from] FilmTooLarge),
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
    /// No device to run the mode on (e.g. no GPU adapter), in one line.
    #[error("{0}")]
    NoDevice(String),
    /// The device failed while the mode ran (a GPU lost or reset), in one line: the
    /// mode renders nothing more; its film keeps the samples from before.
    #[error("{0}")]
    DeviceFailed(String),
}
