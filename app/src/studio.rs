//! Meso Studio's main window: the material editor over the progressive viewport.
//! Menus (File, Edit, View) with shortcuts, the lights and scene panel (left), the
//! material panel (right), the viewport (centre) and the status bar. The studio owns
//! the document and sends every edit to the render thread as a versioned message;
//! it shows the newest finished frame and never waits for one. Switching the render
//! mode prepares the new mode as a background job (progress, Cancel) while the old
//! one keeps rendering; the compare view renders a reference beside the live image.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use egui::{Key, KeyboardShortcut, Modifiers, Ui};
use meso_materials::image::Image;
use meso_materials::metrics::{self, Comparison};
use meso_materials::spmm::SpmmMaterial;
use meso_materials::spmm::pack::ResidualPrecision;
use meso_render::geometry::{BrushUnits, SceneBvh, brush, pick};
use meso_render::scene::mesh::{Placement, load_obj};
use meso_render::scene::{Environment, Material, Scene, load_scene};
use meso_render::{
    Device, ModeError, ModeKind, Prepare, RenderMode, SceneEdit, Unrenderable, Unsupported,
};

use crate::disabled::Disabled;
use crate::document::{Document, read_pack_file};
use crate::explorer::Explorer;
use crate::jobs::Job;
use crate::library::{self, Entry, EntryKind, Library, LibraryRequest, ThumbnailCache};
use crate::material_panel::MaterialPanel;
use crate::mode_maker::{ModeMaker, core_modes, mode_name};
use crate::reference::{Reference, ReferenceRenderer};
use crate::render_worker::{Command, RenderWorker};
use crate::scene_panel::{self, PanelState, Request, Switching};
use crate::viewport::{CompareLabels, Viewport};

pub const UNDO: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::Z);
pub const REDO: KeyboardShortcut =
    KeyboardShortcut::new(Modifiers::COMMAND.plus(Modifiers::SHIFT), Key::Z);
pub const SAVE: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::S);
pub const SAVE_AS: KeyboardShortcut =
    KeyboardShortcut::new(Modifiers::COMMAND.plus(Modifiers::SHIFT), Key::S);
pub const OPEN_PACK: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::O);
pub const EXPORT: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::E);

/// The scene the README's first command opens.
/// The mode and device a document's scene file names.
fn doc_scene_mode(doc: Option<&Document>) -> (ModeKind, Device) {
    doc.map_or((ModeKind::Spmm, Device::Cpu), |d| {
        (d.scene.render.mode, d.scene.render.device)
    })
}

pub fn default_scene_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/scenes/default.toml")
}

/// What survives a restart.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct Settings {
    pub recent_packs: Vec<PathBuf>,
    pub recent_scenes: Vec<PathBuf>,
    pub exposure: f64,
    /// Render resolution relative to the viewport's pixels.
    pub resolution: f32,
    /// Samples per pixel after which the renderer rests.
    pub max_samples: u32,
    /// Frame, ray and latency timings in the status bar.
    pub show_timings: bool,
    /// The compare view: live image left of the divider, a reference right of it.
    pub compare: bool,
    /// Samples per pixel the compare view's reference is refined to.
    pub reference_spp: u32,
    /// The first frames through the viewport denoiser (saved images and the compare
    /// view's figures are always the unfiltered estimate).
    pub denoise: bool,
    /// The material library window is open.
    pub show_library: bool,
    /// Scenes that name the spmm mode on the CPU open on the GPU when wgpu offers a
    /// hardware adapter (not a software one such as llvmpipe) that renders them; the
    /// Device switch goes back to the CPU on request.
    pub gpu_by_default: bool,
    /// The designer's own library folders (the shipped packs are always listed).
    pub library_folders: Vec<PathBuf>,
    /// Where library thumbnails are cached (`None`: `library::default_cache_dir`).
    pub thumbnail_cache: Option<PathBuf>,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            recent_packs: Vec::new(),
            recent_scenes: Vec::new(),
            exposure: 0.0,
            resolution: 0.5,
            max_samples: 1024,
            show_timings: true,
            compare: false,
            reference_spp: 256,
            denoise: true,
            show_library: false,
            gpu_by_default: true,
            library_folders: Vec::new(),
            thumbnail_cache: None,
        }
    }
}

impl Settings {
    /// The defaults, with the GPU default off: tests open scenes on the device they
    /// name, never on whatever GPU the machine running them has.
    #[cfg(test)]
    pub fn for_tests() -> Self {
        Self {
            gpu_by_default: false,
            ..Self::default()
        }
    }
}

/// A library file read for a material slot: its path, the material, and (for a
/// pack) its residual precision.
type Assigned = (PathBuf, Material, ResidualPrecision);

/// "loading default.toml": what a background job does, for the status bar.
fn job_name(verb: &str, path: &Path) -> String {
    let file = path.file_name().unwrap_or(path.as_os_str());
    format!("{verb} {}", file.to_string_lossy())
}

fn remember(list: &mut Vec<PathBuf>, path: &Path) {
    list.retain(|p| p != path);
    list.insert(0, path.to_path_buf());
    list.truncate(8);
}

/// Least time between two comparisons of the live image with the reference.
const MEASURE_EVERY: Duration = Duration::from_millis(250);

/// A mode being prepared to replace the current one.
struct Switch {
    kind: ModeKind,
    device: Device,
    /// What the new mode renders without.
    disabled: Disabled,
    /// The document version of the scene it is prepared for.
    version: u64,
    job: Job<Result<Box<dyn RenderMode>, ModeError>>,
    /// Edits made while it is prepared, already translated for it: replayed after
    /// it is installed, so it ends at the document's current scene.
    replay: Vec<(u64, SceneEdit)>,
    /// A preparation of the current mode for new geometry (`prepares_geometry`): the
    /// mode on screen still shows the old meshes, so cancelling it cannot simply keep
    /// that mode.
    for_geometry: bool,
}

/// The compare view's numbers and the two images they were computed from.
#[derive(Clone)]
pub struct Measured {
    pub reference: Arc<Image>,
    pub live: Arc<Image>,
    pub reference_spp: u32,
    pub comparison: Comparison,
}

/// The edit a mode should get for a document edit (already applied to the document's
/// `scene`), or `None` if it only concerns parts the mode renders without. A light
/// added while a mode renders without some lights is checked: if the mode cannot
/// render it either, it is left out too.
fn route(
    maker: &dyn ModeMaker,
    mode: (ModeKind, Device),
    disabled: &mut Disabled,
    scene: &Scene,
    edit: SceneEdit,
) -> Option<SceneEdit> {
    if let SceneEdit::AddLight(_) = &edit
        && (!disabled.is_empty() || mode != (ModeKind::Spmm, Device::Cpu))
    {
        let mode_scene = disabled.scene_for_mode(scene);
        // The new light is the last of the document's and of the mode's.
        let last = mode_scene.lights.len().saturating_sub(1);
        if let Err(ModeError::Unsupported(u)) = maker.supports(mode.0, mode.1, &mode_scene)
            && u.parts
                .iter()
                .any(|p| matches!(p, Unrenderable::Light { index, .. } if *index == last))
        {
            disabled.disable_light(scene.lights.len().saturating_sub(1));
            return None;
        }
    }
    disabled.translate(edit)
}

fn ctx_repaint_after(ctx: Option<&egui::Context>, after: Duration) {
    if let Some(ctx) = ctx {
        ctx.request_repaint_after(after);
    }
}

/// Statistics of the newest frame, for the status bar.
#[derive(Clone, Copy, Debug, Default)]
pub struct Latency {
    /// Edit sent to the first frame rendered after it, in milliseconds.
    pub last_edit_to_frame_ms: Option<f64>,
}

pub struct Studio {
    pub doc: Option<Document>,
    pub settings: Settings,
    worker: RenderWorker,
    viewport: Viewport,
    pub material_panel: MaterialPanel,
    /// Where render modes come from (core's registry unless a test injects one).
    maker: Arc<dyn ModeMaker>,
    /// The mode rendering now and what it renders without.
    mode: (ModeKind, Device),
    disabled: Disabled,
    /// A mode being prepared to replace it.
    switch: Option<Switch>,
    /// A mode that cannot render some lights: switch without them, or stay?
    unsupported_prompt: Option<Unsupported>,
    /// The mode an opened scene asks for (`[render] mode/device`), requested once the
    /// scene is loaded into the renderer in the spmm mode.
    scene_mode: Option<(ModeKind, Device)>,
    /// Why the last switch did not happen, shown until dismissed.
    pub mode_message: Option<String>,
    /// Shipped environment maps, the map read last (file, image), and the last
    /// environment used (turning it on again brings it back).
    environments: Vec<(String, PathBuf)>,
    env_source: Option<(PathBuf, Arc<Image>)>,
    last_environment: Option<Environment>,
    env_job: Option<Job<(PathBuf, Arc<Image>)>>,
    /// The compare view's reference renderer, its newest image, and the metrics.
    reference: Option<ReferenceRenderer>,
    reference_latest: Option<Reference>,
    measure_job: Option<Job<Measured>>,
    measured: Option<Measured>,
    /// When the last comparison started and what it compared (live frame time,
    /// reference image number).
    measure_started: Instant,
    measure_key: Option<(Instant, u64)>,
    /// For clicks: the scene's geometry (rebuilt when meshes change).
    bvh: Option<SceneBvh>,
    /// Full-quality render size and the size the renderer has now.
    full_size: (u32, u32),
    render_size: (u32, u32),
    moving: bool,
    /// Edits sent and not yet seen in a frame: (version, when).
    in_flight: VecDeque<(u64, Instant)>,
    pub latency: Latency,
    /// The last error, shown until dismissed.
    pub error: Option<String>,
    /// Unsaved-changes prompt on quit.
    quit_prompt: bool,
    allow_close: bool,
    explorer: Option<Explorer>,
    ui_frame_ms: f64,
    repaint: Option<egui::Context>,
    /// The window title last sent (sent again only when it changes).
    shown_title: String,
    /// (`Document::dirty_key`, dirty) of the last check.
    dirty_cache: ((usize, usize), bool),
    /// Loads in progress: a scene (with its BVH), a pack.
    scene_job: Option<Job<(PathBuf, Scene, SceneBvh)>>,
    pack_job: Option<Job<(PathBuf, Arc<SpmmMaterial>, ResidualPrecision)>>,
    /// The material library (made when first shown) and a library file being read to
    /// go on material slot `.0`.
    library: Option<Library>,
    assign_job: Option<(usize, Job<Assigned>)>,
    /// The material of the object last clicked in the viewport: what the library
    /// assigns to (the edited pack's object until a click).
    pub selected_material: Option<usize>,
}

impl Studio {
    /// Opens `scene` (or the default scene); a scene that fails to load leaves an empty
    /// studio with the error shown.
    pub fn new(repaint: Option<egui::Context>, scene: Option<PathBuf>, settings: Settings) -> Self {
        Self::with_maker(repaint, scene, settings, core_modes())
    }

    /// `new` with render modes made by `maker`.
    pub fn with_maker(
        repaint: Option<egui::Context>,
        scene: Option<PathBuf>,
        settings: Settings,
        maker: Arc<dyn ModeMaker>,
    ) -> Self {
        let mut s = Self {
            doc: None,
            settings,
            worker: RenderWorker::spawn_with(repaint.clone(), Arc::clone(&maker)),
            viewport: Viewport::default(),
            material_panel: MaterialPanel::default(),
            maker,
            mode: (ModeKind::Spmm, Device::Cpu),
            disabled: Disabled::default(),
            switch: None,
            unsupported_prompt: None,
            scene_mode: None,
            mode_message: None,
            environments: scene_panel::shipped_environments(),
            env_source: None,
            last_environment: None,
            env_job: None,
            reference: None,
            reference_latest: None,
            measure_job: None,
            measured: None,
            measure_started: Instant::now(),
            measure_key: None,
            bvh: None,
            full_size: (0, 0),
            render_size: (0, 0),
            moving: false,
            in_flight: VecDeque::new(),
            latency: Latency::default(),
            error: None,
            quit_prompt: false,
            allow_close: false,
            explorer: None,
            ui_frame_ms: 0.0,
            repaint,
            shown_title: String::new(),
            dirty_cache: ((0, 0), false),
            scene_job: None,
            pack_job: None,
            library: None,
            assign_job: None,
            selected_material: None,
        };
        s.set_max_samples(s.settings.max_samples);
        s.worker.send(Command::Denoise(s.settings.denoise));
        s.open_scene(&scene.unwrap_or_else(default_scene_path));
        s
    }

    /// The window is drawn by `render_state`'s wgpu renderer on the device of
    /// `shared`, which the GPU modes share (`window_device::modes_for`): their frames
    /// are shown from there. `None`: frames reach the window through the host.
    pub fn drawn_by(
        mut self,
        window: Option<(eframe::egui_wgpu::RenderState, meso_gpu::GpuContext)>,
    ) -> Self {
        if let Some((rs, shared)) = window {
            self.viewport.set_window(rs, &shared);
        }
        self
    }

    /// Whether the viewport's image was shown without leaving the device.
    pub fn shows_frames_from_device(&self) -> bool {
        self.viewport.shows_from_device()
    }

    /// Stops the renderer after this many samples per pixel (tests pin images).
    pub fn set_max_samples(&self, n: u32) {
        self.worker.send(Command::MaxSamples(n));
    }

    /// The newest frame on screen.
    #[cfg(test)]
    pub fn frame(&self) -> Option<&crate::render_worker::Frame> {
        self.viewport.frame()
    }

    /// Starts loading a scene in the background; the current one stays until it is
    /// ready.
    pub fn open_scene(&mut self, path: &Path) {
        let path = path.to_path_buf();
        let name = job_name("loading", &path);
        self.scene_job = Some(Job::spawn(name, self.repaint.clone(), move || {
            let scene = load_scene(&path).map_err(|e| e.to_string())?;
            let bvh = SceneBvh::build(&scene.meshes);
            Ok((path, scene, bvh))
        }));
    }

    /// Whether a load is in progress.
    pub fn busy(&self) -> bool {
        self.scene_job.is_some()
            || self.pack_job.is_some()
            || self.env_job.is_some()
            || self.assign_job.is_some()
    }

    /// The mode rendering now.
    pub fn mode(&self) -> (ModeKind, Device) {
        self.mode
    }

    /// Whether a mode is being prepared to replace the current one.
    pub fn switching(&self) -> bool {
        self.switch.is_some()
    }

    /// Lights and ambient the current mode renders without.
    pub fn disabled(&self) -> &Disabled {
        &self.disabled
    }

    /// The compare view's latest numbers and the two images they come from.
    pub fn measured(&self) -> Option<&Measured> {
        self.measured.as_ref()
    }

    /// Asks for another render mode: it is checked first (`supports`); a mode that
    /// is not built or cannot render a material says so and the current mode stays;
    /// one that cannot render some lights asks whether to switch without them;
    /// otherwise the new mode is prepared in the background. Choosing the current
    /// mode stops a switch in progress.
    pub fn request_mode(&mut self, kind: ModeKind, device: Device) {
        self.unsupported_prompt = None;
        self.mode_message = None;
        if let Some(sw) = self.switch.take() {
            sw.job.cancel();
        }
        let Some(doc) = &self.doc else { return };
        if (kind, device) == self.mode {
            return;
        }
        let staying = mode_name(self.mode.0, self.mode.1);
        match self.maker.supports(kind, device, &doc.scene) {
            Ok(()) => self.start_switch(kind, device, Disabled::default()),
            Err(ModeError::Unsupported(u)) if u.only_lights() => self.unsupported_prompt = Some(u),
            Err(e) => self.mode_message = Some(format!("{e}; staying in {staying}.")),
        }
    }

    /// The prompt's "switch with these lights disabled": asks again (the lights may
    /// have changed while the prompt was open) and leaves out what the mode cannot
    /// render, if that is only lights and the ambient term.
    fn switch_without_lights(&mut self, kind: ModeKind, device: Device) {
        self.unsupported_prompt = None;
        let Some(doc) = &self.doc else { return };
        match self.maker.supports(kind, device, &doc.scene) {
            Ok(()) => self.start_switch(kind, device, Disabled::default()),
            Err(ModeError::Unsupported(u)) if u.only_lights() => {
                self.start_switch(kind, device, Disabled::from_unsupported(&u))
            }
            Err(e) => {
                let staying = mode_name(self.mode.0, self.mode.1);
                self.mode_message = Some(format!("{e}; staying in {staying}."));
            }
        }
    }

    /// Prepares `kind` on `device` in the background for the document's scene
    /// without the `disabled` parts, at the current render size.
    fn start_switch(&mut self, kind: ModeKind, device: Device, disabled: Disabled) {
        let Some(doc) = &self.doc else { return };
        let scene = disabled.scene_for_mode(&doc.scene);
        let (w, h) = if self.render_size == (0, 0) {
            (self.full_size.0.max(16), self.full_size.1.max(16))
        } else {
            self.render_size
        };
        let maker = Arc::clone(&self.maker);
        let name = format!("preparing {}", mode_name(kind, device));
        let job = Job::spawn_controlled(name, self.repaint.clone(), move |c| {
            let report = |stage: &str, fraction: f32| c.report(stage, fraction);
            let prepare = Prepare::new(&report, c.cancel_flag());
            Ok(maker.create(kind, device, scene, w, h, prepare))
        });
        self.switch = Some(Switch {
            kind,
            device,
            disabled,
            version: doc.version,
            job,
            replay: Vec::new(),
            for_geometry: false,
        });
    }

    /// Stops preparing the new mode; the current one stays.
    pub fn cancel_switch(&mut self) {
        if let Some(sw) = &self.switch {
            sw.job.cancel();
        }
    }

    /// Installs a prepared mode: the render thread swaps to it (the old mode renders
    /// until then), then gets the edits made while it was prepared.
    fn poll_switch(&mut self) {
        let Some(r) = self.switch.as_ref().and_then(|s| s.job.poll()) else {
            return;
        };
        let Some(sw) = self.switch.take() else {
            return;
        };
        let target = mode_name(sw.kind, sw.device);
        let staying = mode_name(self.mode.0, self.mode.1);
        match r {
            Ok(Ok(mode)) => {
                self.worker.send(Command::Install {
                    version: sw.version,
                    mode,
                });
                for (version, edit) in sw.replay {
                    self.worker.send(Command::Edit {
                        version,
                        edit: Box::new(edit),
                    });
                }
                if let Some(doc) = &self.doc {
                    self.worker.send(Command::Unchanged {
                        version: doc.version,
                    });
                    self.in_flight.push_back((doc.version, Instant::now()));
                }
                self.mode = (sw.kind, sw.device);
                self.disabled = sw.disabled;
            }
            Ok(Err(ModeError::Cancelled(_))) if sw.for_geometry => {
                // The mode on screen has the old meshes: show the new ones in the
                // spmm mode, which needs no precomputation, rather than a stale view.
                self.mode_message = Some(format!(
                    "the {target} preparation for the new meshes was cancelled; showing them in spmm."
                ));
                self.start_switch(ModeKind::Spmm, self.mode.1, Disabled::default());
            }
            Ok(Err(ModeError::Cancelled(_))) => {}
            Ok(Err(e)) => {
                self.mode_message = Some(format!(
                    "switching to {target} failed: {e}; staying in {staying}."
                ))
            }
            Err(e) => {
                self.mode_message = Some(format!(
                    "switching to {target} failed: {e}; staying in {staying}."
                ))
            }
        }
    }

    /// Reads an environment map in the background; it lights the scene when ready.
    pub fn open_environment(&mut self, path: &Path) {
        let path = path.to_path_buf();
        let name = job_name("reading", &path);
        self.env_job = Some(Job::spawn(name, self.repaint.clone(), move || {
            let map = meso_materials::image::read_image(&path)
                .map_err(|e| format!("`{}`: {e}", path.display()))?;
            if let Some(p) = meso_render::environment::check_map(&map) {
                return Err(format!("`{}`: {p}", path.display()));
            }
            Ok((path, Arc::new(map)))
        }));
    }

    /// Turns the environment on: the last one used, or the first shipped map.
    fn environment_on(&mut self) {
        if let Some(e) = self.last_environment.clone() {
            self.edit(SceneEdit::Environment(Some(e)));
        } else if let Some((_, path)) = self.environments.first().cloned() {
            self.open_environment(&path);
        } else {
            self.error = Some("no environment map is shipped: pick a file".into());
        }
    }

    fn environment_dialog(&mut self) {
        if let Some(p) = rfd::FileDialog::new()
            .add_filter("environment map", &["exr", "hdr", "png"])
            .pick_file()
        {
            self.open_environment(&p);
        }
    }

    /// Installs finished loads.
    fn poll_jobs(&mut self) {
        self.poll_switch();
        if let Some(r) = self.env_job.as_ref().and_then(|j| j.poll()) {
            self.env_job = None;
            match r {
                Ok((path, map)) => {
                    let env = match self.doc.as_ref().and_then(|d| d.scene.environment.clone()) {
                        Some(e) => Environment {
                            map: Arc::clone(&map),
                            ..e
                        },
                        None => Environment {
                            map: Arc::clone(&map),
                            strength: 1.0,
                            rotate_y_deg: 0.0,
                            mis: true,
                        },
                    };
                    self.env_source = Some((path, map));
                    self.edit(SceneEdit::Environment(Some(env)));
                    if let Some(doc) = &mut self.doc {
                        doc.close_group();
                    }
                }
                Err(e) => self.error = Some(e),
            }
        }
        if let Some(r) = self.scene_job.as_ref().and_then(|j| j.poll()) {
            self.scene_job = None;
            match r {
                Ok((path, scene, bvh)) => {
                    remember(&mut self.settings.recent_scenes, &path);
                    self.bvh = Some(bvh);
                    // Versions keep increasing across documents, so a frame of the
                    // previous scene never passes for one of this.
                    let mut doc = Document::new(scene, Some(path));
                    doc.version = self.doc.as_ref().map_or(1, |d| d.version + 1);
                    self.doc = Some(doc);
                    self.in_flight.clear();
                    self.material_panel = MaterialPanel::default();
                    self.selected_material = None;
                    // A new scene opens in the spmm mode, which renders everything; the
                    // mode the scene names is asked for once it is loaded (below).
                    self.scene_mode = Some(doc_scene_mode(self.doc.as_ref()))
                        .map(|m| self.default_device(m))
                        .filter(|m| *m != (ModeKind::Spmm, Device::Cpu));
                    if let Some(sw) = self.switch.take() {
                        sw.job.cancel();
                    }
                    self.unsupported_prompt = None;
                    self.mode = (ModeKind::Spmm, Device::Cpu);
                    self.disabled = Disabled::default();
                    // The viewport loads it into the renderer at its size.
                    self.render_size = (0, 0);
                }
                Err(e) => self.error = Some(e),
            }
        }
        if let Some(r) = self.assign_job.as_ref().and_then(|(_, j)| j.poll()) {
            let (index, _) = self.assign_job.take().expect("polled above");
            let assigned = r.and_then(|(path, material, precision)| {
                let doc = self.doc.as_mut().ok_or("no scene is open")?;
                let is_pack = matches!(material, Material::Spmm { .. });
                let edit = doc.assign(index, material, &path, precision)?;
                Ok((path, edit, is_pack))
            });
            match assigned {
                Ok((path, edit, is_pack)) => {
                    if is_pack {
                        remember(&mut self.settings.recent_packs, &path);
                    }
                    self.material_panel = MaterialPanel::default();
                    self.send(edit);
                }
                Err(e) => self.error = Some(e),
            }
        }
        if let Some(r) = self.pack_job.as_ref().and_then(|j| j.poll()) {
            self.pack_job = None;
            let installed = r.and_then(|(path, material, precision)| {
                let doc = self.doc.as_mut().ok_or("no scene is open")?;
                let edit = doc.install_pack(&path, material, precision)?;
                Ok((path, edit))
            });
            match installed {
                Ok((path, edit)) => {
                    remember(&mut self.settings.recent_packs, &path);
                    self.material_panel = MaterialPanel::default();
                    self.send(edit);
                }
                Err(e) => self.error = Some(e),
            }
        }
    }

    /// The mode a newly opened scene asks for: the spmm mode on the CPU moves to the
    /// GPU when `gpu_by_default` is set, wgpu offers a hardware adapter and the GPU
    /// renders the scene; anything else as the scene names it.
    fn default_device(&self, named: (ModeKind, Device)) -> (ModeKind, Device) {
        let Some(doc) = &self.doc else { return named };
        let gpu = (ModeKind::Spmm, Device::Gpu);
        if named == (ModeKind::Spmm, Device::Cpu)
            && self.settings.gpu_by_default
            && self.maker.supports(gpu.0, gpu.1, &doc.scene).is_ok()
            && meso_gpu::hardware_adapter().is_some()
        {
            gpu
        } else {
            named
        }
    }

    fn load_into_renderer(&mut self, size: (u32, u32)) {
        let Some(doc) = &self.doc else { return };
        self.render_size = size;
        self.worker.send(Command::Load {
            version: doc.version,
            scene: Box::new(self.disabled.scene_for_mode(&doc.scene)),
            mode: self.mode.0,
            device: self.mode.1,
            width: size.0,
            height: size.1,
        });
        self.in_flight.push_back((doc.version, Instant::now()));
        // After the first load, so an installed mode always follows the Load.
        if let Some((kind, device)) = self.scene_mode.take() {
            self.request_mode(kind, device);
        }
    }

    /// Applies an edit to the document (one undo group while a drag lasts) and sends
    /// it to the renderer.
    pub fn edit(&mut self, edit: SceneEdit) {
        let Some(doc) = &mut self.doc else { return };
        match doc.apply(&edit) {
            Ok(()) => self.send(edit),
            Err(e) => self.error = Some(e.to_string()),
        }
    }

    /// A view change (camera, size, moving): sent, not undoable.
    fn view(&mut self, edit: SceneEdit) {
        let Some(doc) = &mut self.doc else { return };
        if doc.apply_view(&edit).is_ok() {
            self.send(edit);
        }
    }

    /// Sends an edit already applied to the document to the renderer, translated
    /// for what the mode renders without (and noted for a mode being prepared).
    fn send(&mut self, edit: SceneEdit) {
        let Some(doc) = &self.doc else { return };
        if let SceneEdit::Meshes(m) = &edit {
            self.bvh = Some(SceneBvh::build(m));
            // A mode whose preparation depends on the geometry is prepared again in the
            // background, with progress and Cancel, for the edited scene (which the
            // document already holds), instead of recomputing on the render thread.
            let (kind, device, disabled) = match &self.switch {
                Some(sw) => (sw.kind, sw.device, sw.disabled.clone()),
                None => (self.mode.0, self.mode.1, self.disabled.clone()),
            };
            if kind.prepares_geometry() {
                if let Some(sw) = self.switch.take() {
                    sw.job.cancel();
                }
                self.start_switch(kind, device, disabled);
                if let Some(sw) = &mut self.switch {
                    sw.for_geometry = true;
                }
                return;
            }
        }
        let version = doc.version;
        if let Some(sw) = &mut self.switch
            && let Some(e) = route(
                self.maker.as_ref(),
                (sw.kind, sw.device),
                &mut sw.disabled,
                &doc.scene,
                edit.clone(),
            )
        {
            sw.replay.push((version, e));
        }
        let command = match route(
            self.maker.as_ref(),
            self.mode,
            &mut self.disabled,
            &doc.scene,
            edit,
        ) {
            Some(e) => Command::Edit {
                version,
                edit: Box::new(e),
            },
            None => Command::Unchanged { version },
        };
        self.worker.send(command);
        self.in_flight.push_back((version, Instant::now()));
    }

    pub fn undo(&mut self) {
        if let Some(doc) = &mut self.doc {
            for e in doc.undo() {
                self.send(e);
            }
        }
    }

    pub fn redo(&mut self) {
        if let Some(doc) = &mut self.doc {
            for e in doc.redo() {
                self.send(e);
            }
        }
    }

    /// Saves the pack to `path`; on failure the error is shown and the edits stay.
    pub fn save_pack_as(&mut self, path: &Path) -> bool {
        let Some(doc) = &mut self.doc else {
            return false;
        };
        match doc.save_pack(path) {
            Ok(()) => {
                remember(&mut self.settings.recent_packs, path);
                true
            }
            Err(e) => {
                self.error = Some(format!("saving failed, the edits are kept: {e}"));
                false
            }
        }
    }

    fn save(&mut self) -> bool {
        let path = self
            .doc
            .as_ref()
            .and_then(|d| d.pack.as_ref())
            .and_then(|p| p.path.clone());
        match path {
            Some(p) => self.save_pack_as(&p),
            None => self.save_as_dialog(),
        }
    }

    fn save_as_dialog(&mut self) -> bool {
        match rfd::FileDialog::new()
            .add_filter("SPMM pack", &["spmm"])
            .save_file()
        {
            Some(p) => self.save_pack_as(&p),
            None => false,
        }
    }

    /// Starts reading a pack in the background; it replaces the edited one when ready.
    pub fn open_pack(&mut self, path: &Path) {
        let path = path.to_path_buf();
        let name = job_name("reading", &path);
        self.pack_job = Some(Job::spawn(name, self.repaint.clone(), move || {
            let (material, precision) = read_pack_file(&path)?;
            Ok((path, material, precision))
        }));
    }

    /// A file dropped on the window: a scene `.toml` opens; a `.spmm` pack or a MERL
    /// `.binary` goes on the selected object (`assign_file`); a BTF is named with what
    /// to do instead.
    pub fn open_dropped(&mut self, path: &Path) {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("toml") => self.open_scene(path),
            _ => match EntryKind::of(path) {
                Some(kind) => self.assign_file(kind, path),
                None => {
                    self.error = Some(format!(
                        "`{}`: drop a .spmm pack, a MERL .binary or a scene .toml",
                        path.display()
                    ))
                }
            },
        }
    }

    /// Makes the pack on material slot `index` the one the material panel edits, or
    /// says why not.
    pub fn edit_pack(&mut self, index: usize) {
        let Some(doc) = self.doc.as_mut() else {
            return;
        };
        match doc.edit_pack(index) {
            // As when a pack is put on an object: the panel's cluster, texel and mask
            // belonged to the other pack.
            Ok(()) => self.material_panel = MaterialPanel::default(),
            Err(e) => self.error = Some(e),
        }
    }

    /// The material slot the library and dropped materials go on: the object last
    /// clicked, else the edited pack's, else the first.
    pub fn target_material(&self) -> Option<usize> {
        let doc = self.doc.as_ref()?;
        let count = doc.scene.materials.len();
        self.selected_material
            .filter(|&i| i < count)
            .or(doc.pack.as_ref().map(|p| p.material))
            .or((count > 0).then_some(0))
    }

    /// "leather (material 0)": the target as the library names it.
    fn target_name(&self) -> String {
        match (self.doc.as_ref(), self.target_material()) {
            (Some(doc), Some(i)) => {
                let name = doc.scene.material_names.get(i).map_or("?", |n| n.as_str());
                format!(
                    "{name} (material {i}, {})",
                    doc.scene.materials[i].kind_name()
                )
            }
            _ => "no object (open a scene)".into(),
        }
    }

    /// Reads a library file in the background and puts its material on the target
    /// slot when ready (one undo step); a BTF is refused with what to do instead.
    pub fn assign_file(&mut self, kind: EntryKind, path: &Path) {
        if kind == EntryKind::Btf {
            self.error = Some(library::btf_message(path));
            return;
        }
        let (Some(doc), Some(index)) = (self.doc.as_ref(), self.target_material()) else {
            self.error = Some("open a scene first: a material goes on one of its objects".into());
            return;
        };
        let slot = doc.scene.materials[index].clone();
        let path = path.to_path_buf();
        let name = job_name("reading", &path);
        let job = Job::spawn(name, self.repaint.clone(), move || {
            let bytes = std::fs::read(&path).map_err(|e| format!("`{}`: {e}", path.display()))?;
            let (material, precision) = library::material_from(kind, &path, &bytes, Some(&slot))?;
            Ok((path, material, precision))
        });
        self.assign_job = Some((index, job));
    }

    /// The library's cache of thumbnails.
    fn thumbnail_cache(&self) -> ThumbnailCache {
        ThumbnailCache::new(
            self.settings
                .thumbnail_cache
                .clone()
                .unwrap_or_else(library::default_cache_dir),
        )
    }

    /// The shipped folder, then the designer's.
    fn library_folders(&self) -> Vec<PathBuf> {
        std::iter::once(library::shipped_dir())
            .chain(self.settings.library_folders.iter().cloned())
            .collect()
    }

    /// The material library (opened, listing its folders and starting thumbnails).
    pub fn library(&mut self) -> &mut Library {
        if self.library.is_none() {
            let lib = Library::open(
                &self.library_folders(),
                self.thumbnail_cache(),
                self.repaint.clone(),
            );
            self.library = Some(lib);
        }
        self.library.as_mut().expect("made above")
    }

    /// Adds a folder to the library (remembered across runs).
    pub fn add_library_folder(&mut self, dir: &Path) {
        if !self.settings.library_folders.iter().any(|f| f == dir) {
            self.settings.library_folders.push(dir.to_path_buf());
        }
        let folders = self.library_folders();
        self.library().rescan(&folders);
    }

    fn library_window(&mut self, ctx: &egui::Context) {
        if !self.settings.show_library {
            return;
        }
        let target = self.target_name();
        let mut open = true;
        let mut requests = Vec::new();
        let lib = self.library();
        egui::Window::new("Material library")
            .open(&mut open)
            .default_pos([290.0, 60.0])
            .default_size([420.0, 520.0])
            .vscroll(true)
            .show(ctx, |ui| requests = lib.show(ui, &target));
        self.settings.show_library &= open;
        for r in requests {
            match r {
                LibraryRequest::Assign(Entry { kind, path, .. }) => self.assign_file(kind, &path),
                LibraryRequest::AddFolderDialog => {
                    if let Some(dir) = rfd::FileDialog::new().pick_folder() {
                        self.add_library_folder(&dir);
                    }
                }
                LibraryRequest::RemoveFolder(dir) => {
                    self.settings.library_folders.retain(|f| *f != dir);
                    let folders = self.library_folders();
                    self.library().rescan(&folders);
                }
            }
        }
    }

    /// Writes the frame on screen (EXR: linear; PNG: after the viewport's exposure).
    pub fn export_frame(&mut self, path: &Path) {
        let Some(frame) = self.viewport.frame() else {
            self.error = Some("no frame has been rendered yet".into());
            return;
        };
        if let Err(e) =
            meso_materials::image::write_image(path, &frame.image(), self.settings.exposure)
        {
            self.error = Some(format!("exporting failed: {e}"));
        }
    }

    fn replace_mesh(&mut self, path: &Path) {
        let Some(doc) = &self.doc else { return };
        let Some(pack) = &doc.pack else { return };
        let placement = Placement {
            scale: 1.0,
            rotation: glam::DMat3::IDENTITY,
            translate: glam::DVec3::ZERO,
        };
        match load_obj(path, &placement, pack.material) {
            Ok(mesh) => {
                let mut meshes: Vec<_> = doc
                    .scene
                    .meshes
                    .iter()
                    .filter(|m| m.material != pack.material)
                    .cloned()
                    .collect();
                meshes.insert(0, mesh);
                self.edit(SceneEdit::Meshes(meshes));
            }
            Err(e) => self.error = Some(e.to_string()),
        }
    }

    /// `Document::dirty`, recomputed only when the packs involved change.
    fn dirty(&mut self) -> bool {
        let Some(doc) = &self.doc else { return false };
        let key = doc.dirty_key();
        if self.dirty_cache.0 != key {
            self.dirty_cache = (key, doc.dirty());
        }
        self.dirty_cache.1
    }

    fn title(&mut self) -> String {
        let dirty = self.dirty();
        let Some(doc) = &self.doc else {
            return "Meso Studio".into();
        };
        let name = doc
            .pack
            .as_ref()
            .and_then(|p| p.path.as_ref())
            .and_then(|p| p.file_name())
            .map_or("untitled".into(), |n| n.to_string_lossy().into_owned());
        format!("{}{name} — Meso Studio", if dirty { "● " } else { "" })
    }

    /// Takes the newest frame and measures how long the edits before it took.
    fn receive(&mut self) {
        for notice in self.worker.take_notices() {
            // The status bar and the Device switch follow the device now rendering.
            if let Some(now) = notice.now {
                self.mode = now;
            }
            self.error = Some(notice.message);
        }
        for r in self.worker.take_rejected() {
            self.error = Some(format!(
                "the renderer refused edit {}: {}",
                r.version, r.message
            ));
        }
        if let Some(frame) = self.worker.take_frame() {
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
            self.viewport.set_frame(frame);
        }
    }

    fn shortcuts(&mut self, ui: &Ui) {
        // The longer shortcuts first: Ctrl+Shift+Z would also match Ctrl+Z.
        if ui.input_mut(|i| i.consume_shortcut(&REDO)) {
            self.redo();
        }
        if ui.input_mut(|i| i.consume_shortcut(&UNDO)) {
            self.undo();
        }
        if ui.input_mut(|i| i.consume_shortcut(&SAVE_AS)) {
            self.save_as_dialog();
        }
        if ui.input_mut(|i| i.consume_shortcut(&SAVE)) {
            self.save();
        }
        if ui.input_mut(|i| i.consume_shortcut(&OPEN_PACK)) {
            self.open_pack_dialog();
        }
        if ui.input_mut(|i| i.consume_shortcut(&EXPORT)) {
            self.export_dialog();
        }
    }

    fn open_scene_dialog(&mut self) {
        if let Some(p) = rfd::FileDialog::new()
            .add_filter("Meso scene", &["toml"])
            .pick_file()
        {
            self.open_scene(&p);
        }
    }

    fn open_pack_dialog(&mut self) {
        if let Some(p) = rfd::FileDialog::new()
            .add_filter("SPMM pack", &["spmm"])
            .pick_file()
        {
            self.open_pack(&p);
        }
    }

    fn export_dialog(&mut self) {
        if let Some(p) = rfd::FileDialog::new()
            .add_filter("OpenEXR (linear)", &["exr"])
            .add_filter("PNG (sRGB)", &["png"])
            .save_file()
        {
            self.export_frame(&p);
        }
    }

    fn menus(&mut self, ui: &mut Ui) {
        let ctx = ui.ctx().clone();
        let sc = |s: &KeyboardShortcut| ctx.format_shortcut(s);
        egui::MenuBar::new().ui(ui, |ui| {
            ui.menu_button("File", |ui| {
                if ui.button("Open scene…").clicked() {
                    self.open_scene_dialog();
                }
                if ui
                    .add(egui::Button::new("Open pack…").shortcut_text(sc(&OPEN_PACK)))
                    .clicked()
                {
                    self.open_pack_dialog();
                }
                ui.menu_button("Recent", |ui| {
                    for p in self.settings.recent_packs.clone() {
                        if ui.button(p.display().to_string()).clicked() {
                            self.open_pack(&p);
                        }
                    }
                    ui.separator();
                    for p in self.settings.recent_scenes.clone() {
                        if ui.button(p.display().to_string()).clicked() {
                            self.open_scene(&p);
                        }
                    }
                });
                ui.separator();
                if ui
                    .add(egui::Button::new("Save pack").shortcut_text(sc(&SAVE)))
                    .clicked()
                {
                    self.save();
                }
                if ui
                    .add(egui::Button::new("Save pack as…").shortcut_text(sc(&SAVE_AS)))
                    .clicked()
                {
                    self.save_as_dialog();
                }
                if ui
                    .add(egui::Button::new("Export frame…").shortcut_text(sc(&EXPORT)))
                    .clicked()
                {
                    self.export_dialog();
                }
                ui.separator();
                if ui.button("Quit").clicked() {
                    ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
                }
            });
            ui.menu_button("Edit", |ui| {
                let (can_undo, can_redo) = self
                    .doc
                    .as_ref()
                    .map_or((false, false), |d| (d.can_undo(), d.can_redo()));
                if ui
                    .add_enabled(can_undo, egui::Button::new("Undo").shortcut_text(sc(&UNDO)))
                    .clicked()
                {
                    self.undo();
                }
                if ui
                    .add_enabled(can_redo, egui::Button::new("Redo").shortcut_text(sc(&REDO)))
                    .clicked()
                {
                    self.redo();
                }
            });
            ui.menu_button("View", |ui| {
                if ui.button("BRDF explorer").clicked() {
                    self.explorer = Some(Explorer::default());
                }
                ui.checkbox(&mut self.settings.show_library, "Material library");
                ui.add(
                    egui::Slider::new(&mut self.settings.exposure, -8.0..=8.0)
                        .text("exposure (stops)"),
                );
                if ui
                    .add(
                        egui::Slider::new(&mut self.settings.max_samples, 1..=65536)
                            .logarithmic(true)
                            .text("stop at spp"),
                    )
                    .changed()
                {
                    self.set_max_samples(self.settings.max_samples);
                }
                if ui
                    .checkbox(&mut self.settings.denoise, "Denoise the first frames")
                    .on_hover_text(
                        "An edge-aware filter guided by normal, depth and albedo, fading \
                         out by 32 samples per pixel; saved images are never filtered",
                    )
                    .changed()
                {
                    self.worker.send(Command::Denoise(self.settings.denoise));
                }
                ui.checkbox(&mut self.settings.show_timings, "timings in the status bar");
                ui.checkbox(&mut self.settings.compare, "Compare with a reference");
                let names: Vec<&'static str> = self
                    .viewport
                    .frame()
                    .map(|f| f.overlays.iter().map(|o| o.0).collect())
                    .unwrap_or_default();
                if !names.is_empty() {
                    ui.horizontal(|ui| {
                        ui.label("debug overlay");
                        let mut chosen = self.viewport.overlay();
                        ui.selectable_value(&mut chosen, None, "image");
                        for name in names {
                            ui.selectable_value(&mut chosen, Some(name), name);
                        }
                        self.viewport.set_overlay(chosen);
                    });
                }
                ui.add(
                    egui::Slider::new(&mut self.settings.reference_spp, 1..=4096)
                        .logarithmic(true)
                        .text("reference spp"),
                );
                ui.horizontal(|ui| {
                    ui.label("resolution");
                    for (r, name) in [(0.25, "25%"), (0.5, "50%"), (1.0, "100%")] {
                        ui.selectable_value(&mut self.settings.resolution, r, name);
                    }
                });
            });
        });
    }

    fn status(&self, ui: &mut Ui) {
        ui.horizontal_wrapped(|ui| {
            for job in [
                self.scene_job.as_ref().map(|j| (&j.name, j.started)),
                self.pack_job.as_ref().map(|j| (&j.name, j.started)),
                self.assign_job.as_ref().map(|(_, j)| (&j.name, j.started)),
                self.env_job.as_ref().map(|j| (&j.name, j.started)),
                self.switch.as_ref().map(|s| (&s.job.name, s.job.started)),
            ]
            .into_iter()
            .flatten()
            {
                ui.spinner();
                ui.label(format!("{}… {:.1} s", job.0, job.1.elapsed().as_secs_f64()));
                ui.separator();
            }
            let Some(doc) = &self.doc else {
                ui.label("no scene");
                return;
            };
            match self.viewport.frame() {
                Some(f) => {
                    if f.preview {
                        ui.label("preview").on_hover_text(
                            "The view changed: one pixel in every few has its first sample, spread over the image; the whole frame follows.",
                        );
                    }
                    ui.label(format!(
                        "{} spp · {}x{} · {} non-finite dropped · film {:.1} MB",
                        f.progress.min_samples,
                        f.progress.width,
                        f.progress.height,
                        f.progress.dropped,
                        f.progress.film_bytes as f64 / 1e6
                    ));
                    if let Some(b) = f.material_bytes {
                        ui.label(format!(
                            "materials {:.1} of {:.1} MB resident",
                            b.resident as f64 / 1e6,
                            b.full as f64 / 1e6
                        ))
                        .on_hover_text(
                            "Packs are prepared when a ray first reaches them: packs no ray reaches hold nothing.",
                        );
                    }
                    if self.settings.show_timings {
                        ui.label(format!(
                            "{:.1} ms/frame · {:.2} M rays/s",
                            f.frame_ms,
                            f.rays_per_second / 1e6
                        ));
                    }
                    if let Some(summary) = &f.summary {
                        ui.separator();
                        if self.viewport.shows_from_device() {
                            ui.label(format!("{summary} · shown from the device"))
                                .on_hover_text(
                                    "The frame goes from the GPU mode's film to the window without a copy through the host.",
                                );
                        } else {
                            ui.label(summary);
                        }
                    }
                }
                None => {
                    ui.label("waiting for the first frame");
                }
            }
            ui.separator();
            if let Some(p) = &doc.pack
                && let Material::Spmm {
                    material,
                    residual,
                    npca,
                    ..
                } = &doc.scene.materials[p.material]
            {
                let parts = match (material.residual().is_some(), *residual) {
                    (false, _) => "bases only (no residual in the pack)".to_string(),
                    (true, false) => "bases, residual off".into(),
                    (true, true) => {
                        let mut used = (*npca).min(material.npca());
                        if self.moving {
                            used = used.min(meso_materials::spmm::MOVING_NPCA);
                        }
                        let moving = if self.moving { " while moving" } else { "" };
                        format!("bases + residual, N_PCA {used}/{}{moving}", material.npca())
                    }
                };
                ui.label(format!("{} clusters · {parts}", material.clusters().len()));
            }
            if self.settings.compare {
                ui.separator();
                ui.label(format!("live: {}", mode_name(self.mode.0, self.mode.1)));
                match &self.reference_latest {
                    Some(r) => ui.label(format!("reference: spmm, {} spp", r.spp)),
                    None => ui.label("reference: starting"),
                };
                if let Some(m) = &self.measured {
                    let c = &m.comparison;
                    ui.label(format!(
                        "RMSE {:.4} · PSNR {:.2} dB · MSSIM {:.4}",
                        c.rmse, c.psnr_db, c.mssim
                    ));
                }
                if let Some(e) = self.reference.as_ref().and_then(|r| r.error()) {
                    ui.colored_label(ui.visuals().error_fg_color, format!("reference: {e}"));
                }
            }
            if self.settings.show_timings {
                ui.separator();
                if let Some(ms) = self.latency.last_edit_to_frame_ms {
                    ui.label(format!("edit to frame {ms:.0} ms"));
                }
                ui.label(format!("UI {:.1} ms", self.ui_frame_ms));
            }
            if !self.worker.is_running() {
                ui.colored_label(ui.visuals().error_fg_color, "the render thread stopped");
            }
        });
    }

    /// One UI frame of the whole window.
    pub fn show(&mut self, ui: &mut Ui) {
        let start = Instant::now();
        self.poll_jobs();
        self.receive();
        self.shortcuts(ui);
        let dropped: Vec<PathBuf> = ui.input(|i| {
            i.raw
                .dropped_files
                .iter()
                .map(|f| f.path().to_path_buf())
                .filter(|p| !p.as_os_str().is_empty())
                .collect()
        });
        for path in dropped {
            self.open_dropped(&path);
        }
        egui::Panel::top("menu").show(ui, |ui| self.menus(ui));
        egui::Panel::bottom("status").show(ui, |ui| self.status(ui));
        let mut requests = Vec::new();
        if let Some(doc) = &self.doc {
            if let Some(e) = &doc.scene.environment {
                self.last_environment = Some(e.clone());
            }
            let state = PanelState {
                mode: self.mode,
                switching: self.switch.as_ref().map(|sw| Switching {
                    target: mode_name(sw.kind, sw.device),
                    progress: sw.job.progress(),
                    cancelling: sw.job.cancelled(),
                }),
                disabled: &self.disabled,
                environments: &self.environments,
                environment_name: doc.scene.environment.as_ref().and_then(|e| {
                    self.env_source
                        .as_ref()
                        .filter(|(_, m)| Arc::ptr_eq(m, &e.map))
                        .and_then(|(p, _)| p.file_stem())
                        .map(|n| n.to_string_lossy().into_owned())
                }),
                target_material: self.target_material(),
            };
            egui::Panel::left("scene")
                .resizable(true)
                .default_size(270.0)
                .show(ui, |ui| {
                    egui::ScrollArea::vertical().show(ui, |ui| {
                        requests = scene_panel::show(ui, doc, &state);
                    });
                });
            let mut edits = Vec::new();
            egui::Panel::right("material")
                .resizable(true)
                .default_size(330.0)
                .show(ui, |ui| {
                    egui::ScrollArea::vertical().show(ui, |ui| {
                        edits = self.material_panel.show(ui, doc);
                    });
                });
            requests.extend(edits.into_iter().map(Request::Edit));
        }
        for r in requests {
            match r {
                Request::Edit(e) => self.edit(e),
                Request::OpenSceneDialog => self.open_scene_dialog(),
                Request::Mesh(p) => self.replace_mesh(&p),
                Request::SwitchMode(kind, device) => self.request_mode(kind, device),
                Request::CancelSwitch => self.cancel_switch(),
                Request::EnvironmentOn => self.environment_on(),
                Request::EnvironmentMap(p) => self.open_environment(&p),
                Request::EnvironmentFileDialog => self.environment_dialog(),
                Request::EditPack(index) => self.edit_pack(index),
            }
        }
        self.update_compare();
        egui::CentralPanel::default().show(ui, |ui| self.viewport_ui(ui));
        // One drag of a slider is one undo step: the group ends when the button is up.
        if !ui.input(|i| i.pointer.any_down())
            && let Some(doc) = &mut self.doc
        {
            doc.close_group();
        }
        self.library_window(&ui.ctx().clone());
        self.dialogs(ui);
        let title = self.title();
        if title != self.shown_title {
            ui.ctx()
                .send_viewport_cmd(egui::ViewportCommand::Title(title.clone()));
            self.shown_title = title;
        }
        self.ui_frame_ms = start.elapsed().as_secs_f64() * 1e3;
    }

    fn viewport_ui(&mut self, ui: &mut Ui) {
        let Some(camera) = self.doc.as_ref().map(|d| d.scene.camera) else {
            ui.centered_and_justified(|ui| ui.label("Open a scene (File > Open scene…)"));
            return;
        };
        let compare = self.settings.compare.then(|| CompareLabels {
            live: format!("live: {}", mode_name(self.mode.0, self.mode.1)),
            reference: match &self.reference_latest {
                Some(r) => format!("reference: spmm, {} spp", r.spp),
                None => "reference: spmm, starting".into(),
            },
        });
        let scale = f64::from(self.settings.resolution);
        // The brush outline: its radius in points when measured in image pixels.
        let brush_points = self.material_panel.paint.on.then(|| {
            let b = &self.material_panel.paint.brush;
            match b.units {
                BrushUnits::ScreenPixels => {
                    (b.radius / (scale * f64::from(ui.ctx().pixels_per_point()))) as f32
                }
                BrushUnits::Texels => 4.0,
            }
        });
        let input = self
            .viewport
            .show(ui, &camera, self.settings.exposure, compare, brush_points);
        let full = (
            ((f64::from(input.panel_pixels.0) * scale) as u32).clamp(16, 4096),
            ((f64::from(input.panel_pixels.1) * scale) as u32).clamp(16, 4096),
        );
        if self.render_size == (0, 0) {
            self.full_size = full;
            self.load_into_renderer(full);
        } else if full != self.full_size && !self.moving {
            self.full_size = full;
            self.render_size = full;
            self.view(SceneEdit::Resize {
                width: full.0,
                height: full.1,
            });
        }
        if input.drag_started {
            self.moving = true;
            let preview = ((full.0 / 4).max(16), (full.1 / 4).max(16));
            self.render_size = preview;
            self.view(SceneEdit::Moving(true));
            self.view(SceneEdit::Resize {
                width: preview.0,
                height: preview.1,
            });
        }
        if let Some(c) = input.camera {
            self.view(SceneEdit::Camera(c));
        }
        if input.drag_stopped {
            self.moving = false;
            self.render_size = self.full_size;
            self.view(SceneEdit::Resize {
                width: self.full_size.0,
                height: self.full_size.1,
            });
            self.view(SceneEdit::Moving(false));
        }
        if let Some((x, y)) = input.click {
            self.pick_at(x, y);
        }
        if let Some((from, to)) = input.paint {
            self.paint_stroke(from, to);
        }
        if input.paint_end {
            self.material_panel.end_stroke();
        }
    }

    /// Paints the brush from `from` to `to` (in [0, 1]^2 of the image) on the edited
    /// pack, through the same picking as a click: one edit of the stroke so far, in the
    /// open undo group (a stroke is one undo step).
    pub fn paint_stroke(&mut self, from: (f64, f64), to: (f64, f64)) {
        let (Some(doc), Some(bvh)) = (&self.doc, &self.bvh) else {
            return;
        };
        let Some(index) = doc.pack.as_ref().map(|p| p.material) else {
            return;
        };
        let (w, h) = (self.full_size.0.max(1), self.full_size.1.max(1));
        let at = |p: (f64, f64)| glam::DVec2::new(p.0 * f64::from(w), p.1 * f64::from(h));
        let brush = self.material_panel.paint.brush;
        let edit = self.material_panel.stroke_edit(doc, |mask| {
            brush::stroke(
                &doc.scene,
                bvh,
                (w, h),
                at(from),
                at(to),
                &brush,
                index,
                mask,
            )
        });
        if let Some(e) = edit {
            self.edit(e);
        }
    }

    /// The compare view: keeps the reference renderer on the document's version and
    /// render size, shows its newest image, and compares the live frame with it (off
    /// this thread, at most every `MEASURE_EVERY`) when both show the same version at
    /// the same size.
    fn update_compare(&mut self) {
        if !self.settings.compare {
            if self.reference.take().is_some() {
                self.viewport.clear_reference();
                self.reference_latest = None;
                self.measured = None;
                self.measure_job = None;
                self.measure_key = None;
            }
            return;
        }
        let Some(doc) = &self.doc else { return };
        if self.render_size == (0, 0) {
            return;
        }
        let reference = self
            .reference
            .get_or_insert_with(|| ReferenceRenderer::spawn(self.repaint.clone()));
        reference.request(
            doc.version,
            &doc.scene,
            self.render_size,
            self.settings.reference_spp,
        );
        if let Some(r) = reference.latest()
            && self
                .reference_latest
                .as_ref()
                .is_none_or(|old| old.seq != r.seq)
        {
            self.viewport.set_reference(Arc::clone(&r.image));
            self.reference_latest = Some(r);
        }
        if let Some(r) = self.measure_job.as_ref().and_then(|j| j.poll()) {
            self.measure_job = None;
            match r {
                Ok(m) => self.measured = Some(m),
                Err(e) => self.error = Some(e),
            }
        }
        let (Some(live), Some(r)) = (self.viewport.frame(), &self.reference_latest) else {
            return;
        };
        let key = (live.finished, r.seq);
        let comparable = live.version == r.version
            && !live.preview
            && live.estimate.size() == (r.image.width(), r.image.height());
        if comparable
            && self.measure_job.is_none()
            && self.measure_key != Some(key)
            && self.measure_started.elapsed() >= MEASURE_EVERY
        {
            self.measure_key = Some(key);
            self.measure_started = Instant::now();
            let (reference, live, reference_spp) = (Arc::clone(&r.image), live.image(), r.spp);
            self.measure_job = Some(Job::spawn("comparing", self.repaint.clone(), move || {
                let comparison =
                    metrics::compare(&reference, &live, 0.0).map_err(|e| e.to_string())?;
                Ok(Measured {
                    reference,
                    live,
                    reference_spp,
                    comparison,
                })
            }));
        } else if !comparable || self.measure_key != Some(key) {
            // Wake up again to compare once the interval has passed.
            ctx_repaint_after(self.repaint.as_ref(), MEASURE_EVERY);
        }
    }

    /// Chooses the cluster and texel under a click at (x, y) in [0, 1]^2 of the image.
    pub fn pick_at(&mut self, x: f64, y: f64) {
        let (Some(doc), Some(bvh)) = (&self.doc, &self.bvh) else {
            return;
        };
        let (w, h) = self.full_size;
        if let Some(p) = pick(
            &doc.scene,
            bvh,
            w.max(1),
            h.max(1),
            x * f64::from(w),
            y * f64::from(h),
        ) && {
            self.selected_material = Some(p.material);
            true
        } && doc
            .pack
            .as_ref()
            .is_some_and(|pk| pk.material == p.material)
            && let Some((texel, cluster)) = p.texel
        {
            self.material_panel.cluster = cluster;
            self.material_panel.texel = Some(texel);
        }
    }

    fn dialogs(&mut self, ui: &mut Ui) {
        let ctx = ui.ctx().clone();
        if let Some(e) = self.error.clone() {
            egui::Window::new("Error")
                .collapsible(false)
                .resizable(false)
                .anchor(egui::Align2::CENTER_TOP, egui::vec2(0.0, 40.0))
                .show(&ctx, |ui| {
                    ui.label(e);
                    if ui.button("OK").clicked() {
                        self.error = None;
                    }
                });
        }
        if let Some(m) = self.mode_message.clone() {
            egui::Window::new("Render mode")
                .collapsible(false)
                .resizable(false)
                .anchor(egui::Align2::CENTER_TOP, egui::vec2(0.0, 120.0))
                .show(&ctx, |ui| {
                    ui.label(m);
                    if ui.button("OK").clicked() {
                        self.mode_message = None;
                    }
                });
        }
        if let Some(u) = self.unsupported_prompt.clone() {
            let target = mode_name(u.mode, u.device);
            let current = mode_name(self.mode.0, self.mode.1);
            let parts: Vec<String> = u.parts.iter().map(|p| p.to_string()).collect();
            egui::Window::new("Switch render mode?")
                .collapsible(false)
                .resizable(false)
                .anchor(egui::Align2::CENTER_TOP, egui::vec2(0.0, 120.0))
                .show(&ctx, |ui| {
                    ui.label(format!(
                        "The {target} mode cannot render {}.",
                        parts.join(", ")
                    ));
                    ui.horizontal(|ui| {
                        if ui
                            .button(format!(
                                "Switch with these lights disabled for {}",
                                u.mode.name()
                            ))
                            .clicked()
                        {
                            self.switch_without_lights(u.mode, u.device);
                        }
                        if ui.button(format!("Stay in {current}")).clicked() {
                            self.unsupported_prompt = None;
                        }
                    });
                });
        }
        // Quitting with unsaved edits asks first.
        if ctx.input(|i| i.viewport().close_requested()) && !self.allow_close && self.dirty() {
            ctx.send_viewport_cmd(egui::ViewportCommand::CancelClose);
            self.quit_prompt = true;
        }
        if self.quit_prompt {
            let r = egui::Modal::new(egui::Id::unique("meso-quit-prompt")).show(&ctx, |ui| {
                ui.heading("Save the edited pack?");
                ui.label("The pack has changes that are not saved.");
                ui.horizontal(|ui| {
                    if ui.button("Save").clicked() && self.save() {
                        self.allow_close = true;
                    }
                    if ui.button("Discard").clicked() {
                        self.allow_close = true;
                    }
                    if ui.button("Cancel").clicked() {
                        self.quit_prompt = false;
                    }
                });
            });
            if r.should_close() {
                self.quit_prompt = false;
            }
            if self.allow_close {
                self.quit_prompt = false;
                ctx.send_viewport_cmd(egui::ViewportCommand::Close);
            }
        }
        if let Some(ex) = &mut self.explorer {
            let mut open = true;
            egui::Window::new("BRDF explorer")
                .open(&mut open)
                .default_size([900.0, 600.0])
                .show(&ctx, |ui| ex.show(ui));
            if !open {
                self.explorer = None;
            }
        }
    }
}

#[cfg(test)]
#[path = "studio_tests.rs"]
mod tests;

#[cfg(test)]
#[path = "mode_tests.rs"]
mod mode_tests;
