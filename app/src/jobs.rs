//! Long loads as named background jobs: a scene (meshes, packs, environment maps) or
//! a pack is read on its own thread while the window stays responsive; the studio
//! polls the job each frame, shows its name and elapsed time with a spinner, and
//! installs the result when it arrives. A newer job of the same kind replaces an
//! older one (its result is dropped).

use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::time::Instant;

pub struct Job<T> {
    pub name: String,
    pub started: Instant,
    result: Receiver<Result<T, String>>,
}

impl<T: Send + 'static> Job<T> {
    /// Runs `work` on a new thread.
    pub fn spawn(
        name: impl Into<String>,
        repaint: Option<egui::Context>,
        work: impl FnOnce() -> Result<T, String> + Send + 'static,
    ) -> Self {
        let (tx, rx) = mpsc::channel();
        let name = name.into();
        let spawned = std::thread::Builder::new()
            .name("meso-load".into())
            .spawn(move || {
                let _ = tx.send(work());
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
        }
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
}
