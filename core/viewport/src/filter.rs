//! The viewport denoiser beside the render thread. The render thread publishes each
//! frame as it is and hands the frame's filters to this thread, then goes on with
//! the next frame: a filter never sits in a frame's path, so an edit waits for at
//! most a tile of rendering, never for the denoiser. The newest job wins (a job not
//! yet started is replaced by the next frame's, so while frames come faster than the
//! filter some are never filtered), and a filter of a document version the render
//! thread has left stops between passes.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;

use meso_materials::image::Image;

/// One filter of a frame: the picture to show, or `None` when `stop` said yes (or
/// the guides did not fit the image).
pub(crate) type Stage = Box<dyn FnOnce(&mut dyn FnMut() -> bool) -> Option<Image> + Send>;

/// The filters of one frame of document `version` with `samples` per pixel, run in
/// order (a quick one first when the view has no filtered picture yet); each result
/// is shown when ready.
pub(crate) struct Job {
    pub version: u64,
    pub samples: u32,
    pub stages: Vec<Stage>,
}

#[derive(Default)]
struct Queue {
    job: Option<Job>,
    closed: bool,
}

/// The thread and its one-job queue.
pub(crate) struct FilterThread {
    queue: Arc<(Mutex<Queue>, Condvar)>,
    thread: Option<JoinHandle<()>>,
}

impl FilterThread {
    /// Starts the thread. `current` is the newest document version the render
    /// thread has applied; `show(job, picture)` publishes a finished filter.
    pub fn spawn(current: Arc<AtomicU64>, show: impl Fn(&Job, Image) + Send + 'static) -> Self {
        let queue = Arc::new((Mutex::new(Queue::default()), Condvar::new()));
        let q = Arc::clone(&queue);
        let thread = std::thread::Builder::new()
            .name("meso-denoise".into())
            .spawn(move || run(&q, &current, &show))
            .ok();
        Self { queue, thread }
    }

    /// Queues `job` in place of any job not yet started. Without a thread (it could
    /// not be started) the frame is simply not filtered.
    pub fn submit(&self, job: Job) {
        if self.thread.is_some() {
            self.lock().job = Some(job);
            self.queue.1.notify_one();
        }
    }

    /// Drops the job not yet started (the denoiser was turned off).
    pub fn cancel(&self) {
        self.lock().job = None;
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Queue> {
        self.queue.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Drop for FilterThread {
    fn drop(&mut self) {
        self.lock().closed = true;
        self.queue.1.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run(queue: &(Mutex<Queue>, Condvar), current: &AtomicU64, show: &dyn Fn(&Job, Image)) {
    loop {
        let mut job = {
            let mut q = queue.0.lock().unwrap_or_else(PoisonError::into_inner);
            loop {
                if q.closed {
                    return;
                }
                if let Some(job) = q.job.take() {
                    break job;
                }
                q = queue.1.wait(q).unwrap_or_else(PoisonError::into_inner);
            }
        };
        let closed = || queue.0.lock().map_or(true, |q| q.closed);
        let version = job.version;
        let mut stop = || current.load(Ordering::Acquire) != version || closed();
        for stage in std::mem::take(&mut job.stages) {
            match stage(&mut stop) {
                Some(picture) => show(&job, picture),
                None => break,
            }
        }
    }
}
