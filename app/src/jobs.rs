//! Long loads as named background jobs: a scene (meshes, packs, environment maps) or
//! a pack is read on its own thread while the window stays responsive; the studio
//! polls the job each frame, shows its name and elapsed time with a spinner, and
//! installs the result when it arrives. A newer job of the same kind replaces an
//! older one (its result is dropped). A job may report its stage and progress and
//! watch a cancel flag (`spawn_controlled`): render-mode preparation does.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// What a running job shares with the window: its progress and the cancel flag.
pub struct JobControl {
    progress: Mutex<Option<(String, f32)>>,
    cancel: AtomicBool,
    repaint: Option<egui::Context>,
}

impl JobControl {
    /// Notes that `fraction` (0..=1) of `stage` is done and wakes the window.
    pub fn report(&self, stage: &str, fraction: f32) {
        if let Ok(mut p) = self.progress.lock() {
            *p = Some((stage.to_string(), fraction.clamp(0.0, 1.0)));
        }
        if let Some(ctx) = &self.repaint {
            ctx.request_repaint();
        }
    }

    /// Set once the user cancelled; the work checks it between steps.
    pub fn cancel_flag(&self) -> &AtomicBool {
        &self.cancel
    }
}

pub struct Job<T> {
    pub name: String,
    pub started: Instant,
    result: Receiver<Result<T, String>>,
    control: Arc<JobControl>,
}

impl<T: Send + 'static> Job<T> {
    /// Runs `work` on a new thread.
    pub fn spawn(
        name: impl Into<String>,
        repaint: Option<egui::Context>,
        work: impl FnOnce() -> Result<T, String> + Send + 'static,
    ) -> Self {
        Self::spawn_controlled(name, repaint, |_| work())
    }

    /// Runs `work` on a new thread; it reports progress and watches the cancel flag
    /// through its `JobControl`.
    pub fn spawn_controlled(
        name: impl Into<String>,
        repaint: Option<egui::Context>,
        work: impl FnOnce(&JobControl) -> Result<T, String> + Send + 'static,
    ) -> Self {
        let (tx, rx) = mpsc::channel();
        let name = name.into();
        let control = Arc::new(JobControl {
            progress: Mutex::new(None),
            cancel: AtomicBool::new(false),
            repaint: repaint.clone(),
        });
        let theirs = Arc::clone(&control);
        let spawned = std::thread::Builder::new()
            .name("meso-job".into())
            .spawn(move || {
                let _ = tx.send(work(&theirs));
                if let Some(ctx) = repaint {
                    ctx.request_repaint();
                }
            });
        let (tx_err, rx_err) = mpsc::channel();
        let result = match spawned {
            Ok(_) => rx,
            Err(e) => {
                let _ = tx_err.send(Err(format!("cannot start a loading thread: {e}")));
                rx_err
            }
        };
        Self {
            name,
            started: Instant::now(),
            result,
            control,
        }
    }

    /// The last stage and fraction the job reported.
    pub fn progress(&self) -> Option<(String, f32)> {
        self.control.progress.lock().ok()?.clone()
    }

    /// Asks the job to stop; it answers (usually with an error) when it notices.
    pub fn cancel(&self) {
        self.control.cancel.store(true, Ordering::Relaxed);
    }

    pub fn cancelled(&self) -> bool {
        self.control.cancel.load(Ordering::Relaxed)
    }

    /// The result once the job is done (then the job is spent).
    pub fn poll(&self) -> Option<Result<T, String>> {
        match self.result.try_recv() {
            Ok(r) => Some(r),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err(format!("`{}` stopped", self.name))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_returns_its_result_and_a_panicking_one_an_error() {
        let job = Job::spawn("sum", None, || Ok::<_, String>(2 + 2));
        let deadline = Instant::now() + std::time::Duration::from_secs(10);
        let r = loop {
            if let Some(r) = job.poll() {
                break r;
            }
            assert!(Instant::now() < deadline);
            std::thread::sleep(std::time::Duration::from_millis(1));
        };
        assert_eq!(r, Ok(4));
        let bad: Job<u32> = Job::spawn("broken", None, || panic!("a loader bug"));
        let r = loop {
            if let Some(r) = bad.poll() {
                break r;
            }
            assert!(Instant::now() < deadline);
            std::thread::sleep(std::time::Duration::from_millis(1));
        };
        assert!(r.expect_err("the job died").contains("broken"));
    }

    #[test]
    fn a_controlled_job_reports_progress_and_stops_when_cancelled() {
        let job: Job<u32> = Job::spawn_controlled("count", None, |c| {
            let mut n = 0;
            while !c.cancel_flag().load(Ordering::Relaxed) {
                n += 1;
                c.report("counting", 0.5);
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            Err(format!("cancelled after {n}"))
        });
        let deadline = Instant::now() + std::time::Duration::from_secs(10);
        while job.progress().is_none() {
            assert!(Instant::now() < deadline, "no progress reported");
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert_eq!(job.progress(), Some(("counting".to_string(), 0.5)));
        assert!(job.poll().is_none(), "still running");
        job.cancel();
        let r = loop {
            if let Some(r) = job.poll() {
                break r;
            }
            assert!(Instant::now() < deadline, "did not stop");
            std::thread::sleep(std::time::Duration::from_millis(1));
        };
        assert!(r.expect_err("cancelled").starts_with("cancelled"));
    }
}
