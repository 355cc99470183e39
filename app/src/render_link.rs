//! The studio's end of the render thread: commands go out through it, those that
//! change what is rendered noted with their document version and the time they were
//! sent, so the newest frame tells how long an edit took to show (`Latency`, for the
//! status bar and the latency benchmark). Its own type so the window never keeps the
//! bookkeeping of edits in flight itself.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Instant;

use meso_viewport::maker::ModeMaker;
use meso_viewport::worker::{Command, Frame, Notice, Rejected, RenderWorker};

/// Statistics of the newest frame, for the status bar.
#[derive(Clone, Copy, Debug, Default)]
pub struct Latency {
    /// Edit sent to the first frame rendered after it, in milliseconds.
    pub last_edit_to_frame_ms: Option<f64>,
}

/// The render thread and the edits sent to it not yet seen in a frame.
pub struct RenderLink {
    worker: RenderWorker,
    /// Edits sent and not yet seen in a frame: (version, when).
    in_flight: VecDeque<(u64, Instant)>,
    latency: Latency,
}

impl RenderLink {
    /// Starts the render thread with modes made by `maker`.
    pub fn spawn(repaint: Option<egui::Context>, maker: Arc<dyn ModeMaker>) -> Self {
        Self {
            worker: RenderWorker::spawn_with(
                repaint.map(|ctx| Arc::new(move || ctx.request_repaint()) as _),
                maker,
            ),
            in_flight: VecDeque::new(),
            latency: Latency::default(),
        }
    }

    /// Sends a command whose effect is not measured (settings, installs, replays).
    pub fn send(&self, command: Command) {
        self.worker.send(command);
    }

    /// Sends a command that brings the renderer to document `version`, timed until a
    /// frame of that version arrives.
    pub fn send_tracked(&mut self, command: Command, version: u64) {
        self.worker.send(command);
        self.in_flight.push_back((version, Instant::now()));
    }

    /// Forgets the edits in flight (a new document).
    /// Edits sent whose frame has not come back yet.
    pub fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    pub fn forget_in_flight(&mut self) {
        self.in_flight.clear();
    }

    /// What the render thread says: fallbacks, refused edits.
    pub fn take_messages(&self) -> (Vec<Notice>, Vec<Rejected>) {
        (self.worker.take_notices(), self.worker.take_rejected())
    }

    /// The newest frame, if one arrived, with the latency of the edits before it
    /// measured.
    pub fn take_frame(&mut self) -> Option<Frame> {
        let frame = self.worker.take_frame()?;
        let mut newest = None;
        while let Some(&(v, t)) = self.in_flight.front() {
            if v > frame.version {
                break;
            }
            newest = Some(t);
            self.in_flight.pop_front();
        }
        if let Some(t) = newest {
            self.latency.last_edit_to_frame_ms =
                Some(frame.finished.saturating_duration_since(t).as_secs_f64() * 1e3);
        }
        Some(frame)
    }

    pub fn latency(&self) -> Latency {
        self.latency
    }

    /// Whether the render thread still runs.
    pub fn is_running(&self) -> bool {
        self.worker.is_running()
    }
}
