//! The status bar along the window's bottom: background jobs with their time, the
//! frame's samples, size and film, resident material bytes, timings, the mode's
//! summary (and whether the frame was shown from the device), the edited pack's
//! parts, the compare view's numbers, latency and the UI's time. A read-only view
//! (`StatusBar`) of what the studio holds, so drawing it changes nothing.

use std::time::Instant;

use egui::Ui;
use meso_render::scene::Material;
use meso_render::{Device, ModeKind};

use crate::compare::CompareView;
use crate::document::Document;
use crate::render_link::Latency;
use crate::settings::Settings;
use meso_viewport::worker::Frame;

/// What the status bar shows, borrowed from the studio for one frame.
pub struct StatusBar<'a> {
    /// Background jobs in progress: name and start.
    pub jobs: Vec<(&'a String, Instant)>,
    pub doc: Option<&'a Document>,
    /// The frame on screen and whether it was shown without leaving the device.
    pub frame: Option<&'a Frame>,
    pub from_device: bool,
    pub settings: &'a Settings,
    /// The camera is being dragged.
    pub moving: bool,
    pub mode: (ModeKind, Device),
    pub compare: &'a CompareView,
    pub latency: Latency,
    pub ui_frame_ms: f64,
    pub renderer_running: bool,
}

impl StatusBar<'_> {
    pub fn show(&self, ui: &mut Ui) {
        ui.horizontal_wrapped(|ui| {
            for (name, started) in &self.jobs {
                ui.spinner();
                ui.label(format!("{name}… {:.1} s", started.elapsed().as_secs_f64()));
                ui.separator();
            }
            let Some(doc) = self.doc else {
                ui.label("no scene");
                return;
            };
            match self.frame {
                Some(f) => self.frame_status(ui, f),
                None => {
                    ui.label("waiting for the first frame");
                }
            }
            ui.separator();
            self.pack_status(ui, doc);
            self.safety_status(ui, doc);
            if self.settings.compare {
                ui.separator();
                self.compare.status(ui, self.mode);
            }
            if self.settings.show_timings {
                ui.separator();
                if let Some(ms) = self.latency.last_edit_to_frame_ms {
                    ui.label(format!("edit to frame {ms:.0} ms"));
                }
                ui.label(format!("UI {:.1} ms", self.ui_frame_ms));
            }
            if !self.renderer_running {
                ui.colored_label(ui.visuals().error_fg_color, "the render thread stopped");
            }
        });
    }

    /// The frame on screen: samples, size, film, materials, timings, summary.
    fn frame_status(&self, ui: &mut Ui, f: &Frame) {
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
            if self.from_device {
                ui.label(format!("{summary} · shown from the device"))
                    .on_hover_text(
                        "The frame goes from the GPU mode's film to the window without a copy through the host.",
                    );
            } else {
                ui.label(summary);
            }
        }
    }

    /// The edited pack: clusters, and which parts render (fewer N_PCA while moving).
    fn pack_status(&self, ui: &mut Ui, doc: &Document) {
        let Some(p) = &doc.pack else { return };
        let Material::Spmm {
            material,
            residual,
            npca,
            ..
        } = &doc.scene.materials[p.material]
        else {
            return;
        };
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

    /// Undo's memory and what it dropped; the journal, or why it cannot be written.
    fn safety_status(&self, ui: &mut Ui, doc: &Document) {
        let u = doc.undo_stats();
        if u.dropped > 0 || u.bytes * 2 > u.budget {
            ui.separator();
            let mut text = format!(
                "undo {} steps · {:.0} of {} MB",
                u.steps,
                u.bytes as f64 / (1 << 20) as f64,
                u.budget >> 20
            );
            if u.dropped > 0 {
                text += &format!(" · {} oldest dropped", u.dropped);
            }
            ui.label(text).on_hover_text(
                "Undo keeps at most its budget (Settings: undo_budget_mb); the oldest steps beyond it are dropped.",
            );
        }
        if let Some(e) = doc.journal_error() {
            ui.separator();
            ui.colored_label(ui.visuals().error_fg_color, "not journaled")
                .on_hover_text(e);
        } else if let Some(j) = doc.journal() {
            ui.separator();
            ui.label("journaled").on_hover_text(format!(
                "Every edit is written to {} within a quarter of a second; after a crash the studio offers it back.",
                j.path().display()
            ));
        }
    }
}
