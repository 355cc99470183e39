//! The viewport's render thread. The UI never waits on it: commands (load a scene,
//! apply an edit) go over a channel, each carrying the document version it brings the
//! renderer to; the thread applies everything pending, renders one progressive frame
//! with the scene's render mode, and publishes the image in a latest-wins slot, then
//! asks egui to repaint. It idles once every pixel has `max_samples` samples.
//! A mode prepared elsewhere (the studio's mode-switch job) is swapped in by
//! `Install`; until then the previous mode keeps rendering.
//! A GPU mode's frame stays on its device (`Estimate::Device`) unless the denoiser
//! needs it on the host: the viewport shows it from there, and the host reads it back
//! only when it asks for the image (saving, comparing).

use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use meso_materials::image::Image;
use meso_render::scene::Scene;
use meso_render::{
    Denoiser, Device, Guides, ImageOnDevice, ModeKind, Pass, Prepare, Progress, RenderMode,
    SceneEdit, denoise, preview,
};

use crate::mode_maker::{ModeMaker, core_modes};
use meso_render::RenderModeExt;

pub enum Command {
    /// Replace the scene (and mode) entirely.
    Load {
        version: u64,
        scene: Box<Scene>,
        mode: ModeKind,
        device: Device,
        width: u32,
        height: u32,
    },
    /// Replace the mode by one prepared off this thread for the scene at `version`.
    Install {
        version: u64,
        mode: Box<dyn RenderMode>,
    },
    Edit {
        version: u64,
        edit: Box<SceneEdit>,
    },
    /// The document moved to `version` without a change this mode sees (an edit of a
    /// light the mode renders without): the next frame carries the version.
    Unchanged {
        version: u64,
    },
    /// Samples per pixel after which the thread idles.
    MaxSamples(u32),
    /// Show the first frames through the viewport denoiser (fading out by
    /// `denoise::FADE_SAMPLES`); the estimate itself is never filtered.
    Denoise(bool),
    /// Let a command stop the frame in flight between tiles, and show a preview of the
    /// frame after an edit that restarts every pixel (`render::preview`), both on by
    /// default; off, a command waits for the whole frame and the first frame after a
    /// restart is whole (the behaviour the latency bench compares).
    YieldToEdits(bool),
}

/// A frame's estimate: on the host, or left on the GPU mode's device.
#[derive(Clone, Debug)]
pub enum Estimate {
    Host(Arc<Image>),
    /// Read back the first time the host asks for it (`image`).
    Device(Arc<dyn ImageOnDevice>),
}

impl Estimate {
    /// The estimate on the host. A read-back the device fails gives a black image of
    /// the frame's size (the render thread reports the failure with the next frame).
    pub fn image(&self) -> Arc<Image> {
        match self {
            Self::Host(img) => Arc::clone(img),
            Self::Device(d) => d.read().unwrap_or_else(|_| {
                let (w, h) = d.size();
                Arc::new(Image::new(w, h))
            }),
        }
    }

    pub fn size(&self) -> (u32, u32) {
        match self {
            Self::Host(img) => (img.width(), img.height()),
            Self::Device(d) => d.size(),
        }
    }

    /// The estimate on the device, when it is there.
    pub fn on_device(&self) -> Option<&dyn ImageOnDevice> {
        match self {
            Self::Host(_) => None,
            Self::Device(d) => Some(d.as_ref()),
        }
    }
}

/// A finished frame.
#[derive(Clone)]
pub struct Frame {
    /// The newest document version applied before this frame was rendered.
    pub version: u64,
    /// The mode that rendered it.
    pub mode: ModeKind,
    pub device: Device,
    /// The estimate: what is saved, compared and measured (`image`).
    pub estimate: Estimate,
    /// The mode's debug images by name (`RenderMode::debug_overlays`; the adaptive
    /// mode's bandwidth level and samples per pixel), empty for other modes.
    pub overlays: Vec<(&'static str, Arc<Image>)>,
    /// What the viewport shows when it is not the estimate itself: the estimate
    /// blended with its denoised version during the first frames when the denoiser is
    /// on (`None`: the estimate).
    pub shown: Option<Arc<Image>>,
    /// A preview after an edit that restarted every pixel: one pixel per block has
    /// its first sample and the estimate and `shown` are those pixels spread over the
    /// image (`render::preview`), for the viewport only: not an estimate to measure.
    pub preview: bool,
    pub progress: Progress,
    pub frame_ms: f64,
    pub rays_per_second: f64,
    pub finished: Instant,
    /// The mode's own one-line state (`RenderMode::summary`).
    pub summary: Option<String>,
    /// Prepared material data held and what preparing everything would hold.
    pub material_bytes: Option<meso_render::MaterialBytes>,
}

impl Frame {
    /// The estimate on the host (read back from the device the first time).
    pub fn image(&self) -> Arc<Image> {
        self.estimate.image()
    }

    /// What the viewport shows, on the host.
    pub fn shown_image(&self) -> Arc<Image> {
        self.shown.clone().unwrap_or_else(|| self.image())
    }
}

/// Something the thread did on its own: a failed device replaced.
#[derive(Clone, Debug, PartialEq)]
pub struct Notice {
    pub message: String,
    /// The mode and device rendering from now on (`None`: none could take over).
    pub now: Option<(ModeKind, Device)>,
}

/// A rejected command: the version it carried and why.
#[derive(Clone, Debug)]
pub struct Rejected {
    pub version: u64,
    pub message: String,
}

struct Shared {
    frame: Option<Frame>,
    rejected: Vec<Rejected>,
    /// What the thread did on its own (fell back to the CPU), for the status line.
    notices: Vec<Notice>,
}

pub struct RenderWorker {
    commands: Option<Sender<Command>>,
    shared: Arc<Mutex<Shared>>,
    thread: Option<JoinHandle<()>>,
}

impl RenderWorker {
    /// Starts the thread with core's modes; `repaint` is woken after each frame.
    pub fn spawn(repaint: Option<egui::Context>) -> Self {
        Self::spawn_with(repaint, core_modes())
    }

    /// Starts the thread; `Load` makes its modes with `maker`.
    pub fn spawn_with(repaint: Option<egui::Context>, maker: Arc<dyn ModeMaker>) -> Self {
        let (tx, rx) = mpsc::channel();
        let shared = Arc::new(Mutex::new(Shared {
            frame: None,
            rejected: Vec::new(),
            notices: Vec::new(),
        }));
        let out = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("meso-render".into())
            .spawn(move || run(rx, out, repaint, maker.as_ref()))
            .ok();
        Self {
            commands: Some(tx),
            shared,
            thread,
        }
    }

    /// Queues a command; false if the thread is gone.
    pub fn send(&self, command: Command) -> bool {
        self.commands
            .as_ref()
            .is_some_and(|tx| tx.send(command).is_ok())
    }

    /// The newest finished frame, if one arrived since the last call.
    pub fn take_frame(&self) -> Option<Frame> {
        self.shared.lock().ok()?.frame.take()
    }

    /// Commands the renderer refused since the last call.
    pub fn take_rejected(&self) -> Vec<Rejected> {
        self.shared
            .lock()
            .map(|mut s| std::mem::take(&mut s.rejected))
            .unwrap_or_default()
    }

    /// What the thread did on its own since the last call (a failed GPU replaced by
    /// the CPU), one line each.
    pub fn take_notices(&self) -> Vec<Notice> {
        self.shared
            .lock()
            .map(|mut s| std::mem::take(&mut s.notices))
            .unwrap_or_default()
    }

    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for RenderWorker {
    fn drop(&mut self) {
        // Closing the channel ends the loop after the frame in progress.
        self.commands.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How the viewport's denoiser runs for a frame.
enum Filter<'a> {
    /// `Denoiser::apply_unless`: the frame is not shown if `stop` says yes first.
    Full(&'a mut dyn FnMut() -> bool),
    /// `Denoiser::apply_halved`: the first picture after an edit that keeps the
    /// samples, which the next frame replaces with the full filter's.
    Halved,
}

/// The viewport's picture of `m`'s film after `samples` samples per pixel, with the
/// estimate: the estimate blended with its denoised version while the blend's strength
/// is positive and the mode gives guides (the estimate then read to the host); else
/// the estimate alone, left on the device where the mode's film is. `guides` caches
/// the mode's guides until a command changes the scene, the view or the mode (they
/// trace a ray per pixel: most of the denoiser's cost). `None` when a full filter was
/// stopped.
fn estimate_and_shown(
    m: &dyn RenderMode,
    samples: u32,
    (denoise, guides): (bool, &mut Option<Option<Guides>>),
    filter: Filter,
) -> Option<(Estimate, Option<Arc<Image>>)> {
    let strength = denoise::viewport_strength(samples);
    let g = if denoise && strength > 0.0 {
        guides.get_or_insert_with(|| m.guides(Pass::Frame)).as_ref()
    } else {
        None
    };
    let Some(g) = g else {
        let estimate = match m.image_on_device() {
            Some(d) => Estimate::Device(d),
            None => Estimate::Host(Arc::new(m.image())),
        };
        return Some((estimate, None));
    };
    let image = m.image();
    let denoiser = Denoiser::for_samples(samples);
    let filtered = match filter {
        Filter::Full(stop) => Some(denoiser.apply_unless(&image, g, stop)?),
        Filter::Halved => denoiser.apply_halved(&image, &g.halved()),
    };
    let shown = filtered.map(|d| Arc::new(denoise::blend(&image, &d, strength)));
    Some((Estimate::Host(Arc::new(image)), shown))
}

/// Whether `command` may change what the pixels' centre rays see first (the
/// denoiser's guides): not settings, and not edits of emitters alone.
fn changes_guides(command: &Command) -> bool {
    match command {
        Command::MaxSamples(_)
        | Command::Denoise(_)
        | Command::YieldToEdits(_)
        | Command::Unchanged { .. } => false,
        Command::Edit { edit, .. } => !matches!(
            **edit,
            SceneEdit::Light { .. }
                | SceneEdit::AddLight(_)
                | SceneEdit::RemoveLight(_)
                | SceneEdit::Ambient(_)
                | SceneEdit::Environment(_)
                | SceneEdit::Background(_)
                | SceneEdit::LightSamples(_)
        ),
        Command::Load { .. } | Command::Install { .. } => true,
    }
}

/// Publishes the preview of `m`'s film after `render_preview` did `stats`: at once as
/// it is, then, when the denoiser is on and the mode gives the preview's guides,
/// through the denoiser on its grid (a few milliseconds later).
fn publish_preview(
    m: &dyn RenderMode,
    (stats, stride, version): (meso_render::FrameStats, u32, u64),
    denoise: bool,
    publish: &dyn Fn(Frame),
) {
    let estimate = m.image();
    let image = Arc::new(preview::spread(&estimate, stride));
    let frame = Frame {
        preview: true,
        ..frame_with(m, stats, version, Estimate::Host(image), None)
    };
    publish(frame.clone());
    if let Some(denoised) = denoise
        .then(|| denoised_preview(m, &estimate, stride))
        .flatten()
    {
        publish(Frame {
            shown: Some(Arc::new(denoised)),
            ..frame
        });
    }
}

/// The preview through the viewport denoiser at the grid's resolution: the previewed
/// pixels (one sample each) filtered with their own guides, by one pass fewer per
/// factor of two of the stride (about the full filter's footprint in image pixels),
/// then spread.
fn denoised_preview(m: &dyn RenderMode, estimate: &Image, stride: u32) -> Option<Image> {
    let guides = m.guides(Pass::Preview { stride })?;
    let full = Denoiser::for_samples(1);
    let coarse = Denoiser {
        passes: full.passes.saturating_sub(stride.max(1).ilog2()).max(1),
        ..full
    };
    let grid = coarse.apply(&preview::gather(estimate, stride), &guides)?;
    Some(preview::spread(
        &preview::scatter(estimate, &grid, stride)?,
        stride,
    ))
}

/// The frame to publish at once after commands changed the image without restarting
/// it (an emission edit): the denoiser, while on, at half resolution, so the edit shows
/// before a full filter's time.
fn edited_frame_of(
    m: &dyn RenderMode,
    version: u64,
    denoise: bool,
    guides: &mut Option<Option<Guides>>,
) -> Frame {
    let samples = m.progress().min_samples;
    // Only a full filter can be stopped; were it `None`, the estimate shows as it is.
    let (estimate, shown) = estimate_and_shown(m, samples, (denoise, guides), Filter::Halved)
        .unwrap_or_else(|| (Estimate::Host(Arc::new(m.image())), None));
    frame_with(m, Default::default(), version, estimate, shown)
}

/// The frame to publish of `m`'s film now, after a call that did `stats`; `None` when
/// `stop` said yes before the denoiser was done (a command is waiting: the frame is
/// stale).
fn frame_of(
    m: &dyn RenderMode,
    stats: meso_render::FrameStats,
    version: u64,
    (denoise, guides): (bool, &mut Option<Option<Guides>>),
    stop: &mut dyn FnMut() -> bool,
) -> Option<Frame> {
    let progress = m.progress();
    // A frame that traced only the pixels an edit restarted (a brush stroke step)
    // is shown as it is: denoising the whole image would cost far more than it.
    let pixels = u64::from(progress.width) * u64::from(progress.height);
    let partial = stats.counters.samples > 0 && stats.counters.samples * 2 <= pixels;
    let (estimate, shown) = estimate_and_shown(
        m,
        progress.min_samples,
        (denoise && !partial, guides),
        Filter::Full(stop),
    )?;
    Some(frame_with(m, stats, version, estimate, shown))
}

fn frame_with(
    m: &dyn RenderMode,
    stats: meso_render::FrameStats,
    version: u64,
    estimate: Estimate,
    shown: Option<Arc<Image>>,
) -> Frame {
    let diagnostics = m.diagnostics();
    let (summary, material_bytes) = (diagnostics.summary(), diagnostics.material_bytes());
    Frame {
        version,
        mode: m.kind(),
        device: m.device(),
        shown,
        estimate,
        preview: false,
        progress: m.progress(),
        overlays: diagnostics
            .overlays()
            .into_iter()
            .map(|(name, img)| (name, Arc::new(img)))
            .collect(),
        frame_ms: stats.seconds * 1e3,
        rays_per_second: stats.counters.rays.total() as f64 / stats.seconds.max(1e-9),
        finished: Instant::now(),
        summary,
        material_bytes,
    }
}

/// Applies one command to the render thread's mode, document version and knobs
/// (sample limit, denoising, yielding to edits); a refusal with its version.
fn apply(
    command: Command,
    maker: &dyn ModeMaker,
    mode: &mut Option<Box<dyn RenderMode>>,
    version: &mut u64,
    (max_samples, denoise, yield_to_edits): (&mut u32, &mut bool, &mut bool),
) -> Result<(), (u64, String)> {
    match command {
        Command::Load {
            version: v,
            scene,
            mode: kind,
            device,
            width,
            height,
        } => {
            *version = v;
            maker
                .create(kind, device, *scene, width, height, Prepare::quietly())
                .map(|m| *mode = Some(m))
                .map_err(|e| (v, e.to_string()))
        }
        Command::Install {
            version: v,
            mode: m,
        } => {
            *version = v;
            *mode = Some(m);
            Ok(())
        }
        Command::Edit { version: v, edit } => {
            *version = v;
            match mode {
                Some(m) => m.apply(*edit).map(|_| ()).map_err(|e| (v, e.to_string())),
                None => Err((v, "no scene is loaded".into())),
            }
        }
        Command::Unchanged { version: v } => {
            *version = v;
            Ok(())
        }
        Command::MaxSamples(n) => {
            *max_samples = n.max(1);
            Ok(())
        }
        Command::Denoise(on) => {
            *denoise = on;
            Ok(())
        }
        Command::YieldToEdits(on) => {
            *yield_to_edits = on;
            Ok(())
        }
    }
}

/// The same scene as `m` (edits included) on the CPU after its device failed
/// (`failure`), with a notice saying so (or why the CPU cannot take over).
fn fall_back(
    m: &dyn RenderMode,
    failure: &str,
    maker: &dyn ModeMaker,
    shared: &Mutex<Shared>,
) -> Option<Box<dyn RenderMode>> {
    let progress = m.progress();
    let fallback = maker.create(
        m.kind(),
        Device::Cpu,
        m.scene().clone(),
        progress.width,
        progress.height,
        Prepare::quietly(),
    );
    let message = match &fallback {
        Ok(_) => format!("{failure}; rendering on the CPU"),
        Err(e) => format!("{failure}; the CPU cannot take over: {e}"),
    };
    let now = fallback.as_ref().ok().map(|m| (m.kind(), m.device()));
    if let Ok(mut s) = shared.lock() {
        s.notices.push(Notice { message, now });
    }
    fallback.ok()
}

fn run(
    rx: Receiver<Command>,
    shared: Arc<Mutex<Shared>>,
    repaint: Option<egui::Context>,
    maker: &dyn ModeMaker,
) {
    let publish = |frame: Frame| {
        if let Ok(mut s) = shared.lock() {
            s.frame = Some(frame);
        }
        if let Some(ctx) = &repaint {
            ctx.request_repaint();
        }
    };
    let mut mode: Option<Box<dyn RenderMode>> = None;
    let mut version = 0;
    let mut max_samples = 4096u32;
    let mut denoise = true;
    let mut yield_to_edits = true;
    let mut guides: Option<Option<Guides>> = None;
    // Commands that arrived during a frame and stopped it: applied first next time.
    let mut early: Vec<Command> = Vec::new();
    loop {
        let idle = mode
            .as_ref()
            .is_none_or(|m| m.progress().min_samples >= max_samples);
        // Idle: wait for work (waking now and then to notice a closed channel).
        let mut pending = std::mem::take(&mut early);
        if idle && pending.is_empty() {
            match rx.recv_timeout(Duration::from_millis(200)) {
                Ok(c) => pending.push(c),
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => return,
            }
        }
        loop {
            match rx.try_recv() {
                Ok(c) => pending.push(c),
                Err(mpsc::TryRecvError::Empty) => break,
                Err(mpsc::TryRecvError::Disconnected) => return,
            }
        }
        // Anything but a sample limit may change the image: publish a frame even if
        // the film is already converged (an emission edit re-weights it).
        let mut changed = false;
        for command in pending {
            changed |= !matches!(command, Command::MaxSamples(_) | Command::YieldToEdits(_));
            if changes_guides(&command) {
                guides = None;
            }
            let knobs = (&mut max_samples, &mut denoise, &mut yield_to_edits);
            let result = apply(command, maker, &mut mode, &mut version, knobs);
            if let Err((version, message)) = result
                && let Ok(mut s) = shared.lock()
            {
                s.rejected.push(Rejected { version, message });
            }
        }
        let Some(m) = mode.as_mut() else { continue };
        // Once: `min_samples` reads every pixel of the film.
        let progress = m.progress();
        let converged = progress.min_samples >= max_samples;
        if converged && !changed {
            continue;
        }
        if converged {
            // The quick picture first, then the full filter's (the same without it).
            let quick = edited_frame_of(m.as_ref(), version, denoise, &mut guides);
            let filtered = quick.shown.is_some();
            publish(quick);
            if filtered
                && let Some(f) = frame_of(
                    m.as_ref(),
                    Default::default(),
                    version,
                    (denoise, &mut guides),
                    &mut || false,
                )
            {
                publish(f);
            }
            continue;
        }
        // No pixel has a sample (a camera edit restarted them all): a few pixels of
        // the frame first, spread over the viewport, then the rest of the frame.
        let stride = preview::stride_for(progress.width, progress.height);
        let previewed = yield_to_edits
            && progress.min_samples == 0
            && match m.render_preview(stride) {
                Some(stats) => {
                    publish_preview(m.as_ref(), (stats, stride, version), denoise, &publish);
                    true
                }
                None => false,
            };
        // Every pixel keeps a sample (an emission edit re-weights, a stopped frame
        // left its rows): show the edit now, then go on with the frame. (A preview
        // leaves unsampled pixels, so this holds as it did before it.)
        let shows_whole = m.progress().shows_every_pixel;
        if changed && shows_whole && yield_to_edits {
            publish(edited_frame_of(m.as_ref(), version, denoise, &mut guides));
        }
        let stats = if (shows_whole || previewed) && yield_to_edits {
            // A command stops the frame between tiles; it is applied at once and the
            // frame resumes after it. A film with unsampled pixels and no preview
            // renders its frame whole, so a stream of edits still shows frames (a
            // wheel zoom shows a preview per step).
            m.render_frame_yielding(&mut || match rx.try_recv() {
                Ok(c) => {
                    early.push(c);
                    true
                }
                Err(mpsc::TryRecvError::Empty) => false,
                Err(mpsc::TryRecvError::Disconnected) => true,
            })
        } else {
            m.render_frame()
        };
        if let Some(failure) = m.failure() {
            // The device failed (a GPU lost): the same scene, edits included, goes on
            // on the CPU, and the studio says why.
            mode = fall_back(m.as_ref(), &failure.to_string(), maker, &shared);
            guides = None;
            continue;
        }
        if !early.is_empty() {
            continue;
        }
        // A command arriving while the frame is filtered stops the filter (when edits
        // may stop frames): the frame is stale, the command is applied at once.
        let mut stop = || match yield_to_edits.then(|| rx.try_recv()) {
            None => false,
            Some(Ok(c)) => {
                early.push(c);
                true
            }
            Some(Err(mpsc::TryRecvError::Empty)) => false,
            Some(Err(mpsc::TryRecvError::Disconnected)) => true,
        };
        if let Some(f) = frame_of(
            m.as_ref(),
            stats,
            version,
            (denoise, &mut guides),
            &mut stop,
        ) {
            publish(f);
        }
    }
}

#[cfg(test)]
#[path = "render_worker_tests.rs"]
mod tests;
