//! The studio's side of never losing work: the offer at start to restore sessions
//! that ended without saving (their journals, `meso_session::recover`), the question
//! asked when the edited pack's file changed on disk (reload, overwrite, save as, or
//! keep editing), and a scripted run (`--run SCRIPT.toml`) walked one UI frame at a
//! time. What to do is returned as `Ask`s; the studio does it.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use egui::Context;
use meso_session::recover::Session;
use meso_session::script::Runner;

/// What the user chose.
#[derive(Debug, Clone, PartialEq)]
pub enum Ask {
    Restore(Session),
    Discard(PathBuf),
    Reload,
    Overwrite,
    SaveAs,
}

/// How often the edited pack's file is checked for changes by other programs.
const CHECK_EVERY: Duration = Duration::from_secs(2);

#[derive(Default)]
pub struct Recovery {
    /// Sessions to offer, newest first; empty when answered.
    pub offer: Vec<Session>,
    /// The edited pack's file changed on disk: the question is open.
    pub conflict: Option<PathBuf>,
    /// A change the user chose to keep editing over (not asked again until the file
    /// changes again): its path and modification time.
    kept_over: Option<(PathBuf, Option<std::time::SystemTime>)>,
    last_check: Option<Instant>,
    /// A scripted run in progress.
    pub script: Option<Runner>,
}

fn modified(p: &std::path::Path) -> Option<std::time::SystemTime> {
    std::fs::metadata(p).and_then(|m| m.modified()).ok()
}

impl Recovery {
    /// Whether the pack file's state is due a check now.
    pub fn check_due(&mut self, now: Instant) -> bool {
        let due = self.last_check.is_none_or(|t| now - t >= CHECK_EVERY);
        if due {
            self.last_check = Some(now);
        }
        due
    }

    /// The edited pack's file changed on disk: ask, unless the user kept editing over
    /// this very change.
    pub fn changed_on_disk(&mut self, path: PathBuf) {
        let kept = self
            .kept_over
            .as_ref()
            .is_some_and(|(p, t)| *p == path && *t == modified(&path));
        if !kept && self.conflict.is_none() {
            self.conflict = Some(path);
        }
    }

    pub fn show(&mut self, ctx: &Context) -> Vec<Ask> {
        let mut asks = Vec::new();
        if !self.offer.is_empty() {
            self.offer_window(ctx, &mut asks);
        }
        if let Some(path) = self.conflict.clone() {
            self.conflict_window(ctx, &path, &mut asks);
        }
        asks
    }

    fn offer_window(&mut self, ctx: &Context, asks: &mut Vec<Ask>) {
        let mut later = false;
        egui::Window::new("Restore unsaved work?")
            .collapsible(false)
            .resizable(false)
            .anchor(egui::Align2::CENTER_TOP, egui::vec2(0.0, 80.0))
            .show(ctx, |ui| {
                ui.label("These sessions ended without saving. Their edits are in recovery journals.");
                for s in &self.offer {
                    ui.separator();
                    let scene = s
                        .scene
                        .as_ref()
                        .map_or("the default scene".into(), |p| p.display().to_string());
                    let packs: Vec<String> = s.packs.iter().map(|p| p.display().to_string()).collect();
                    ui.label(format!(
                        "{} edits, {} to {}\nscene: {scene}\npacks: {}",
                        s.edits,
                        s.started,
                        s.last_edit,
                        if packs.is_empty() { "none".into() } else { packs.join(", ") }
                    ));
                    ui.horizontal(|ui| {
                        if ui.button("Restore").clicked() {
                            asks.push(Ask::Restore(s.clone()));
                        }
                        if ui.button("Discard").clicked() {
                            asks.push(Ask::Discard(s.journal.clone()));
                        }
                    });
                }
                ui.separator();
                if ui
                    .button("Later")
                    .on_hover_text("Keep the journals; they are offered at the next start and `meso recover` reads them.")
                    .clicked()
                {
                    later = true;
                }
            });
        if later {
            self.offer.clear();
        }
        for a in asks.iter() {
            match a {
                Ask::Restore(s) => self.offer.retain(|o| o.journal != s.journal),
                Ask::Discard(p) => self.offer.retain(|o| &o.journal != p),
                _ => {}
            }
        }
    }

    fn conflict_window(&mut self, ctx: &Context, path: &std::path::Path, asks: &mut Vec<Ask>) {
        let mut keep = false;
        let before = asks.len();
        egui::Window::new("The pack changed on disk")
            .collapsible(false)
            .resizable(false)
            .anchor(egui::Align2::CENTER_TOP, egui::vec2(0.0, 120.0))
            .show(ctx, |ui| {
                ui.label(format!(
                    "Another program changed `{}` since it was opened. Your edits are kept \
                     (and journaled) whatever you choose.",
                    path.display()
                ));
                ui.horizontal(|ui| {
                    if ui
                        .button("Reload theirs")
                        .on_hover_text("Undo brings your edits back.")
                        .clicked()
                    {
                        asks.push(Ask::Reload);
                    }
                    if ui.button("Overwrite with mine").clicked() {
                        asks.push(Ask::Overwrite);
                    }
                    if ui.button("Save mine as…").clicked() {
                        asks.push(Ask::SaveAs);
                    }
                    if ui.button("Keep editing").clicked() {
                        keep = true;
                    }
                });
            });
        if keep {
            self.kept_over = Some((path.to_path_buf(), modified(path)));
        }
        if keep || asks.len() > before {
            self.conflict = None;
        }
    }
}
