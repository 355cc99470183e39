//! Meso Studio's main window: the material editor over the progressive viewport.
//! Menus (File, Edit, View) with shortcuts, the lights and scene panel (left), the
//! material panel (right), the viewport (centre) and the status bar. The studio owns
//! the document and sends every edit to the render thread as a versioned message;
//! it shows the newest finished frame and never waits for one. It is the glue: the
//! parts live in their own types and files — the render mode switch (`ModeSwitch`,
//! mode_switch.rs), the compare view (`CompareView`, compare.rs), file loading
//! (`Loader`, loader.rs), the render sizes and picking (`Canvas`, canvas.rs), the
//! render thread's end with latency (`RenderLink`, render_link.rs), the menus and
//! dialogs (`Chrome`, chrome.rs), the status bar (status_bar.rs) and the library
//! window (library_window.rs) — and the studio routes what they ask for.

use meso_render::geometry::SceneBvh;
use meso_render::scene::Material;
use meso_render::scene::mesh::{Placement, load_obj};
use meso_render::{Device, ModeKind, SceneEdit};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::canvas::Canvas;
use crate::chrome::{self, Chrome};
use crate::compare::CompareView;
use crate::disabled::Disabled;
use crate::document::Document;
use crate::library::{self, EntryKind, Library};
use crate::library_window::LibraryWindow;
use crate::loader::{self, Dropped, Loaded, Loader};
use crate::material_panel::MaterialPanel;
use crate::mode_switch::ModeSwitch;
use crate::recovery::{Ask, Recovery};
use crate::render_link::RenderLink;
use crate::viewport::Viewport;
use meso_session::SaveError;
use meso_session::recover::{self, Session};
use meso_session::script::{Runner, Script};
use meso_viewport::maker::{ModeMaker, core_modes};
use meso_viewport::worker::Command;

pub use crate::chrome::{EXPORT, OPEN_PACK, REDO, SAVE, SAVE_AS, UNDO};
pub use crate::compare::Measured;
pub use crate::render_link::Latency;
pub use crate::settings::Settings;

/// Scripted edits applied in one UI frame at most.
const SCRIPT_EDITS_PER_FRAME: usize = 4;

/// The scene the README's first command opens.
pub fn default_scene_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/scenes/default.toml")
}

fn remember(list: &mut Vec<PathBuf>, path: &Path) {
    list.retain(|p| p != path);
    list.insert(0, path.to_path_buf());
    list.truncate(8);
}

pub struct Studio {
    pub doc: Option<Document>,
    pub settings: Settings,
    pub material_panel: MaterialPanel,
    /// The material of the object last clicked in the viewport: what the library
    /// assigns to (the edited pack's object until a click).
    pub selected_material: Option<usize>,
    /// The last error, shown until dismissed.
    pub error: Option<String>,
    /// The render thread, with the edits in flight and their latency.
    renderer: RenderLink,
    viewport: Viewport,
    /// The render sizes and the geometry clicks land on.
    canvas: Canvas,
    /// The mode rendering now and a switch to another.
    modes: ModeSwitch,
    compare: CompareView,
    /// Loads in progress and the environment maps.
    loader: Loader,
    /// Menus, dialogs, title.
    chrome: Chrome,
    library: LibraryWindow,
    /// The restore offer, pack conflicts and a scripted run.
    recovery: Recovery,
    /// A session being restored: its scene is loading, its journal replays then.
    restoring: Option<Session>,
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
            material_panel: MaterialPanel::default(),
            selected_material: None,
            error: None,
            renderer: RenderLink::spawn(repaint.clone(), Arc::clone(&maker)),
            viewport: Viewport::default(),
            canvas: Canvas::default(),
            modes: ModeSwitch::new(maker, repaint.clone()),
            compare: CompareView::new(repaint.clone()),
            loader: Loader::new(repaint.clone()),
            chrome: Chrome::default(),
            library: LibraryWindow::new(repaint),
            recovery: Recovery::default(),
            restoring: None,
        };
        if s.settings.journal {
            let mut offer = recover::restorable(&s.settings.sessions_dir());
            offer.reverse();
            s.recovery.offer = offer;
        }
        s.set_max_samples(s.settings.max_samples);
        s.renderer.send(Command::Denoise(s.settings.denoise));
        s.open_scene(&scene.unwrap_or_else(default_scene_path));
        s
    }

    /// The window is drawn by `render_state`'s wgpu renderer on the device of
    /// `shared`, which the GPU modes share (`window_device::modes_for`): their frames
    /// are shown from there. `None`: frames reach the window through the host.
    #[cfg(feature = "gpu")]
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
        self.renderer.send(Command::MaxSamples(n));
    }

    /// The newest frame on screen.
    #[cfg(test)]
    pub fn frame(&self) -> Option<&meso_viewport::worker::Frame> {
        self.viewport.frame()
    }

    /// The full-quality render size.
    #[cfg(test)]
    pub fn full_size(&self) -> (u32, u32) {
        self.canvas.full_size
    }

    /// Statistics of the newest frame.
    pub fn latency(&self) -> Latency {
        self.renderer.latency()
    }

    /// Starts loading a scene in the background; the current one stays until it is
    /// ready.
    pub fn open_scene(&mut self, path: &Path) {
        self.loader.open_scene(path);
    }

    /// Whether a load is in progress.
    pub fn busy(&self) -> bool {
        self.loader.busy()
    }

    /// The mode rendering now.
    pub fn mode(&self) -> (ModeKind, Device) {
        self.modes.mode()
    }

    /// Whether a mode is being prepared to replace the current one.
    pub fn switching(&self) -> bool {
        self.modes.switching()
    }

    /// Lights and ambient the current mode renders without.
    pub fn disabled(&self) -> &Disabled {
        self.modes.disabled()
    }

    /// Why the last mode switch did not happen, shown until dismissed.
    pub fn mode_message(&self) -> Option<String> {
        self.modes.message().cloned()
    }

    /// The question the mode switch asks, while it is open.
    pub fn mode_prompt(&self) -> Option<&meso_render::Unsupported> {
        self.modes.prompt()
    }

    /// The compare view's latest numbers and the two images they come from.
    pub fn measured(&self) -> Option<&Measured> {
        self.compare.measured()
    }

    /// Asks for another render mode (`ModeSwitch::request`).
    pub fn request_mode(&mut self, kind: ModeKind, device: Device) {
        let size = self.canvas.prepare_size();
        self.modes.request(self.doc.as_ref(), kind, device, size);
    }

    /// Stops preparing the new mode; the current one stays.
    pub fn cancel_switch(&mut self) {
        self.modes.cancel();
    }

    /// Reads an environment map in the background; it lights the scene when ready.
    pub fn open_environment(&mut self, path: &Path) {
        self.loader.open_environment(path);
    }

    /// Installs finished loads and a prepared mode.
    fn poll_jobs(&mut self) {
        let size = self.canvas.prepare_size();
        self.modes.poll(self.doc.as_ref(), &mut self.renderer, size);
        for done in self.loader.poll(self.doc.as_ref()) {
            match done {
                Ok(loaded) => self.install(loaded),
                Err(e) => self.error = Some(e),
            }
        }
    }

    /// Installs a finished load.
    fn install(&mut self, loaded: Loaded) {
        match loaded {
            Loaded::Environment(env, path) => {
                if let Some(doc) = &mut self.doc {
                    doc.note_source(&env.map, &path);
                }
                self.edit(SceneEdit::Environment(Some(env)));
                if let Some(doc) = &mut self.doc {
                    doc.close_group();
                }
            }
            Loaded::Scene(path, loaded) => {
                let (scene, bvh) = *loaded;
                remember(&mut self.settings.recent_scenes, &path);
                self.canvas.bvh = Some(bvh);
                // The previous document's journal goes if nothing in it is unsaved,
                // else it stays for `meso recover` and the next start.
                if let Some(old) = &mut self.doc {
                    let clean = !old.dirty();
                    old.close_journal(clean);
                }
                // Versions keep increasing across documents, so a frame of the
                // previous scene never passes for one of this.
                let mut doc = Document::new(scene, Some(path.clone()));
                doc.version = self.doc.as_ref().map_or(1, |d| d.version + 1);
                doc.set_undo_budget(self.settings.undo_budget_mb << 20);
                if self.settings.journal {
                    doc.journal_to(&self.settings.sessions_dir());
                }
                self.renderer.forget_in_flight();
                self.material_panel = MaterialPanel::default();
                self.selected_material = None;
                // A new scene opens in the spmm mode, which renders everything; the
                // mode the scene names is asked for once it is loaded.
                self.modes.open_scene(&doc, self.settings.gpu_by_default);
                self.doc = Some(doc);
                // The viewport loads it into the renderer at its size.
                self.canvas.render_size = (0, 0);
                self.finish_restore(&path);
            }
            Loaded::Assigned(index, (path, material, precision)) => {
                let is_pack = matches!(material, Material::Spmm { .. });
                let assigned = self
                    .doc
                    .as_mut()
                    .ok_or_else(|| "no scene is open".to_string())
                    .and_then(|doc| doc.assign(index, material, &path, precision));
                match assigned {
                    Ok(edit) => {
                        if is_pack {
                            remember(&mut self.settings.recent_packs, &path);
                        }
                        self.material_panel = MaterialPanel::default();
                        self.send(edit);
                    }
                    Err(e) => self.error = Some(e),
                }
            }
            Loaded::Pack(path, material, precision) => {
                let installed = self
                    .doc
                    .as_mut()
                    .ok_or_else(|| "no scene is open".to_string())
                    .and_then(|doc| doc.install_pack(&path, material, precision));
                match installed {
                    Ok(edit) => {
                        remember(&mut self.settings.recent_packs, &path);
                        self.material_panel = MaterialPanel::default();
                        self.send(edit);
                    }
                    Err(e) => self.error = Some(e),
                }
            }
        }
    }

    /// Loads the document into the renderer at `size` in the mode rendering now; the
    /// mode the scene asks for is requested after it.
    fn load_into_renderer(&mut self, size: (u32, u32)) {
        let Some(doc) = &self.doc else { return };
        self.canvas.render_size = size;
        let (mode, device) = self.modes.mode();
        let command = Command::Load {
            version: doc.version,
            scene: Box::new(self.modes.disabled().scene_for_mode(&doc.scene)),
            mode,
            device,
            width: size.0,
            height: size.1,
        };
        self.renderer.send_tracked(command, doc.version);
        // After the first load, so an installed mode always follows the Load.
        if let Some((kind, device)) = self.modes.take_scene_mode() {
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
    /// for what the mode renders without (and noted for a mode being prepared); new
    /// geometry rebuilds the picking BVH and may prepare the mode again.
    fn send(&mut self, edit: SceneEdit) {
        let Some(doc) = &self.doc else { return };
        if let SceneEdit::Meshes(m) = &edit {
            self.canvas.bvh = Some(SceneBvh::build(m));
            let size = self.canvas.prepare_size();
            if self.modes.prepare_for_geometry(doc, size) {
                return;
            }
        }
        let version = doc.version;
        let command = match self.modes.translate(doc, edit) {
            Some(e) => Command::Edit {
                version,
                edit: Box::new(e),
            },
            None => Command::Unchanged { version },
        };
        self.renderer.send_tracked(command, version);
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
            Err(SaveError::ChangedOnDisk(p)) => {
                self.recovery.conflict = Some(p);
                false
            }
            Err(e) => {
                self.error = Some(e.to_string());
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
        let pack: [(&str, &[&str]); 1] = [("SPMM pack", &["spmm"])];
        match chrome::save_file(&pack) {
            Some(p) => self.save_pack_as(&p),
            None => false,
        }
    }

    /// Starts reading a pack in the background; it replaces the edited one when ready.
    pub fn open_pack(&mut self, path: &Path) {
        self.loader.open_pack(path);
    }

    /// A file dropped on the window: a scene `.toml` opens; a `.spmm` pack or a MERL
    /// `.binary` goes on the selected object (`assign_file`); a BTF is named with what
    /// to do instead.
    pub fn open_dropped(&mut self, path: &Path) {
        match loader::dropped(path) {
            Ok(Dropped::Scene) => self.open_scene(path),
            Ok(Dropped::Material(kind)) => self.assign_file(kind, path),
            Err(e) => self.error = Some(e),
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
        self.loader.assign(kind, path, index, slot);
    }

    /// The material library (opened, listing its folders and starting thumbnails).
    pub fn library(&mut self) -> &mut Library {
        self.library.library(&self.settings)
    }

    /// Adds a folder to the library (remembered across runs).
    pub fn add_library_folder(&mut self, dir: &Path) {
        self.library.add_folder(&mut self.settings, dir);
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

    /// Replaces the edited pack's object's meshes with the OBJ at `path`.
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

    /// Takes the newest frame (its latency measured) and what the render thread says.
    fn receive(&mut self) {
        let (notices, rejected) = self.renderer.take_messages();
        for notice in notices {
            // The status bar and the Device switch follow the device now rendering.
            if let Some(now) = notice.now {
                self.modes.now_renders(now);
            }
            self.error = Some(notice.message);
        }
        for r in rejected {
            self.error = Some(format!(
                "the renderer refused edit {}: {}",
                r.version, r.message
            ));
        }
        if let Some(frame) = self.renderer.take_frame() {
            self.viewport.set_frame(frame);
        }
    }

    /// Paints the brush from `from` to `to` (in [0, 1]^2 of the image) on the edited
    /// pack, through the same picking as a click: one edit of the stroke so far, in the
    /// open undo group (a stroke is one undo step).
    pub fn paint_stroke(&mut self, from: (f64, f64), to: (f64, f64)) {
        let Some(doc) = &self.doc else { return };
        if self.canvas.bvh.is_none() {
            return;
        }
        let Some(index) = doc.pack.as_ref().map(|p| p.material) else {
            return;
        };
        let brush = self.material_panel.paint.brush;
        let canvas = &self.canvas;
        let edit = self.material_panel.stroke_edit(doc, |mask| {
            canvas.stroke(doc, &brush, index, (from, to), mask)
        });
        if let Some(e) = edit {
            self.edit(e);
        }
    }

    /// Chooses the cluster and texel under a click at (x, y) in [0, 1]^2 of the image;
    /// the object clicked is where the library assigns to.
    pub fn pick_at(&mut self, x: f64, y: f64) {
        let Some(doc) = &self.doc else { return };
        let Some(p) = self.canvas.pick(doc, x, y) else {
            return;
        };
        self.selected_material = Some(p.material);
        if doc
            .pack
            .as_ref()
            .is_some_and(|pk| pk.material == p.material)
            && let Some((texel, cluster)) = p.texel
        {
            self.material_panel.cluster = cluster;
            self.material_panel.texel = Some(texel);
        }
    }
}

impl Studio {
    /// Sessions offered for restoring (newest first), until answered.
    pub fn restore_offer(&self) -> &[Session] {
        &self.recovery.offer
    }

    /// Restores a session: opens its scene, then replays its journal into it.
    pub fn restore(&mut self, session: Session) {
        self.recovery.offer.retain(|s| s.journal != session.journal);
        let scene = session.scene.clone().unwrap_or_else(default_scene_path);
        self.restoring = Some(session);
        self.open_scene(&scene);
    }

    /// After a scene loaded: replays the journal being restored, if it is this
    /// scene's, and removes it once the new session's journal holds its edits.
    fn finish_restore(&mut self, path: &Path) {
        let Some(session) = self.restoring.take() else {
            return;
        };
        let wanted = session.scene.clone().unwrap_or_else(default_scene_path);
        let same = |a: &Path, b: &Path| std::path::absolute(a).ok() == std::path::absolute(b).ok();
        if !same(&wanted, path) {
            return;
        }
        let Some(doc) = self.doc.as_mut() else { return };
        let replayed = meso_session::journal::read(&session.journal)
            .map_err(|e| e.to_string())
            .and_then(|c| doc.replay(&c));
        match replayed {
            Ok(r) => {
                let written = doc.journal().map_or(Ok(()), |j| j.flush());
                if written.is_ok() {
                    let _ = recover::discard(&session.journal);
                }
                if !r.lost.is_empty() {
                    self.error = Some(format!(
                        "restored; these edits could not be journaled and are missing: {}",
                        r.lost.join(", ")
                    ));
                }
                self.material_panel = MaterialPanel::default();
            }
            Err(e) => {
                self.error = Some(format!(
                    "could not restore `{}` (it is kept): {e}",
                    session.journal.display()
                ));
            }
        }
    }

    /// Runs a script's edits through the same path as the panels, one undo step each,
    /// as their waits come due.
    pub fn run_script(&mut self, script: Script) {
        self.recovery.script = Some(Runner::new(script));
    }

    /// Whether a scripted run is still going.
    pub fn script_running(&self) -> bool {
        self.recovery.script.as_ref().is_some_and(|r| !r.done())
    }

    /// The scripted edits due now (after the scene has loaded).
    fn step_script(&mut self, ctx: &egui::Context) {
        // After the scene is loaded and in the renderer.
        if self.busy() || self.doc.is_none() || self.canvas.render_size == (0, 0) {
            if self.recovery.script.is_some() {
                ctx.request_repaint_after(std::time::Duration::from_millis(10));
            }
            return;
        }
        let Some(mut runner) = self.recovery.script.take() else {
            return;
        };
        // Paced like a hand on the panels: a few edits a UI frame, and none while the
        // renderer has not shown the last ones, so no queue grows behind the script.
        if self.renderer.in_flight() > 1 {
            ctx.request_repaint_after(std::time::Duration::from_millis(5));
            self.recovery.script = Some(runner);
            return;
        }
        let now = std::time::Instant::now();
        for i in runner.due_at_most(now, SCRIPT_EDITS_PER_FRAME) {
            let Some(doc) = &self.doc else { break };
            match runner.script.edit_on(i, doc) {
                Ok(Some(e)) => {
                    self.edit(e);
                    if let Some(doc) = &mut self.doc {
                        doc.close_group();
                    }
                }
                Ok(None) => {}
                Err(e) => {
                    self.error = Some(e);
                    return;
                }
            }
        }
        if let Some(wait) = runner.wait(now) {
            ctx.request_repaint_after(wait);
            self.recovery.script = Some(runner);
        }
    }

    /// Checks the edited pack's file for changes by other programs, and does what
    /// the recovery dialogs asked.
    fn poll_recovery(&mut self, ctx: &egui::Context) {
        self.step_script(ctx);
        if self.recovery.check_due(std::time::Instant::now()) {
            if let Some(p) = self.doc.as_ref().and_then(|d| d.pack_changed_on_disk()) {
                self.recovery.changed_on_disk(p);
            }
            ctx.request_repaint_after(std::time::Duration::from_secs(2));
        }
        for ask in self.recovery.show(ctx) {
            match ask {
                Ask::Restore(s) => self.restore(s),
                Ask::Discard(p) => {
                    if let Err(e) = recover::discard(&p) {
                        self.error = Some(e);
                    }
                }
                Ask::Reload => {
                    let reloaded = self.doc.as_mut().map(|d| d.reload_pack());
                    match reloaded {
                        Some(Ok(edit)) => {
                            self.material_panel = MaterialPanel::default();
                            self.send(edit);
                        }
                        Some(Err(e)) => self.error = Some(e),
                        None => {}
                    }
                }
                Ask::Overwrite => {
                    let path = self
                        .doc
                        .as_ref()
                        .and_then(|d| d.pack.as_ref())
                        .and_then(|p| p.path.clone());
                    if let (Some(doc), Some(path)) = (self.doc.as_mut(), path)
                        && let Err(e) = doc.save_pack_over(&path)
                    {
                        self.error = Some(e.to_string());
                    }
                }
                Ask::SaveAs => {
                    self.save_as_dialog();
                }
            }
        }
    }

    /// The window closes after the user saved or chose to discard: the journal goes.
    pub fn on_exit(&mut self) {
        if let Some(doc) = &mut self.doc {
            doc.close_journal(true);
        }
    }
}

#[path = "studio_frame.rs"]
mod frame;

#[cfg(test)]
#[path = "studio_tests.rs"]
mod tests;

#[cfg(test)]
#[path = "mode_tests.rs"]
mod mode_tests;

#[cfg(all(test, feature = "gpu"))]
#[path = "window_device_tests.rs"]
mod window_device_tests;

#[cfg(test)]
#[path = "recovery_tests.rs"]
mod recovery_tests;
