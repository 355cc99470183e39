//! The window's chrome: the menus (File, Edit, View) and their shortcuts, the dialogs
//! (the last error, why a mode switch did not happen, a mode that cannot render some
//! lights, unsaved changes on quit, the BRDF explorer) and the window title. What it
//! cannot do itself (open, save, undo, switch) comes back to the studio as `Action`s,
//! so the chrome never reaches into the document or the render thread. The status bar
//! is in status_bar.rs.

use std::path::PathBuf;

use egui::{Key, KeyboardShortcut, Modifiers, Ui};
use meso_render::{Device, ModeKind};

use crate::document::Document;
use crate::explorer::Explorer;
use crate::mode_switch::ModeSwitch;
use crate::settings::Settings;
use meso_viewport::maker::mode_name;

pub const UNDO: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::Z);
pub const REDO: KeyboardShortcut =
    KeyboardShortcut::new(Modifiers::COMMAND.plus(Modifiers::SHIFT), Key::Z);
pub const SAVE: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::S);
pub const SAVE_AS: KeyboardShortcut =
    KeyboardShortcut::new(Modifiers::COMMAND.plus(Modifiers::SHIFT), Key::S);
pub const OPEN_PACK: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::O);
pub const EXPORT: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::E);

/// What a menu item, shortcut or dialog asks the studio to do.
pub enum Action {
    OpenSceneDialog,
    OpenPackDialog,
    OpenScene(PathBuf),
    OpenPack(PathBuf),
    Save,
    SaveAsDialog,
    ExportDialog,
    Undo,
    Redo,
    /// `Settings::max_samples` changed.
    MaxSamples,
    /// `Settings::denoise` changed.
    Denoise,
    /// `Settings::undo_budget_mb` changed.
    UndoBudget,
    /// Show this debug overlay (`None`: the image).
    Overlay(Option<&'static str>),
    /// The prompt's "switch with these lights disabled".
    SwitchWithoutLights(ModeKind, Device),
    /// The prompt's "turn on the environment and switch".
    /// The quit prompt's "Save": save, and close the window if that worked
    /// (`Chrome::close`).
    SaveAndQuit,
}

/// What the menus show besides the settings.
pub struct MenuState {
    pub can_undo: bool,
    pub can_redo: bool,
    /// The debug overlays the frame on screen has, and the one shown.
    pub overlays: Vec<&'static str>,
    pub overlay: Option<&'static str>,
}

/// The chrome's own state: the quit prompt, the explorer, the title, the UI time.
#[derive(Default)]
pub struct Chrome {
    /// Unsaved-changes prompt on quit, and whether closing is allowed now.
    quit_prompt: bool,
    allow_close: bool,
    explorer: Option<Explorer>,
    /// How long the last UI frame took, for the status bar.
    pub ui_frame_ms: f64,
    /// The window title last sent (sent again only when it changes).
    shown_title: String,
    /// (`Document::dirty_key`, dirty) of the last check.
    dirty_cache: ((usize, usize), bool),
}

/// The shortcuts pressed this frame, the longer ones first: Ctrl+Shift+Z would also
/// match Ctrl+Z.
pub fn shortcuts(ui: &Ui) -> Vec<Action> {
    [
        (REDO, Action::Redo),
        (UNDO, Action::Undo),
        (SAVE_AS, Action::SaveAsDialog),
        (SAVE, Action::Save),
        (OPEN_PACK, Action::OpenPackDialog),
        (EXPORT, Action::ExportDialog),
    ]
    .into_iter()
    .filter(|(s, _)| ui.input_mut(|i| i.consume_shortcut(s)))
    .map(|(_, a)| a)
    .collect()
}

/// The system's open-file dialog for `name` files ending in one of `extensions`.
pub fn pick_file(name: &str, extensions: &[&str]) -> Option<PathBuf> {
    rfd::FileDialog::new()
        .add_filter(name, extensions)
        .pick_file()
}

/// The system's save-file dialog offering `formats` (name, extensions).
pub fn save_file(formats: &[(&str, &[&str])]) -> Option<PathBuf> {
    formats
        .iter()
        .fold(rfd::FileDialog::new(), |d, (name, ext)| {
            d.add_filter(*name, ext)
        })
        .save_file()
}

/// The files dropped on the window this frame.
pub fn dropped_files(ui: &Ui) -> Vec<PathBuf> {
    ui.input(|i| {
        i.raw
            .dropped_files
            .iter()
            .map(|f| f.path().to_path_buf())
            .filter(|p| !p.as_os_str().is_empty())
            .collect()
    })
}

/// A dialog anchored at the top centre, `y` points down.
fn dialog(title: &str, y: f32) -> egui::Window<'static> {
    egui::Window::new(title)
        .collapsible(false)
        .resizable(false)
        .anchor(egui::Align2::CENTER_TOP, egui::vec2(0.0, y))
}

impl Chrome {
    /// The menu bar; settings change in place.
    pub fn menus(&mut self, ui: &mut Ui, settings: &mut Settings, state: MenuState) -> Vec<Action> {
        let mut actions = Vec::new();
        egui::MenuBar::new().ui(ui, |ui| {
            ui.menu_button("File", |ui| file_menu(ui, settings, &mut actions));
            ui.menu_button("Edit", |ui| {
                let ctx = ui.ctx().clone();
                let sc = |s: &KeyboardShortcut| ctx.format_shortcut(s);
                let undo = egui::Button::new("Undo").shortcut_text(sc(&UNDO));
                if ui.add_enabled(state.can_undo, undo).clicked() {
                    actions.push(Action::Undo);
                }
                let redo = egui::Button::new("Redo").shortcut_text(sc(&REDO));
                if ui.add_enabled(state.can_redo, redo).clicked() {
                    actions.push(Action::Redo);
                }
                ui.separator();
                let budget = egui::Slider::new(&mut settings.undo_budget_mb, 16..=8192)
                    .logarithmic(true)
                    .text("undo memory (MB)");
                if ui
                    .add(budget)
                    .on_hover_text("The oldest undo steps beyond this are dropped (the status bar says how many).")
                    .changed()
                {
                    actions.push(Action::UndoBudget);
                }
                ui.checkbox(&mut settings.journal, "Recovery journal")
                    .on_hover_text(
                        "Write every edit to a journal as it happens, so a crash loses nothing \
                         (from the next scene opened; docs/app.md)",
                    );
            });
            ui.menu_button("View", |ui| {
                if ui.button("BRDF explorer").clicked() {
                    self.explorer = Some(Explorer::default());
                }
                view_menu(ui, settings, &state, &mut actions);
            });
        });
        actions
    }

    /// `Document::dirty`, recomputed only when the packs involved change.
    pub fn dirty(&mut self, doc: Option<&Document>) -> bool {
        let Some(doc) = doc else { return false };
        let key = doc.dirty_key();
        if self.dirty_cache.0 != key {
            self.dirty_cache = (key, doc.dirty());
        }
        self.dirty_cache.1
    }

    /// Sends the window title for `doc` when it changed: the pack's file, marked
    /// while it has unsaved changes.
    pub fn title(&mut self, ctx: &egui::Context, doc: Option<&Document>) {
        let dirty = self.dirty(doc);
        let title = match doc {
            None => "Meso Studio".into(),
            Some(doc) => {
                let name = doc
                    .pack
                    .as_ref()
                    .and_then(|p| p.path.as_ref())
                    .and_then(|p| p.file_name())
                    .map_or("untitled".into(), |n| n.to_string_lossy().into_owned());
                format!("{}{name} — Meso Studio", if dirty { "● " } else { "" })
            }
        };
        if title != self.shown_title {
            ctx.send_viewport_cmd(egui::ViewportCommand::Title(title.clone()));
            self.shown_title = title;
        }
    }

    /// Closes the window (after the quit prompt).
    pub fn close(&mut self, ctx: &egui::Context) {
        self.allow_close = true;
        self.quit_prompt = false;
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
    }

    /// The dialogs: the last error (`error`, cleared by OK), the mode switch's
    /// message and prompt, the quit prompt when `doc` has unsaved changes, and the
    /// BRDF explorer.
    pub fn dialogs(
        &mut self,
        ui: &mut Ui,
        error: &mut Option<String>,
        modes: &mut ModeSwitch,
        doc: Option<&Document>,
    ) -> Vec<Action> {
        let ctx = ui.ctx().clone();
        let mut actions = Vec::new();
        if let Some(e) = error.clone() {
            dialog("Error", 40.0).show(&ctx, |ui| {
                ui.label(e);
                if ui.button("OK").clicked() {
                    *error = None;
                }
            });
        }
        if let Some(m) = modes.message().cloned() {
            dialog("Render mode", 120.0).show(&ctx, |ui| {
                ui.label(m);
                if ui.button("OK").clicked() {
                    modes.dismiss_message();
                }
            });
        }
        mode_prompt(&ctx, modes, &mut actions);
        // Quitting with unsaved edits asks first.
        if ctx.input(|i| i.viewport().close_requested()) && !self.allow_close && self.dirty(doc) {
            ctx.send_viewport_cmd(egui::ViewportCommand::CancelClose);
            self.quit_prompt = true;
        }
        if self.quit_prompt {
            self.quit_prompt(&ctx, &mut actions);
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
        actions
    }

    /// "Save the edited pack?": Save (then close), Discard (close), Cancel.
    fn quit_prompt(&mut self, ctx: &egui::Context, actions: &mut Vec<Action>) {
        let mut discard = false;
        let r = egui::Modal::new(egui::Id::unique("meso-quit-prompt")).show(ctx, |ui| {
            ui.heading("Save the edited pack?");
            ui.label("The pack has changes that are not saved.");
            ui.horizontal(|ui| {
                if ui.button("Save").clicked() {
                    actions.push(Action::SaveAndQuit);
                }
                if ui.button("Discard").clicked() {
                    discard = true;
                }
                if ui.button("Cancel").clicked() {
                    self.quit_prompt = false;
                }
            });
        });
        if r.should_close() {
            self.quit_prompt = false;
        }
        if discard {
            self.close(ctx);
        }
    }
}

/// The File menu.
fn file_menu(ui: &mut Ui, settings: &Settings, actions: &mut Vec<Action>) {
    let ctx = ui.ctx().clone();
    let sc = |s: &KeyboardShortcut| ctx.format_shortcut(s);
    if ui.button("Open scene…").clicked() {
        actions.push(Action::OpenSceneDialog);
    }
    let open_pack = egui::Button::new("Open pack…").shortcut_text(sc(&OPEN_PACK));
    if ui.add(open_pack).clicked() {
        actions.push(Action::OpenPackDialog);
    }
    ui.menu_button("Recent", |ui| {
        for p in &settings.recent_packs {
            if ui.button(p.display().to_string()).clicked() {
                actions.push(Action::OpenPack(p.clone()));
            }
        }
        ui.separator();
        for p in &settings.recent_scenes {
            if ui.button(p.display().to_string()).clicked() {
                actions.push(Action::OpenScene(p.clone()));
            }
        }
    });
    ui.separator();
    let items = [
        ("Save pack", SAVE, Action::Save),
        ("Save pack as…", SAVE_AS, Action::SaveAsDialog),
        ("Export frame…", EXPORT, Action::ExportDialog),
    ];
    for (label, shortcut, action) in items {
        if ui
            .add(egui::Button::new(label).shortcut_text(sc(&shortcut)))
            .clicked()
        {
            actions.push(action);
        }
    }
    ui.separator();
    if ui.button("Quit").clicked() {
        ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
    }
}

/// The View menu after the explorer: the library, exposure, samples, denoising,
/// timings, the compare view, debug overlays, reference samples, resolution.
fn view_menu(ui: &mut Ui, settings: &mut Settings, state: &MenuState, actions: &mut Vec<Action>) {
    ui.checkbox(&mut settings.show_library, "Material library");
    ui.add(egui::Slider::new(&mut settings.exposure, -8.0..=8.0).text("exposure (stops)"));
    if ui
        .add(
            egui::Slider::new(&mut settings.max_samples, 1..=65536)
                .logarithmic(true)
                .text("stop at spp"),
        )
        .changed()
    {
        actions.push(Action::MaxSamples);
    }
    if ui
        .checkbox(&mut settings.denoise, "Denoise the first frames")
        .on_hover_text(
            "An edge-aware filter guided by normal, depth and albedo, fading \
             out by 32 samples per pixel; saved images are never filtered",
        )
        .changed()
    {
        actions.push(Action::Denoise);
    }
    ui.checkbox(&mut settings.show_timings, "timings in the status bar");
    ui.checkbox(&mut settings.compare, "Compare with a reference");
    if !state.overlays.is_empty() {
        ui.horizontal(|ui| {
            ui.label("debug overlay");
            let mut chosen = state.overlay;
            ui.selectable_value(&mut chosen, None, "image");
            for &name in &state.overlays {
                ui.selectable_value(&mut chosen, Some(name), name);
            }
            actions.push(Action::Overlay(chosen));
        });
    }
    ui.add(
        egui::Slider::new(&mut settings.reference_spp, 1..=4096)
            .logarithmic(true)
            .text("reference spp"),
    );
    ui.horizontal(|ui| {
        ui.label("resolution");
        for (r, name) in [(0.25, "25%"), (0.5, "50%"), (1.0, "100%")] {
            ui.selectable_value(&mut settings.resolution, r, name);
        }
    });
}

/// "Switch render mode?": the mode asked for cannot render some lights; switch without
/// them, or stay.
fn mode_prompt(ctx: &egui::Context, modes: &mut ModeSwitch, actions: &mut Vec<Action>) {
    let Some(u) = modes.prompt().cloned() else {
        return;
    };
    let target = mode_name(u.mode, u.device);
    let current = mode_name(modes.mode().0, modes.mode().1);
    let parts: Vec<String> = u.parts.iter().map(|p| p.to_string()).collect();
    dialog("Switch render mode?", 120.0).show(ctx, |ui| {
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
                actions.push(Action::SwitchWithoutLights(u.mode, u.device));
            }
            if ui.button(format!("Stay in {current}")).clicked() {
                modes.stay();
            }
        });
    });
}
