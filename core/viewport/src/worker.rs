//! The viewport's render thread. The UI never waits on it: commands (load a scene,
//! apply an edit) go over a channel, each carrying the document version it brings the
//! renderer to; the thread applies everything pending, renders one progressive frame
//! with the scene's render mode, and publishes the image in a latest-wins slot, then
//! wakes the window (`Wake`). It idles once every pixel has `max_samples` samples.
//! The viewport denoiser runs beside it (`filter`): a frame is published as it is at
//! once, and again with its filtered picture when that is ready; until then a frame
//! shows the newest filtered picture of its document version, if there is one.
//! A mode prepared elsewhere (the studio's mode-switch job) is swapped in by
//! `Install`; until then the previous mode keeps rendering.
//! A GPU mode's frame stays on its device (`Picture::Device`), and so does its
//! denoised picture, filtered there (`RenderMode::denoised_on_device`): the viewport
//! shows them from there, and the host reads one back only when it asks for the image
//! (saving, comparing).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use meso_materials::image::Image;
use meso_render::scene::Scene;
use meso_render::{
    Denoiser, Device, Guides, ImageOnDevice, Invalidation, ModeKind, Pass, Prepare, Progress,
    RenderMode, SceneEdit, denoise, preview,
};

use crate::filter::{FilterThread, Job, Stage};
use crate::maker::{ModeMaker, core_modes};
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

/// A frame's image (its estimate, or the denoised picture shown): on the host, or
/// left on the GPU mode's device.
#[derive(Clone, Debug)]
pub enum Picture {
    Host(Arc<Image>),
    /// Read back the first time the host asks for it (`image`).
    Device(Arc<dyn ImageOnDevice>),
}

impl Picture {
    /// The image on the host. A read-back the device fails gives a black image of
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

    /// The image on the host, when it is there (nothing is read back).
    pub fn on_host(&self) -> Option<&Image> {
        match self {
            Self::Host(img) => Some(img),
            Self::Device(_) => None,
        }
    }

    /// The image on the device, when it is there.
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
    pub estimate: Picture,
    /// The mode's debug images by name (`RenderMode::debug_overlays`; the adaptive
    /// mode's bandwidth level and samples per pixel), empty for other modes.
    pub overlays: Vec<(&'static str, Arc<Image>)>,
    /// What the viewport shows when it is not the estimate itself: the estimate
    /// blended with its denoised version during the first frames when the denoiser is
    /// on (`None`: the estimate); on the device when a GPU mode filtered it there.
    pub shown: Option<Picture>,
    /// Samples per pixel of the frame whose filtered picture `shown` is (a frame
    /// shows an earlier frame's picture of its version until its own filter is done;
    /// 0: the preview's); `None` when `shown` is not the denoiser's.
    pub shown_samples: Option<u32>,
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
        self.shown.as_ref().unwrap_or(&self.estimate).image()
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

/// What the two threads hand the window.
struct Shared {
    frame: Option<Frame>,
    rejected: Vec<Rejected>,
    /// What the thread did on its own (fell back to the CPU), for the status line.
    notices: Vec<Notice>,
    /// The last frame published, and whether its picture may be the denoiser's: a
    /// filtered picture that arrives later is published with it.
    latest: Option<(Frame, bool)>,
    /// The newest filtered picture: frames of its version show it until their own
    /// filter is done.
    filtered: Option<Filtered>,
}

/// A filtered picture: of a frame of document `version` with `samples` per pixel.
#[derive(Clone)]
struct Filtered {
    version: u64,
    samples: u32,
    picture: Arc<Image>,
}

/// Called after each published frame (the window asks for a repaint).
pub type Wake = Arc<dyn Fn() + Send + Sync>;

pub struct RenderWorker {
    commands: Option<Sender<Command>>,
    shared: Arc<Mutex<Shared>>,
    thread: Option<JoinHandle<()>>,
}

impl RenderWorker {
    /// Starts the thread with core's modes; `wake` is called after each frame.
    pub fn spawn(wake: Option<Wake>) -> Self {
        Self::spawn_with(wake, core_modes())
    }

    /// Starts the thread; `Load` makes its modes with `maker`.
    pub fn spawn_with(wake: Option<Wake>, maker: Arc<dyn ModeMaker>) -> Self {
        let (tx, rx) = mpsc::channel();
        let shared = Arc::new(Mutex::new(Shared {
            frame: None,
            rejected: Vec::new(),
            notices: Vec::new(),
            latest: None,
            filtered: None,
        }));
        let out = Publisher {
            shared: Arc::clone(&shared),
            wake,
        };
        let thread = std::thread::Builder::new()
            .name("meso-render".into())
            .spawn(move || run(rx, out, maker.as_ref()))
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

/// Where both threads publish: the shared slot and the wake-up.
#[derive(Clone)]
struct Publisher {
    shared: Arc<Mutex<Shared>>,
    wake: Option<Wake>,
}

impl Publisher {
    /// Publishes `frame`. A frame whose picture may be the denoiser's (`filterable`)
    /// and that has none of its own shows the newest filtered picture of its version.
    fn frame(&self, mut frame: Frame, filterable: bool) {
        if let Ok(mut s) = self.shared.lock() {
            if filterable
                && frame.shown.is_none()
                && let Some(f) = s.filtered.as_ref().filter(|f| f.version == frame.version)
            {
                frame.shown = Some(Picture::Host(Arc::clone(&f.picture)));
                frame.shown_samples = Some(f.samples);
            }
            s.latest = Some((frame.clone(), filterable));
            s.frame = Some(frame);
        }
        self.wake();
    }

    /// Publishes the denoiser's `picture` of `job`'s frame with the last frame, if
    /// that frame is of the job's version and may show it (else it came too late).
    fn filtered(&self, job: &Job, picture: Image) {
        let Ok(mut s) = self.shared.lock() else {
            return;
        };
        let latest = s.latest.as_ref().filter(|l| l.0.version == job.version);
        let Some((latest, true)) = latest else {
            return;
        };
        let picture = Arc::new(picture);
        let frame = Frame {
            shown: Some(Picture::Host(Arc::clone(&picture))),
            shown_samples: Some(job.samples),
            ..latest.clone()
        };
        s.filtered = Some(Filtered {
            version: job.version,
            samples: job.samples,
            picture,
        });
        s.latest = Some((frame.clone(), true));
        s.frame = Some(frame);
        drop(s);
        self.wake();
    }

    /// Forgets the filtered picture (the denoiser was turned off).
    fn forget_filtered(&self) {
        if let Ok(mut s) = self.shared.lock() {
            s.filtered = None;
            if let Some(latest) = s.latest.as_mut() {
                latest.1 = false;
            }
        }
    }

    fn has_filtered(&self, version: u64) -> bool {
        self.shared
            .lock()
            .is_ok_and(|s| s.filtered.as_ref().is_some_and(|f| f.version == version))
    }

    fn wake(&self) {
        if let Some(wake) = &self.wake {
            wake();
        }
    }
}

/// The denoiser's side of the render thread: whether it is on, the mode's guides for
/// the current view (they trace a ray per pixel: cached until a command changes the
/// scene, the view or the mode), the preview's, and the thread that filters.
struct Denoising {
    on: bool,
    guides: Option<Option<Arc<Guides>>>,
    preview_guides: Option<(u32, Option<Arc<Guides>>)>,
    thread: FilterThread,
}

impl Denoising {
    /// Forgets the guides (the view, the scene or the mode changed).
    fn forget_guides(&mut self) {
        self.guides = None;
        self.preview_guides = None;
    }

    /// Publishes `m`'s film now, after a call that did `stats`, and queues its filters
    /// on the denoiser's thread: the half-resolution one first while its version has
    /// no filtered picture, then the full one. None once the blend has faded out, when
    /// the mode gives no guides, or for a `partial` frame, which traced only the
    /// pixels an edit restarted (filtering the whole image would cost far more than
    /// it). The frame goes out before the guides are traced, so an edit never waits
    /// for them to see its frame.
    fn publish_frame(
        &mut self,
        m: &dyn RenderMode,
        (stats, version, partial): (meso_render::FrameStats, u64, bool),
        out: &Publisher,
    ) {
        let samples = m.progress().min_samples;
        let on_device = m.image_on_device();
        let filter = denoise::viewport_filter(samples).filter(|_| self.on && !partial);
        // A GPU mode filters on its device: the frame and its picture stay there.
        if let (Some((denoiser, strength)), Some(estimate)) = (&filter, &on_device)
            && let Some(picture) = m.denoised_on_device(estimate.as_ref(), denoiser, *strength)
        {
            let estimate = Picture::Device(Arc::clone(estimate));
            let picture = Some(Picture::Device(picture));
            let frame = Frame {
                shown_samples: Some(samples),
                ..frame_with(m, stats, version, estimate, picture)
            };
            return out.frame(frame, false);
        }
        let Some((denoiser, strength)) = filter.filter(|_| self.guides != Some(None)) else {
            let estimate = match on_device {
                Some(d) => Picture::Device(d),
                None => Picture::Host(Arc::new(m.image())),
            };
            return out.frame(frame_with(m, stats, version, estimate, None), false);
        };
        let image = Arc::new(m.image());
        let quick = !out.has_filtered(version);
        out.frame(
            frame_with(m, stats, version, Picture::Host(Arc::clone(&image)), None),
            true,
        );
        let Some(guides) = self
            .guides
            .get_or_insert_with(|| m.guides(Pass::Frame).map(Arc::new))
            .clone()
        else {
            return;
        };
        let mut stages: Vec<Stage> = Vec::new();
        if quick {
            let (image, guides) = (Arc::clone(&image), Arc::clone(&guides));
            stages.push(Box::new(move |stop: &mut dyn FnMut() -> bool| {
                if stop() {
                    return None;
                }
                let d = denoiser.apply_halved(&image, &guides.halved())?;
                Some(denoise::blend(&image, &d, strength))
            }));
        }
        stages.push(Box::new(move |stop: &mut dyn FnMut() -> bool| {
            let d = denoiser.apply_unless(&image, &guides, stop)?;
            Some(denoise::blend(&image, &d, strength))
        }));
        self.thread.submit(Job {
            version,
            samples,
            stages,
        });
    }

    /// Publishes the preview of `m`'s film (its pixels of one per `stride` block, all
    /// sampled, spread over the image) after a call that did `stats`: at once as it
    /// is, then, when the denoiser is on and the mode gives the preview's guides,
    /// through the denoiser on its grid (`denoised_preview`) on the denoiser's thread.
    fn publish_preview(
        &mut self,
        m: &dyn RenderMode,
        (stats, stride, version): (meso_render::FrameStats, u32, u64),
        out: &Publisher,
    ) {
        let estimate = m.image();
        let image = Arc::new(preview::spread(&estimate, stride));
        let frame = Frame {
            preview: true,
            ..frame_with(m, stats, version, Picture::Host(image), None)
        };
        if !self.on {
            return out.frame(frame, false);
        }
        if self.preview_guides.as_ref().is_none_or(|g| g.0 != stride) {
            let guides = m.guides(Pass::Preview { stride }).map(Arc::new);
            self.preview_guides = Some((stride, guides));
        }
        let guides = self.preview_guides.as_ref().and_then(|g| g.1.clone());
        out.frame(frame, guides.is_some());
        if let Some(guides) = guides {
            let stage = Box::new(move |stop: &mut dyn FnMut() -> bool| {
                (!stop()).then(|| denoised_preview(&estimate, &guides, stride))?
            }) as Stage;
            self.thread.submit(Job {
                version,
                samples: 0,
                stages: vec![stage],
            });
        }
    }
}

/// The preview through the viewport denoiser at the grid's resolution: the previewed
/// pixels (one sample each) filtered with their own `guides`, by one pass fewer per
/// factor of two of the stride (about the full filter's footprint in image pixels),
/// then spread.
fn denoised_preview(estimate: &Image, guides: &Guides, stride: u32) -> Option<Image> {
    let full = Denoiser::for_samples(1);
    let coarse = Denoiser {
        passes: full.passes.saturating_sub(stride.max(1).ilog2()).max(1),
        ..full
    };
    let grid = coarse.apply(&preview::gather(estimate, stride), guides)?;
    Some(preview::spread(
        &preview::scatter(estimate, &grid, stride)?,
        stride,
    ))
}

/// Whether `command` may change what the pixels' centre rays see first (the
/// denoiser's guides): not settings, and not edits of emitters alone.
fn changes_guides(command: &Command) -> bool {
    match command {
        Command::MaxSamples(_)
        | Command::Denoise(_)
        | Command::YieldToEdits(_)
        | Command::Unchanged { .. } => false,
        Command::Edit { edit, .. } => edit.changes_guides(),
        Command::Load { .. } | Command::Install { .. } => true,
    }
}

fn frame_with(
    m: &dyn RenderMode,
    stats: meso_render::FrameStats,
    version: u64,
    estimate: Picture,
    shown: Option<Picture>,
) -> Frame {
    let diagnostics = m.diagnostics();
    let (summary, material_bytes) = (diagnostics.summary(), diagnostics.material_bytes());
    Frame {
        version,
        mode: m.kind(),
        device: m.device(),
        shown,
        shown_samples: None,
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
/// (sample limit, denoising, yielding to edits); a refusal with its version. Sets
/// `restarted` when an edit restarted samples.
fn apply(
    command: Command,
    maker: &dyn ModeMaker,
    (mode, restarted): (&mut Option<Box<dyn RenderMode>>, &mut bool),
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
                Some(m) => m
                    .apply(*edit)
                    .map(|i| *restarted |= i != Invalidation::Nothing)
                    .map_err(|e| (v, e.to_string())),
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

fn run(rx: Receiver<Command>, out: Publisher, maker: &dyn ModeMaker) {
    let mut mode: Option<Box<dyn RenderMode>> = None;
    let mut version = 0;
    // The newest version applied, read by the denoiser's thread to stop stale filters.
    let current = Arc::new(AtomicU64::new(0));
    let mut max_samples = 4096u32;
    let mut yield_to_edits = true;
    let mut denoising = Denoising {
        on: true,
        guides: None,
        preview_guides: None,
        thread: {
            let out = out.clone();
            FilterThread::spawn(Arc::clone(&current), move |job, picture| {
                out.filtered(job, picture)
            })
        },
    };
    // A preview stands for the film until a frame shows every pixel: frames stopped
    // by edits, frames of the pixels an edit restarted and emission edits are shown
    // through it meanwhile, so the viewport never shows a half-sampled film.
    let mut previewing = false;
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
        let mut restarted = false;
        for command in pending {
            changed |= !matches!(command, Command::MaxSamples(_) | Command::YieldToEdits(_));
            if changes_guides(&command) {
                denoising.forget_guides();
            }
            if matches!(command, Command::Load { .. } | Command::Install { .. }) {
                previewing = false;
            }
            let was_on = denoising.on;
            let knobs = (&mut max_samples, &mut denoising.on, &mut yield_to_edits);
            let result = apply(
                command,
                maker,
                (&mut mode, &mut restarted),
                &mut version,
                knobs,
            );
            if was_on && !denoising.on {
                denoising.thread.cancel();
                out.forget_filtered();
            }
            if let Err((version, message)) = result
                && let Ok(mut s) = out.shared.lock()
            {
                s.rejected.push(Rejected { version, message });
            }
        }
        current.store(version, Ordering::Release);
        let Some(m) = mode.as_mut() else { continue };
        // Once: `min_samples` reads every pixel of the film.
        let progress = m.progress();
        let converged = progress.min_samples >= max_samples;
        if converged && !changed {
            continue;
        }
        if converged {
            denoising.publish_frame(m.as_ref(), (Default::default(), version, false), &out);
            continue;
        }
        // No pixel shows every layer (a camera edit restarted them all, a light
        // moved): a few pixels of the frame first, spread over the viewport, then the
        // rest of the frame.
        let stride = preview::stride_for(progress.width, progress.height);
        let previewed = yield_to_edits
            && progress.min_samples == 0
            && match m.render_preview(stride) {
                Some(stats) => {
                    denoising.publish_preview(m.as_ref(), (stats, stride, version), &out);
                    true
                }
                None => false,
            };
        previewing |= previewed;
        // Show the edit now, then go on with the frame: every pixel keeps a sample
        // (an emission edit re-weights, a stopped frame left its rows), or the
        // preview's pixels do.
        let shows_whole = m.progress().shows_every_pixel;
        if changed && yield_to_edits && !previewed {
            if shows_whole {
                denoising.publish_frame(m.as_ref(), (Default::default(), version, false), &out);
            } else if previewing && !restarted {
                denoising.publish_preview(m.as_ref(), (Default::default(), stride, version), &out);
            }
        }
        let stats = if (shows_whole || previewing) && yield_to_edits {
            // A command stops the frame between tiles; it is applied at once and the
            // frame resumes after it. A film with unsampled pixels and no preview
            // renders its frame whole, so a stream of edits still shows frames.
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
            mode = fall_back(m.as_ref(), &failure.to_string(), maker, &out.shared);
            denoising.forget_guides();
            previewing = false;
            continue;
        }
        if !early.is_empty() {
            continue;
        }
        let progress = m.progress();
        if previewing && !progress.shows_every_pixel {
            // The pixels an edit restarted, traced first: the preview's among them.
            denoising.publish_preview(m.as_ref(), (stats, stride, version), &out);
            continue;
        }
        previewing = false;
        // A frame that traced only the pixels an edit restarted (a brush stroke step)
        // is shown as it is.
        let pixels = u64::from(progress.width) * u64::from(progress.height);
        let partial = stats.counters.samples > 0 && stats.counters.samples * 2 <= pixels;
        denoising.publish_frame(m.as_ref(), (stats, version, partial), &out);
    }
}

#[cfg(test)]
#[path = "worker_tests.rs"]
mod tests;
