//! One UI frame of the studio (`Studio::show`): installs finished jobs and frames,
//! lays out the menus, status bar, scene and material panels, viewport, library window
//! and dialogs, and does what they ask (`Action`s from the chrome, `Request`s from the
//! panels). Apart from studio.rs, which holds the studio's state and its operations
//! (edits, undo, files, modes), so the window's layout reads in one place.

use std::time::Instant;

use egui::Ui;
use meso_render::SceneEdit;
use meso_render::geometry::BrushUnits;

use super::Studio;
use crate::chrome::{self, Action, MenuState};
use crate::scene_panel::{self, PanelState, Request};
use crate::status_bar::StatusBar;
use meso_viewport::worker::Command;

impl Studio {
    /// Does what a menu item, shortcut or dialog asked for.
    fn act(&mut self, ctx: &egui::Context, action: Action) {
        match action {
            Action::OpenSceneDialog => {
                if let Some(p) = chrome::pick_file("Meso scene", &["toml"]) {
                    self.open_scene(&p);
                }
            }
            Action::OpenPackDialog => {
                if let Some(p) = chrome::pick_file("SPMM pack", &["spmm"]) {
                    self.open_pack(&p);
                }
            }
            Action::OpenScene(p) => self.open_scene(&p),
            Action::OpenPack(p) => self.open_pack(&p),
            Action::Save => {
                self.save();
            }
            Action::SaveAsDialog => {
                self.save_as_dialog();
            }
            Action::ExportDialog => {
                let formats: [(&str, &[&str]); 2] =
                    [("OpenEXR (linear)", &["exr"]), ("PNG (sRGB)", &["png"])];
                if let Some(p) = chrome::save_file(&formats) {
                    self.export_frame(&p);
                }
            }
            Action::Undo => self.undo(),
            Action::Redo => self.redo(),
            Action::MaxSamples => self.set_max_samples(self.settings.max_samples),
            Action::Denoise => self.renderer.send(Command::Denoise(self.settings.denoise)),
            Action::UndoBudget => {
                if let Some(doc) = &mut self.doc {
                    doc.set_undo_budget(self.settings.undo_budget_mb << 20);
                }
            }
            Action::Overlay(o) => self.viewport.set_overlay(o),
            Action::SwitchWithoutLights(kind, device) => {
                let size = self.canvas.prepare_size();
                self.modes
                    .without_lights(self.doc.as_ref(), kind, device, size);
            }
            Action::SaveAndQuit => {
                if self.save() {
                    self.chrome.close(ctx);
                }
            }
        }
    }

    /// Turns the environment on: the last one used, or the first shipped map (read in
    /// the background).
    pub(crate) fn environment_on(&mut self) {
        match self.loader.environment_on() {
            Ok(Some(e)) => self.edit(SceneEdit::Environment(Some(e))),
            Ok(None) => {}
            Err(e) => self.error = Some(e),
        }
    }

    /// Does what the scene and material panels asked for.
    fn request(&mut self, request: Request) {
        match request {
            Request::Edit(e) => self.edit(e),
            Request::OpenSceneDialog => {
                if let Some(p) = chrome::pick_file("Meso scene", &["toml"]) {
                    self.open_scene(&p);
                }
            }
            Request::Mesh(p) => self.replace_mesh(&p),
            Request::SwitchMode(kind, device) => self.request_mode(kind, device),
            Request::CancelSwitch => self.cancel_switch(),
            Request::EnvironmentOn => self.environment_on(),
            Request::EnvironmentMap(p) => self.open_environment(&p),
            Request::EnvironmentFileDialog => {
                if let Some(p) = chrome::pick_file("environment map", &["exr", "hdr", "png"]) {
                    self.open_environment(&p);
                }
            }
            Request::EditPack(index) => self.edit_pack(index),
        }
    }

    /// One UI frame of the whole window.
    pub fn show(&mut self, ui: &mut Ui) {
        let start = Instant::now();
        let ctx = ui.ctx().clone();
        self.poll_jobs();
        self.receive();
        self.poll_recovery(&ctx);
        for a in chrome::shortcuts(ui) {
            self.act(&ctx, a);
        }
        for path in chrome::dropped_files(ui) {
            self.open_dropped(&path);
        }
        egui::Panel::top("menu").show(ui, |ui| {
            let state = MenuState {
                can_undo: self.doc.as_ref().is_some_and(|d| d.can_undo()),
                can_redo: self.doc.as_ref().is_some_and(|d| d.can_redo()),
                overlays: self
                    .viewport
                    .frame()
                    .map_or_else(Vec::new, |f| f.overlays.iter().map(|o| o.0).collect()),
                overlay: self.viewport.overlay(),
            };
            for a in self.chrome.menus(ui, &mut self.settings, state) {
                self.act(&ctx, a);
            }
        });
        egui::Panel::bottom("status").show(ui, |ui| self.status_bar().show(ui));
        for r in self.panels(ui) {
            self.request(r);
        }
        let size = self.canvas.render_size;
        if let Some(e) = self.compare.update(
            self.settings.compare,
            self.doc.as_ref(),
            size,
            self.settings.reference_spp,
            &mut self.viewport,
        ) {
            self.error = Some(e);
        }
        egui::CentralPanel::default().show(ui, |ui| self.viewport_ui(ui));
        // One drag of a slider is one undo step: the group ends when the button is up.
        if !ui.input(|i| i.pointer.any_down())
            && let Some(doc) = &mut self.doc
        {
            doc.close_group();
        }
        let target = self.target_name();
        for entry in self.library.show(&ctx, &mut self.settings, &target) {
            self.assign_file(entry.kind, &entry.path);
        }
        let dialogs = self
            .chrome
            .dialogs(ui, &mut self.error, &mut self.modes, self.doc.as_ref());
        for a in dialogs {
            self.act(&ctx, a);
        }
        self.chrome.title(&ctx, self.doc.as_ref());
        self.chrome.ui_frame_ms = start.elapsed().as_secs_f64() * 1e3;
    }

    /// The status bar's view of the studio.
    fn status_bar(&self) -> StatusBar<'_> {
        StatusBar {
            jobs: self.loader.jobs().chain(self.modes.job()).collect(),
            doc: self.doc.as_ref(),
            frame: self.viewport.frame(),
            from_device: self.viewport.shows_from_device(),
            settings: &self.settings,
            moving: self.canvas.moving,
            mode: self.modes.mode(),
            compare: &self.compare,
            latency: self.renderer.latency(),
            ui_frame_ms: self.chrome.ui_frame_ms,
            renderer_running: self.renderer.is_running(),
        }
    }

    /// The scene panel (left) and the material panel (right); what they ask for.
    fn panels(&mut self, ui: &mut Ui) -> Vec<Request> {
        let mut requests = Vec::new();
        let Some(doc) = &self.doc else {
            return requests;
        };
        self.loader.note_environment(doc);
        let state = PanelState {
            mode: self.modes.mode(),
            switching: self.modes.panel_switching(),
            disabled: self.modes.disabled(),
            environments: self.loader.environments(),
            environment_name: doc
                .scene
                .environment
                .as_ref()
                .and_then(|e| self.loader.environment_name(e)),
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
        requests
    }

    fn viewport_ui(&mut self, ui: &mut Ui) {
        let Some(camera) = self.doc.as_ref().map(|d| d.scene.camera) else {
            ui.centered_and_justified(|ui| ui.label("Open a scene (File > Open scene…)"));
            return;
        };
        let compare = self
            .settings
            .compare
            .then(|| self.compare.labels(self.modes.mode()));
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
        let resized = self.canvas.follow(&input, scale);
        if let Some(size) = resized.load {
            self.load_into_renderer(size);
        }
        for v in resized.views {
            self.view(v);
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
}
