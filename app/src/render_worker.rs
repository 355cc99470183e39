//! The viewport's render thread. The UI never waits on it: commands (load a scene,
//! apply an edit) go over a channel, each carrying the document version it brings the
//! renderer to; the thread applies everything pending, renders one progressive frame
//! with the scene's render mode, and publishes the image in a latest-wins slot, then
//! asks egui to repaint. It idles once every pixel has `max_samples` samples.

use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use meso_core::image::Image;
use meso_core::modes;
use meso_core::render::{Device, ModeKind, Prepare, Progress, RenderMode, SceneEdit};
use meso_core::scene::Scene;

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
    Edit {
        version: u64,
        edit: Box<SceneEdit>,
    },
    /// Samples per pixel after which the thread idles.
    MaxSamples(u32),
}

/// A finished frame.
#[derive(Clone)]
pub struct Frame {
    /// The newest document version applied before this frame was rendered.
    pub version: u64,
    pub image: Arc<Image>,
    pub progress: Progress,
    pub frame_ms: f64,
    pub rays_per_second: f64,
    pub finished: Instant,
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
}

pub struct RenderWorker {
    commands: Option<Sender<Command>>,
    shared: Arc<Mutex<Shared>>,
    thread: Option<JoinHandle<()>>,
}

impl RenderWorker {
    /// Starts the thread; `repaint` is woken after each frame.
    pub fn spawn(repaint: Option<egui::Context>) -> Self {
        let (tx, rx) = mpsc::channel();
        let shared = Arc::new(Mutex::new(Shared {
            frame: None,
            rejected: Vec::new(),
        }));
        let out = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("meso-render".into())
            .spawn(move || run(rx, out, repaint))
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

fn run(rx: Receiver<Command>, shared: Arc<Mutex<Shared>>, repaint: Option<egui::Context>) {
    let mut mode: Option<Box<dyn RenderMode>> = None;
    let mut version = 0;
    let mut max_samples = 4096u32;
    loop {
        let idle = mode
            .as_ref()
            .is_none_or(|m| m.progress().min_samples >= max_samples);
        // Idle: wait for work (waking now and then to notice a closed channel).
        let mut pending = Vec::new();
        if idle {
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
        for command in pending {
            let result = match command {
                Command::Load {
                    version: v,
                    scene,
                    mode: kind,
                    device,
                    width,
                    height,
                } => {
                    version = v;
                    modes::create(kind, device, *scene, width, height, Prepare::quietly())
                        .map(|m| mode = Some(m))
                        .map_err(|e| (v, e.to_string()))
                }
                Command::Edit { version: v, edit } => {
                    version = v;
                    match &mut mode {
                        Some(m) => m.apply(*edit).map(|_| ()).map_err(|e| (v, e.to_string())),
                        None => Err((v, "no scene is loaded".into())),
                    }
                }
                Command::MaxSamples(n) => {
                    max_samples = n.max(1);
                    Ok(())
                }
            };
            if let Err((version, message)) = result
                && let Ok(mut s) = shared.lock()
            {
                s.rejected.push(Rejected { version, message });
            }
        }
        let Some(m) = mode.as_mut() else { continue };
        if m.progress().min_samples >= max_samples {
            continue;
        }
        let stats = m.render_frame();
        let frame = Frame {
            version,
            image: Arc::new(m.image()),
            progress: m.progress(),
            frame_ms: stats.seconds * 1e3,
            rays_per_second: stats.counters.rays.total() as f64 / stats.seconds.max(1e-9),
            finished: Instant::now(),
        };
        if let Ok(mut s) = shared.lock() {
            s.frame = Some(frame);
        }
        if let Some(ctx) = &repaint {
            ctx.request_repaint();
        }
    }
}
