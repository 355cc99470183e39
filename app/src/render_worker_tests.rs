use std::sync::atomic::{AtomicU32, Ordering};

use meso_render::{Diagnostics, EditError, FrameStats, Invalidation, ModeError, SceneEdit};

use super::*;
use crate::mode_maker::CoreModes;

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
    /// Frames go through the gate and render whole (they do not stop).
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
        self.inner.render(pass, None)
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
    let path = crate::studio::default_scene_path().with_file_name("cornell.toml");
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
    let path = crate::studio::default_scene_path().with_file_name("cornell.toml");
    let scene = meso_render::scene::load_scene(&path).expect("the Cornell scene");
    (worker, go, starts, scene)
}

fn next_frame(worker: &RenderWorker) -> Frame {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Some(f) = worker.take_frame() {
            return f;
        }
        assert!(Instant::now() < deadline, "no frame");
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// After a load and after a camera edit, the first frame published is a preview:
/// the frame's own samples of one pixel per block, spread over the image, shown
/// before the rest of the frame is rendered; the whole frame that follows is a
/// plain render's. With yielding off there is no preview.
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
        let mut first = next_frame(&worker);
        assert!(
            first.preview,
            "version {version}: the first frame is a preview"
        );
        // Published as it is, then denoised (the whole frame waits for the test).
        if first.shown.is_none() {
            let denoised = next_frame(&worker);
            assert!(denoised.preview && Arc::ptr_eq(&denoised.image(), &first.image()));
            first = denoised;
        }
        assert_eq!((first.version, first.progress.min_samples), (version, 0));
        let mut direct = fresh(scene);
        direct.render_preview(stride).expect("a preview");
        assert_eq!(*first.image(), preview::spread(&direct.image(), stride));
        // Shown through the denoiser on the grid, which smooths it.
        let denoised = denoised_preview(direct.as_ref(), &direct.image(), stride);
        assert!(
            first.shown.as_deref() == denoised.as_ref(),
            "the preview is not shown through the denoiser on its grid"
        );
        let roughness = |img: &Image| {
            let grid = preview::gather(img, stride);
            let p = grid.pixels();
            p.windows(2).map(|w| (w[0][1] - w[1][1]).abs()).sum::<f32>()
        };
        assert!(
            roughness(&first.shown_image()) < 0.5 * roughness(&first.image()),
            "the denoised preview is not smoother"
        );
        go.send(()).expect("the thread waits");
        let whole = next_frame(&worker);
        assert!(!whole.preview && whole.progress.min_samples == 1);
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
    let whole = next_frame(&worker);
    assert!(!whole.preview && (whole.version, whole.progress.min_samples) == (3, 1));
    // A closed gate lets the thread's next frame run, so it can be joined.
    drop(go);
}

/// An emission edit while the view is still denoised shows at once through the
/// half-resolution filter, and the next frame through the full one.
#[test]
fn an_emission_edit_shows_the_halved_filter_first_then_the_full_one() {
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
        let f = next_frame(&worker);
        assert_eq!((f.version, f.progress.min_samples), (1, spp));
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
    let denoiser = Denoiser::for_samples(3);
    let strength = denoise::viewport_strength(3);
    // Frame 3 is published with version 1, then the edit's quick picture; frame 4
    // waits for the test.
    let quick = std::iter::repeat_with(|| next_frame(&worker))
        .find(|f| f.version == 2)
        .expect("a frame of the edit");
    assert_eq!(quick.progress.min_samples, 3);
    assert_eq!(*quick.image(), image);
    let halved = denoiser
        .apply_halved(&image, &guides.halved())
        .expect("sizes");
    assert_eq!(
        *quick.shown_image(),
        denoise::blend(&image, &halved, strength)
    );
    go.send(()).expect("the thread waits");
    let full = next_frame(&worker);
    assert_eq!((full.version, full.progress.min_samples), (2, 4));
    direct.render_frame();
    let image = direct.image();
    let filtered = Denoiser::for_samples(4)
        .apply(&image, &guides)
        .expect("sizes");
    let strength = denoise::viewport_strength(4);
    assert_eq!(
        *full.shown_image(),
        denoise::blend(&image, &filtered, strength)
    );
    drop(go);
}
