//! The compare view's reference: the document's scene rendered on its own thread in
//! the (spmm, cpu) mode at the viewport's render size, refined up to a set number of
//! samples per pixel. A new document version or size restarts it (the newest request
//! wins); each refined image is published in a slot the studio reads. It shares the
//! CPU with the live render, so it is only started while the compare view is on.

use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use meso_materials::image::Image;
use meso_render::RenderModeExt;
use meso_render::scene::Scene;
use meso_render::{Device, ModeKind, Prepare, RenderMode};

/// The reference as far as it has come.
#[derive(Clone)]
pub struct Reference {
    /// The document version it shows.
    pub version: u64,
    pub image: Arc<Image>,
    /// Samples per pixel (the fewest of any pixel).
    pub spp: u32,
    /// Counts published images, so a reader can tell a new one.
    pub seq: u64,
}

/// What the reference is asked to render: (version, size, samples per pixel).
type Key = (u64, (u32, u32), u32);

struct Start {
    key: Key,
    scene: Box<Scene>,
}

pub struct ReferenceRenderer {
    commands: Option<Sender<Start>>,
    slot: Arc<Mutex<Option<Reference>>>,
    errors: Arc<Mutex<Option<String>>>,
    thread: Option<JoinHandle<()>>,
    requested: Option<Key>,
}

impl ReferenceRenderer {
    pub fn spawn(repaint: Option<egui::Context>) -> Self {
        let (tx, rx) = mpsc::channel();
        let slot = Arc::new(Mutex::new(None));
        let errors = Arc::new(Mutex::new(None));
        let (out, err) = (Arc::clone(&slot), Arc::clone(&errors));
        let thread = std::thread::Builder::new()
            .name("meso-reference".into())
            .spawn(move || run(rx, out, err, repaint))
            .ok();
        Self {
            commands: Some(tx),
            slot,
            errors,
            thread,
            requested: None,
        }
    }

    /// Renders `scene` (at document `version`) at `size` up to `spp` samples per
    /// pixel, unless that is what it renders already.
    pub fn request(&mut self, version: u64, scene: &Scene, size: (u32, u32), spp: u32) {
        let key = (version, size, spp.max(1));
        if self.requested == Some(key) {
            return;
        }
        self.requested = Some(key);
        if let Some(tx) = &self.commands {
            let _ = tx.send(Start {
                key,
                scene: Box::new(scene.clone()),
            });
        }
    }

    /// The newest published reference.
    pub fn latest(&self) -> Option<Reference> {
        self.slot.lock().ok()?.clone()
    }

    /// Why the reference could not be made, if it could not.
    pub fn error(&self) -> Option<String> {
        self.errors.lock().ok()?.clone()
    }

    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for ReferenceRenderer {
    fn drop(&mut self) {
        self.commands.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run(
    rx: Receiver<Start>,
    slot: Arc<Mutex<Option<Reference>>>,
    errors: Arc<Mutex<Option<String>>>,
    repaint: Option<egui::Context>,
) {
    let mut current: Option<(Key, Box<dyn RenderMode>)> = None;
    let mut seq = 0;
    loop {
        let done = current
            .as_ref()
            .is_none_or(|(key, m)| m.progress().min_samples >= key.2);
        let mut newest = None;
        if done {
            match rx.recv_timeout(Duration::from_millis(200)) {
                Ok(s) => newest = Some(s),
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => return,
            }
        }
        loop {
            match rx.try_recv() {
                Ok(s) => newest = Some(s),
                Err(mpsc::TryRecvError::Empty) => break,
                Err(mpsc::TryRecvError::Disconnected) => return,
            }
        }
        if let Some(Start { key, scene }) = newest {
            let (w, h) = key.1;
            match meso_modes::create(
                ModeKind::Spmm,
                Device::Cpu,
                *scene,
                w,
                h,
                Prepare::quietly(),
            ) {
                Ok(m) => {
                    current = Some((key, m));
                    if let Ok(mut e) = errors.lock() {
                        *e = None;
                    }
                }
                Err(e) => {
                    current = None;
                    if let Ok(mut slot) = errors.lock() {
                        *slot = Some(e.to_string());
                    }
                    continue;
                }
            }
        }
        let Some((key, m)) = current.as_mut() else {
            continue;
        };
        if m.progress().min_samples >= key.2 {
            continue;
        }
        m.render_frame();
        seq += 1;
        let reference = Reference {
            version: key.0,
            image: Arc::new(m.image()),
            spp: m.progress().min_samples,
            seq,
        };
        if let Ok(mut s) = slot.lock() {
            *s = Some(reference);
        }
        if let Some(ctx) = &repaint {
            ctx.request_repaint();
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use super::*;

    fn wait(r: &ReferenceRenderer, version: u64, spp: u32) -> Reference {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Some(x) = r.latest()
                && x.version == version
                && x.spp >= spp
            {
                return x;
            }
            assert!(
                Instant::now() < deadline,
                "no reference of version {version}"
            );
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    #[test]
    fn the_reference_refines_to_the_asked_samples_and_restarts_on_a_new_version() {
        let scene = meso_render::scene::load_scene(&crate::studio::default_scene_path())
            .expect("default scene");
        let mut r = ReferenceRenderer::spawn(None);
        r.request(3, &scene, (24, 16), 2);
        let a = wait(&r, 3, 2);
        assert_eq!((a.image.width(), a.image.height(), a.spp), (24, 16, 2));
        // The same image as core's mode at the same samples: it is the spmm mode.
        let mut m = meso_modes::create(
            ModeKind::Spmm,
            Device::Cpu,
            scene.clone(),
            24,
            16,
            Prepare::quietly(),
        )
        .expect("mode");
        m.render_frame();
        m.render_frame();
        assert_eq!(*a.image, m.image());
        r.request(4, &scene, (24, 16), 1);
        let b = wait(&r, 4, 1);
        assert!(b.seq > a.seq);
    }
}
