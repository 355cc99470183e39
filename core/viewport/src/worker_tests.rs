use std::sync::atomic::{AtomicU32, Ordering};

use meso_render::{Diagnostics, EditError, FrameStats, Invalidation, ModeError, SceneEdit};

use super::*;
use crate::maker::CoreModes;

/// The shipped scenes.
fn scenes_dir() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/scenes")
}

/// Core's CPU spmm mode in a test's clothes: posing as a GPU mode whose device
/// fails on its third frame, as a lost GPU does (nothing more is added after it),
/// or with frames that say they started and wait for the test's go-ahead (previews
/// do not), so the test sees each frame the thread publishes.
struct Wrapped {
    inner: Box<dyn RenderMode>,
    fails_as_gpu: bool,
    frames: u32,
    gate: Option<Gate>,
}

#[derive(Clone)]
struct Gate {
    go: Arc<Mutex<mpsc::Receiver<()>>>,
    started: mpsc::Sender<()>,
}

/// A gate for a thread's modes, the test's go-ahead and the frame-start signal.
fn gate() -> (Gate, mpsc::Sender<()>, mpsc::Receiver<()>) {
    let (go, gate) = mpsc::channel();
    let (started, starts) = mpsc::channel();
    let go_gate = Arc::new(Mutex::new(gate));
    (
        Gate {
            go: go_gate,
            started,
        },
        go,
        starts,
    )
}

impl RenderMode for Wrapped {
    fn kind(&self) -> ModeKind {
        self.inner.kind()
    }
    fn device(&self) -> Device {
        if self.fails_as_gpu {
            Device::Gpu
        } else {
            self.inner.device()
        }
    }
    fn scene(&self) -> &Scene {
        self.inner.scene()
    }
    /// Frames go through the gate, then render as the mode does (stopping when asked).
    fn render(&mut self, pass: Pass, stop: Option<&mut dyn FnMut() -> bool>) -> Option<FrameStats> {
        if let Pass::Preview { .. } = pass {
            return self.inner.render(pass, stop);
        }
        if let Some(gate) = &self.gate {
            let _ = gate.started.send(());
            // Bounded, so a failed test cannot leave the thread waiting forever.
            let _ = (gate.go.lock()).map(|go| go.recv_timeout(Duration::from_secs(20)));
        }
        self.frames += 1;
        if self.fails_as_gpu && self.frames >= 3 {
            return Some(FrameStats::default());
        }
        self.inner.render(pass, stop)
    }
    fn guides(&self, pass: Pass) -> Option<Guides> {
        self.inner.guides(pass)
    }
    fn image(&self) -> Image {
        self.inner.image()
    }
    fn image_on_device(&self) -> Option<Arc<dyn ImageOnDevice>> {
        self.inner.image_on_device()
    }
    fn progress(&self) -> Progress {
        self.inner.progress()
    }
    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        self.inner.apply(edit)
    }
    fn set_samples_per_frame(&mut self, samples: u32) {
        self.inner.set_samples_per_frame(samples);
    }
    fn failure(&self) -> Option<ModeError> {
        (self.fails_as_gpu && self.frames >= 3)
            .then(|| ModeError::DeviceFailed("the GPU `fake` failed".into()))
    }
    fn diagnostics(&self) -> Diagnostics {
        self.inner.diagnostics()
    }
}

/// Core's modes on the CPU, each made `Wrapped`: with `cpu_made`, a GPU mode is
/// the failing one and CPU modes made are counted; with `gate`, frames wait for the
/// test.
struct TestModes {
    cpu_made: Option<Arc<AtomicU32>>,
    gate: Option<Gate>,
}

impl ModeMaker for TestModes {
    fn supports(&self, kind: ModeKind, _: Device, scene: &Scene) -> Result<(), ModeError> {
        CoreModes::default().supports(kind, Device::Cpu, scene)
    }
    fn create(
        &self,
        kind: ModeKind,
        device: Device,
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Box<dyn RenderMode>, ModeError> {
        let inner =
            CoreModes::default().create(kind, Device::Cpu, scene, width, height, prepare)?;
        if let (Device::Cpu, Some(made)) = (device, &self.cpu_made) {
            made.fetch_add(1, Ordering::Relaxed);
        }
        Ok(Box::new(Wrapped {
            inner,
            fails_as_gpu: device == Device::Gpu && self.cpu_made.is_some(),
            frames: 0,
            gate: self.gate.clone(),
        }))
    }
}

/// A GPU that fails mid-render does not end the render thread: it says why, and
/// the same scene with its edits renders on the CPU from then on.
#[test]
fn a_failed_gpu_falls_back_to_the_cpu_with_the_edited_scene() {
    let cpu_made = Arc::new(AtomicU32::new(0));
    let worker = RenderWorker::spawn_with(
        None,
        Arc::new(TestModes {
            cpu_made: Some(Arc::clone(&cpu_made)),
            gate: None,
        }),
    );
    let path = scenes_dir().join("cornell.toml");
    let scene = meso_render::scene::load_scene(&path).expect("the Cornell scene");
    assert!(worker.send(Command::Load {
        version: 1,
        scene: Box::new(scene.clone()),
        mode: ModeKind::Spmm,
        device: Device::Gpu,
        width: 8,
        height: 8,
    }));
    // An edit the GPU mode takes before it fails: the CPU must keep it.
    let light = scene.lights[0].with_emission(scene.lights[0].emission() * 3.0);
    assert!(worker.send(Command::Edit {
        version: 2,
        edit: Box::new(SceneEdit::Light { index: 0, light }),
    }));
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut notices = Vec::new();
    let mut cpu_frame = None;
    while Instant::now() < deadline && cpu_frame.is_none() {
        notices.extend(worker.take_notices());
        if let Some(f) = worker.take_frame()
            && f.device == Device::Cpu
        {
            cpu_frame = Some(f);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(worker.is_running(), "the render thread survives");
    let frame = cpu_frame.expect("frames from the CPU after the failure");
    assert_eq!(frame.version, 2);
    assert_eq!(cpu_made.load(Ordering::Relaxed), 1);
    assert_eq!(
        notices,
        vec![Notice {
            message: "the GPU `fake` failed; rendering on the CPU".into(),
            now: Some((ModeKind::Spmm, Device::Cpu)),
        }]
    );
    assert!(worker.take_rejected().is_empty());
    // The CPU renders the edited scene: its image is a fresh CPU render of the
    // edited scene after as many frames, bit for bit.
    let mut edited = scene;
    edited.lights[0] = light;
    let mut reference = CoreModes::default()
        .create(
            ModeKind::Spmm,
            Device::Cpu,
            edited,
            8,
            8,
            Prepare::quietly(),
        )
        .expect("the CPU mode");
    meso_render::run_frames(reference.as_mut(), frame.progress.frames, |_, _| {});
    assert!(frame.progress.frames > 0);
    assert_eq!(frame.image().pixels(), reference.image().pixels());
}

/// Core's CPU spmm mode of `scene` at `size` square, made directly (the reference).
fn cpu_mode(scene: &Scene, size: u32) -> Box<dyn RenderMode> {
    CoreModes::default()
        .create(
            ModeKind::Spmm,
            Device::Cpu,
            scene.clone(),
            size,
            size,
            Prepare::quietly(),
        )
        .expect("the CPU mode")
}

/// Loads `scene` at `size` square into the CPU spmm mode as version 1.
fn load(worker: &RenderWorker, scene: &Scene, size: u32) {
    worker.send(Command::Load {
        version: 1,
        scene: Box::new(scene.clone()),
        mode: ModeKind::Spmm,
        device: Device::Cpu,
        width: size,
        height: size,
    });
}

/// A render thread whose frames wait for the test (`Gate`), its go-ahead and
/// frame-start signal, and the Cornell scene.
fn gated_cornell() -> (RenderWorker, mpsc::Sender<()>, mpsc::Receiver<()>, Scene) {
    let (gate, go, starts) = gate();
    let modes = TestModes {
        cpu_made: None,
        gate: Some(gate),
    };
    let worker = RenderWorker::spawn_with(None, Arc::new(modes));
    let path = scenes_dir().join("cornell.toml");
    let scene = meso_render::scene::load_scene(&path).expect("the Cornell scene");
    (worker, go, starts, scene)
}

fn next_frame(worker: &RenderWorker) -> Frame {
    frame_where(worker, |_| true)
}

/// The first frame published that `wanted` accepts (frames before it are dropped).
fn frame_where(worker: &RenderWorker, wanted: impl Fn(&Frame) -> bool) -> Frame {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Some(f) = worker.take_frame().filter(&wanted) {
            return f;
        }
        assert!(Instant::now() < deadline, "no such frame");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// After a load and after a camera edit, the first frame published is a preview:
/// the frame's own samples of one pixel per block, spread over the image, shown
/// before the rest of the frame is rendered, then shown through the denoiser on its
/// grid; the whole frame that follows is a plain render's. With yielding off there
/// is no preview.
#[test]
fn a_restart_shows_a_preview_before_the_whole_frame() {
    const SIZE: u32 = 256;
    let (worker, go, _, scene) = gated_cornell();
    let fresh = |scene: &Scene| cpu_mode(scene, SIZE);
    let stride = preview::stride_for(SIZE, SIZE);
    assert!(stride > 1);
    worker.send(Command::MaxSamples(1));
    load(&worker, &scene, SIZE);
    let mut moved = scene.clone();
    moved.camera.position.x += 0.2;
    for (version, scene) in [(1, &scene), (2, &moved)] {
        if version == 2 {
            worker.send(Command::Edit {
                version,
                edit: Box::new(SceneEdit::Camera(moved.camera)),
            });
        }
        let first = frame_where(&worker, |f| f.version == version);
        assert!(
            first.preview,
            "version {version}: the first frame is a preview"
        );
        assert_eq!(first.progress.min_samples, 0);
        let mut direct = fresh(scene);
        direct.render_preview(stride).expect("a preview");
        assert_eq!(*first.image(), preview::spread(&direct.image(), stride));
        // Then shown through the denoiser on the grid (beside the render thread,
        // while the whole frame waits for the test), which smooths it.
        let denoised = if first.shown.is_some() {
            first
        } else {
            let d = next_frame(&worker);
            assert!(d.preview && Arc::ptr_eq(&d.image(), &first.image()));
            d
        };
        let guides = direct
            .guides(Pass::Preview { stride })
            .expect("preview guides");
        let expected = denoised_preview(&direct.image(), &guides, stride);
        assert!(
            denoised.shown.as_ref().and_then(Picture::on_host) == expected.as_ref(),
            "the preview is not shown through the denoiser on its grid"
        );
        let roughness = |img: &Image| {
            let grid = preview::gather(img, stride);
            let p = grid.pixels();
            p.windows(2).map(|w| (w[0][1] - w[1][1]).abs()).sum::<f32>()
        };
        assert!(
            roughness(&denoised.shown_image()) < 0.5 * roughness(&denoised.image()),
            "the denoised preview is not smoother"
        );
        go.send(()).expect("the thread waits");
        let whole = frame_where(&worker, |f| !f.preview);
        assert!(whole.version == version && whole.progress.min_samples == 1);
        direct.render_frame();
        assert_eq!(whole.image().pixels(), direct.image().pixels());
    }
    worker.send(Command::YieldToEdits(false));
    moved.camera.position.x += 0.2;
    worker.send(Command::Edit {
        version: 3,
        edit: Box::new(SceneEdit::Camera(moved.camera)),
    });
    go.send(()).expect("the thread waits");
    let whole = frame_where(&worker, |f| f.version == 3);
    assert!(!whole.preview && whole.progress.min_samples == 1);
    // A closed gate lets the thread's next frame run, so it can be joined.
    drop(go);
}

/// An emission edit while the view is still denoised is published at once as it
/// is, then through the denoiser's thread (the half-resolution filter, then the full
/// one) while the render thread waits in its next frame; that frame shows the last
/// filtered picture of its version until its own filter is done.
#[test]
fn an_emission_edit_is_shown_at_once_then_filtered_beside_the_next_frame() {
    const SIZE: u32 = 64;
    let (worker, go, starts, scene) = gated_cornell();
    assert_eq!(
        preview::stride_for(SIZE, SIZE),
        1,
        "no preview at this size"
    );
    let mut direct = cpu_mode(&scene, SIZE);
    load(&worker, &scene, SIZE);
    for spp in 1..=2 {
        go.send(()).expect("the thread waits");
        frame_where(&worker, |f| f.progress.min_samples == spp);
        direct.render_frame();
    }
    // The edit arrives while the thread waits in its third frame.
    for _ in 0..3 {
        starts.recv().expect("frames start");
    }
    let light = scene.lights[0].with_emission(scene.lights[0].emission() * 0.5);
    let edit = SceneEdit::Light { index: 0, light };
    worker.send(Command::Edit {
        version: 2,
        edit: Box::new(edit.clone()),
    });
    go.send(()).expect("the thread waits");
    direct.render_frame();
    direct.apply(edit).expect("an emission edit");
    let image = direct.image();
    let guides = direct.guides(Pass::Frame).expect("guides");
    let blended = |image: &Image, samples: u32| {
        let filtered = Denoiser::for_samples(samples)
            .apply(image, &guides)
            .expect("sizes");
        denoise::blend(image, &filtered, denoise::viewport_strength(samples))
    };
    // The fourth frame waits for the test: the filtered picture of the third comes
    // from the denoiser's thread meanwhile.
    let full = blended(&image, 3);
    let filtered = frame_where(&worker, |f| f.version == 2 && f.shown.is_some());
    assert_eq!(*filtered.image(), image);
    assert_eq!(filtered.progress.min_samples, 3);
    let filtered = if *filtered.shown_image() == full {
        filtered
    } else {
        let halved = Denoiser::for_samples(3)
            .apply_halved(&image, &guides.halved())
            .expect("sizes");
        assert_eq!(
            *filtered.shown_image(),
            denoise::blend(&image, &halved, denoise::viewport_strength(3)),
            "the first filtered picture is the halved filter's"
        );
        frame_where(&worker, |f| f.shown_image().as_ref() == &full)
    };
    assert_eq!(*filtered.image(), image);
    go.send(()).expect("the thread waits");
    direct.render_frame();
    let image = direct.image();
    let next = frame_where(&worker, |f| f.progress.min_samples == 4);
    assert_eq!(*next.image(), image);
    let own = blended(&image, 4);
    assert!(
        *next.shown_image() == full || *next.shown_image() == own,
        "the fourth frame shows the third's filtered picture or its own"
    );
    frame_where(&worker, |f| f.shown_image().as_ref() == &own);
    drop(go);
}

/// A filtered picture is published only with a frame of its version that may show
/// one: one that arrives after an edit moved the document on is dropped, and a
/// frame of a newer version never shows an older version's picture.
#[test]
fn a_filtered_picture_never_shows_over_another_version() {
    let publisher = Publisher {
        shared: Arc::new(Mutex::new(Shared {
            frame: None,
            rejected: Vec::new(),
            notices: Vec::new(),
            latest: None,
            filtered: None,
        })),
        wake: None,
    };
    let scene = meso_render::scene::load_scene(&scenes_dir().join("cornell.toml"))
        .expect("the Cornell scene");
    let mut m = cpu_mode(&scene, 8);
    m.render_frame();
    let frame_of = |version| {
        frame_with(
            m.as_ref(),
            Default::default(),
            version,
            Picture::Host(Arc::new(m.image())),
            None,
        )
    };
    let take = || publisher.shared.lock().unwrap().frame.take();
    let job = |version| Job {
        version,
        samples: 1,
        stages: Vec::new(),
    };
    let mut picture = Image::new(8, 8);
    picture.pixels_mut()[0] = [1.0, 2.0, 3.0];
    publisher.frame(frame_of(1), true);
    publisher.filtered(&job(1), picture.clone());
    let filtered = take().expect("a frame");
    assert_eq!(
        filtered.shown.as_ref().and_then(Picture::on_host),
        Some(&picture)
    );
    assert_eq!(filtered.shown_samples, Some(1));
    // The same version's next frame shows it until its own arrives.
    publisher.frame(frame_of(1), true);
    let next = take().expect("a frame");
    assert_eq!(
        next.shown.as_ref().and_then(Picture::on_host),
        Some(&picture)
    );
    assert_eq!(next.shown_samples, Some(1), "an earlier frame's picture");
    // A frame that may not be filtered (a partial one) shows its estimate.
    publisher.frame(frame_of(1), false);
    assert!(take().expect("a frame").shown.is_none());
    publisher.filtered(&job(1), picture.clone());
    assert!(
        take().is_none(),
        "a picture over a frame that may not show one"
    );
    // A newer version: the old picture is neither attached nor published.
    publisher.frame(frame_of(2), true);
    assert!(take().expect("a frame").shown.is_none());
    publisher.filtered(&job(1), picture.clone());
    assert!(take().is_none(), "a stale picture was published");
    publisher.filtered(&job(2), picture.clone());
    assert_eq!(take().expect("a frame").version, 2);
}

/// While a camera edit's preview stands for the film (not every pixel has a sample
/// yet), what the viewport gets is shown through the preview: an emission edit that
/// stops the frame is published at once as the preview's pixels re-weighted, never
/// as a film with unsampled pixels; the frame then completes as one the edit reached
/// before it started.
#[test]
fn while_a_preview_stands_for_the_film_an_edit_is_shown_through_it() {
    const SIZE: u32 = 256;
    let (worker, go, starts, scene) = gated_cornell();
    let stride = preview::stride_for(SIZE, SIZE);
    worker.send(Command::MaxSamples(1));
    load(&worker, &scene, SIZE);
    assert!(frame_where(&worker, |f| f.version == 1).preview);
    starts.recv().expect("the whole frame starts");
    let light = scene.lights[0].with_emission(scene.lights[0].emission() * 0.5);
    let edit = SceneEdit::Light { index: 0, light };
    worker.send(Command::Edit {
        version: 2,
        edit: Box::new(edit.clone()),
    });
    // The frame's first tile runs, sees the edit and stops.
    go.send(()).expect("the thread waits");
    let shown = frame_where(&worker, |f| f.version == 2);
    let mut direct = cpu_mode(&scene, SIZE);
    direct.render_preview(stride).expect("a preview");
    direct.apply(edit).expect("an emission edit");
    assert!(shown.preview, "the edit is shown through the preview");
    assert_eq!(*shown.image(), preview::spread(&direct.image(), stride));
    go.send(()).expect("the thread waits");
    let whole = frame_where(&worker, |f| !f.preview);
    assert_eq!((whole.version, whole.progress.min_samples), (2, 1));
    direct.render_frame();
    assert_eq!(whole.image().pixels(), direct.image().pixels());
    drop(go);
}
