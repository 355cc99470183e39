//! The `RenderMode` trait every mode implements, CPU or GPU: what it renders
//! (`Pass`), what it shows, how it takes edits, and what it reports besides its image
//! (`Diagnostics`, one typed list, so a diagnostic one mode has adds no method to
//! every mode). `RenderModeExt` holds the conveniences built on it.

use std::sync::Arc;

use meso_materials::image::Image;

use crate::scene::Scene;
use crate::{
    Counters, Denoiser, Device, EditError, FrameStats, Guides, Invalidation, ModeError, ModeKind,
    PreparationReport, Progress, SceneEdit,
};

/// What `RenderMode::render` renders, and what `RenderMode::guides` describes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pass {
    /// One progressive frame: `samples_per_frame` samples at every pixel.
    Frame,
    /// While no pixel has a sample yet (after a camera, resize or mesh edit, or at the
    /// start): the next frame's samples of one pixel per `stride` x `stride` block
    /// (`preview::grid_pixels`). The frame then completes the other pixels, so the
    /// film is an uninterrupted frame's. The viewport shows `preview::spread` of the
    /// image meanwhile.
    Preview { stride: u32 },
}

/// A frame's image left on a GPU mode's device, one frame's and unchanged by later
/// ones: a window that draws with that device shows it from there (the GPU module's
/// `DisplayTexture`), and the host reads it back only when it asks (`read`).
pub trait ImageOnDevice: Send + Sync + std::fmt::Debug {
    fn size(&self) -> (u32, u32);
    /// The image on the host: read back the first time it is asked for.
    fn read(&self) -> Result<Arc<Image>, ModeError>;
    /// Waits until the device has made the image (what a window's frame waits for
    /// before it shows it), without reading it back: where benches stop the clock.
    fn wait(&self) -> Result<(), ModeError>;
    /// The concrete image, for the module that shows it.
    fn as_any(&self) -> &dyn std::any::Any;
}

/// A progressive render mode.
pub trait RenderMode: Send {
    fn kind(&self) -> ModeKind;
    fn device(&self) -> Device;
    /// The scene as edited so far.
    fn scene(&self) -> &Scene;
    /// Renders `pass` into the film. Given `stop`, asks it between parts of a frame
    /// (tiles of rows) and returns early, unfinished, once it says yes: the next call
    /// finishes that frame, so an edit need not wait for a whole frame and the samples
    /// are those an uninterrupted frame would take (modes that cannot stop mid-frame
    /// render it whole; without `stop` a frame is one parallel pass). `Pass::Frame`
    /// always renders; `Pass::Preview` returns `None`, and changes nothing, when a
    /// frame is under way, when every pixel already shows (`Progress::
    /// shows_every_pixel`), or when the mode does not preview.
    fn render(&mut self, pass: Pass, stop: Option<&mut dyn FnMut() -> bool>) -> Option<FrameStats>;
    /// What each pixel's centre ray first sees, for the viewport denoiser
    /// (`denoise`): of every pixel (`Pass::Frame`), or of the pixels a preview renders
    /// as an image of one pixel per block (`preview::grid_size`). `None` where the mode
    /// has no such pass (its image is shown as is).
    fn guides(&self, pass: Pass) -> Option<Guides> {
        let _ = pass;
        None
    }
    /// The image accumulated so far, with the current emissions.
    fn image(&self) -> Image;
    /// The same image left on the mode's GPU device (`None`: the mode's film is on the
    /// host): a window drawn with that device shows it without a read-back.
    fn image_on_device(&self) -> Option<Arc<dyn ImageOnDevice>> {
        None
    }
    /// `image` (a frame's image on this mode's device, from `image_on_device`) blended
    /// at `strength` with its version through `denoiser` (`denoise::blend`), filtered
    /// on the device with the mode's own guides, so the viewport's first frames need
    /// no read-back. `None` where the mode cannot (the viewport then filters on the
    /// host with `guides`).
    fn denoised_on_device(
        &self,
        image: &dyn ImageOnDevice,
        denoiser: &Denoiser,
        strength: f32,
    ) -> Option<Arc<dyn ImageOnDevice>> {
        let _ = (image, denoiser, strength);
        None
    }
    /// Makes what `denoised_on_device` needs (its device kernels) ahead of its first
    /// use: the studio calls it while the mode is prepared in the background, so the
    /// first filtered frame does not wait for a shader compiler. A no-op where the
    /// mode filters on the host.
    fn prepare_denoiser(&self) {}
    fn progress(&self) -> Progress;
    /// Applies an edit and restarts only what it invalidates. An edit that brings
    /// what the mode cannot render is refused (`EditError::Unsupported`).
    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError>;
    /// Samples per pixel per frame (at least 1).
    fn set_samples_per_frame(&mut self, samples: u32);
    /// Why the mode stopped rendering (its device failed), if it did: every later
    /// frame adds nothing, and callers should report it or switch device. Always
    /// `None` on the CPU.
    fn failure(&self) -> Option<ModeError> {
        None
    }
    /// What the mode reports besides its image: at least its preparation.
    fn diagnostics(&self) -> Diagnostics;
}

/// Conveniences over `RenderMode::render`, for every mode.
pub trait RenderModeExt: RenderMode {
    /// Adds one frame (`samples_per_frame` samples per pixel) to the film.
    fn render_frame(&mut self) -> FrameStats {
        self.render(Pass::Frame, None).unwrap_or_default()
    }
    /// `render_frame`, stopping between tiles once `stop` says yes (`render`).
    fn render_frame_yielding(&mut self, stop: &mut dyn FnMut() -> bool) -> FrameStats {
        self.render(Pass::Frame, Some(stop)).unwrap_or_default()
    }
    /// A preview of one pixel per `stride` x `stride` block (`Pass::Preview`).
    fn render_preview(&mut self, stride: u32) -> Option<FrameStats> {
        self.render(Pass::Preview { stride }, None)
    }
}

impl<T: RenderMode + ?Sized> RenderModeExt for T {}

/// One thing a mode reports besides its image.
#[derive(Clone, Debug)]
pub enum Diagnostic {
    /// The stages of the last preparation (first build, or the last rebuild an edit
    /// caused) and their times.
    Preparation(PreparationReport),
    /// The mode's own state in one line for status bars (e.g. the biscale mode's
    /// biclusters and light-change time).
    Summary(String),
    /// Device memory by kind (`bvh`, `triangles`, `spmm_bases`, ...) of a GPU mode.
    DeviceMemory(Vec<(&'static str, u64)>),
    /// The GPU adapter the mode runs on.
    Adapter(String),
    /// Ray traversals that ran past a device's bounds (stack or steps) and so may have
    /// missed a hit. A correct render keeps it at 0.
    TraversalOverflows(u64),
    /// Prepared material data held now and what preparing every material would hold,
    /// where the mode prepares materials on demand.
    MaterialBytes(MaterialBytes),
    /// A debug image of the mode's own decisions (the adaptive mode's bandwidth level
    /// and samples per pixel, as colour maps).
    Overlay { name: &'static str, image: Image },
}

/// A mode's diagnostics, with a reader for each kind (absent: the default).
#[derive(Clone, Debug, Default)]
pub struct Diagnostics(pub Vec<Diagnostic>);

impl Diagnostics {
    pub fn preparation(&self) -> PreparationReport {
        self.find(|d| match d {
            Diagnostic::Preparation(p) => Some(p.clone()),
            _ => None,
        })
        .unwrap_or_default()
    }

    pub fn summary(&self) -> Option<String> {
        self.find(|d| match d {
            Diagnostic::Summary(s) => Some(s.clone()),
            _ => None,
        })
    }

    /// Empty where the mode runs on the CPU.
    pub fn device_memory(&self) -> Vec<(&'static str, u64)> {
        self.find(|d| match d {
            Diagnostic::DeviceMemory(m) => Some(m.clone()),
            _ => None,
        })
        .unwrap_or_default()
    }

    /// `None` on the CPU.
    pub fn adapter(&self) -> Option<String> {
        self.find(|d| match d {
            Diagnostic::Adapter(a) => Some(a.clone()),
            _ => None,
        })
    }

    /// Always 0 on the CPU.
    pub fn traversal_overflows(&self) -> u64 {
        self.find(|d| match d {
            Diagnostic::TraversalOverflows(n) => Some(*n),
            _ => None,
        })
        .unwrap_or(0)
    }

    pub fn material_bytes(&self) -> Option<MaterialBytes> {
        self.find(|d| match d {
            Diagnostic::MaterialBytes(b) => Some(*b),
            _ => None,
        })
    }

    /// The debug images by name, in the mode's order.
    pub fn overlays(self) -> Vec<(&'static str, Image)> {
        self.0
            .into_iter()
            .filter_map(|d| match d {
                Diagnostic::Overlay { name, image } => Some((name, image)),
                _ => None,
            })
            .collect()
    }

    fn find<T>(&self, f: impl Fn(&Diagnostic) -> Option<T>) -> Option<T> {
        self.0.iter().find_map(f)
    }
}

/// Bytes of prepared material data (`meso render --json`: `material_bytes_resident`,
/// `material_bytes_full`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MaterialBytes {
    pub resident: u64,
    pub full: u64,
}

/// Totals of a run of frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RunStats {
    pub frames: u32,
    pub counters: Counters,
    /// Time spent rendering frames.
    pub seconds: f64,
    pub dropped: u64,
}

/// Renders `frames` more frames, calling `on_frame(done, stats)` after each (for
/// progress bars); stops early if the mode fails (`RenderMode::failure`).
pub fn run_frames(
    mode: &mut dyn RenderMode,
    frames: u32,
    mut on_frame: impl FnMut(u32, &FrameStats),
) -> RunStats {
    let mut total = RunStats::default();
    for f in 0..frames {
        let s = mode.render_frame();
        total.frames += 1;
        total.counters = total.counters + s.counters;
        total.seconds += s.seconds;
        total.dropped += s.dropped;
        on_frame(f + 1, &s);
        if mode.failure().is_some() {
            break;
        }
    }
    total
}
