//! The material panel's dictionary section: the chosen cluster's basis functions,
//! each in its editor (model, parameters within the spec ranges, the normal as two
//! angles on a hemisphere disk), with duplicate, remove (confirmed) and add. Apart
//! from material_panel.rs because a basis's editor is a widget of its own; the panel
//! turns the edited material into the scene edit.

use egui::{Color32, Ui};
use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use meso_materials::spmm::SpmmMaterial;

use crate::brdf_editor::brdf_editor;

/// The dictionary section's own state.
#[derive(Default)]
pub struct Dictionary {
    /// A basis removal waiting for confirmation: (cluster, basis).
    confirm_remove: Option<(usize, usize)>,
    /// Why the last removal was refused (the cluster's only basis).
    remove_error: Option<String>,
}

impl Dictionary {
    /// Cluster `c`'s dictionary of `m`: the material with the edit made (if any), and
    /// whether a basis was removed.
    pub fn show(
        &mut self,
        ui: &mut Ui,
        m: &SpmmMaterial,
        c: usize,
    ) -> (Option<SpmmMaterial>, bool) {
        let mut removed = false;
        ui.separator();
        ui.strong(format!("Cluster {c}: dictionary"));
        let mut pending = None;
        for (j, basis) in m.clusters()[c].bases.iter().enumerate() {
            let (edited, action) = basis_editor(ui, c, j, basis);
            if let Some(b) = edited
                && let Ok(e) = m.with_basis(c, j, b)
            {
                pending = Some(e);
            }
            match action {
                Some(DictionaryAction::Duplicate) => {
                    pending = m.with_basis_duplicated(c, j).ok().map(|(e, _)| e);
                }
                Some(DictionaryAction::Remove) => self.confirm_remove = Some((c, j)),
                None => {}
            }
        }
        if let Some((rc, rj)) = self.confirm_remove {
            ui.horizontal_wrapped(|ui| {
                ui.colored_label(
                    ui.visuals().warn_fg_color,
                    format!("Remove basis {rj} of cluster {rc} and all its weights?"),
                );
                if ui.button("Remove").clicked() {
                    match m.with_basis_removed(rc, rj) {
                        Ok(e) => pending = Some(e),
                        Err(e) => self.remove_error = Some(e.to_string()),
                    }
                    removed = true;
                    self.confirm_remove = None;
                }
                if ui.button("Cancel").clicked() {
                    self.confirm_remove = None;
                }
            });
        }
        if let Some(e) = &self.remove_error {
            ui.colored_label(ui.visuals().error_fg_color, e);
        }
        if ui
        .button("Add basis")
        .on_hover_text("a Lambertian basis along the macro normal with no weight yet: paint it in (brush: Add) or edit it above")
        .clicked()
    {
        let b = BasisFunction::new(AnalyticBrdf::with_defaults(BrdfModel::Lambertian), DVec3::Z)
            .expect("+z is a unit normal");
        pending = m.with_basis_added(c, b).ok().map(|(e, _)| e);
    }
        (pending, removed)
    }
}

/// A dictionary edit asked for from a basis's editor.
enum DictionaryAction {
    Duplicate,
    Remove,
}

/// The editor of one basis function; returns the edited basis when it changed, and
/// a duplicate or remove request.
fn basis_editor(
    ui: &mut Ui,
    cluster: usize,
    j: usize,
    basis: &BasisFunction,
) -> (Option<BasisFunction>, Option<DictionaryAction>) {
    let mut action = None;
    let mut brdf = *basis.brdf();
    let n = basis.normal();
    let mut theta = n.z.clamp(-1.0, 1.0).acos().to_degrees();
    let mut phi = n.y.atan2(n.x).to_degrees().rem_euclid(360.0);
    let mut changed = false;
    let mut normal_changed = false;
    egui::CollapsingHeader::new(format!("basis {j} · {}", brdf.model().name()))
        .id_salt(("basis", cluster, j))
        .default_open(j == 0)
        .show(ui, |ui| {
            changed |= brdf_editor(ui, (cluster, j), &mut brdf);
            ui.horizontal(|ui| {
                normal_changed |= hemisphere(ui, &mut theta, &mut phi);
                ui.vertical(|ui| {
                    normal_changed |= ui
                        .add(
                            egui::Slider::new(&mut theta, 0.0..=MAX_TILT_DEG)
                                .clamping(egui::SliderClamping::Edits)
                                .text("normal θ (deg)"),
                        )
                        .changed();
                    normal_changed |= ui
                        .add(
                            egui::Slider::new(&mut phi, 0.0..=360.0)
                                .clamping(egui::SliderClamping::Edits)
                                .text("normal φ (deg)"),
                        )
                        .changed();
                });
            });
            ui.horizontal(|ui| {
                if ui
                    .button(format!("Duplicate basis {j}"))
                    .on_hover_text("append a copy with no weights: edit one, keep the other")
                    .clicked()
                {
                    action = Some(DictionaryAction::Duplicate);
                }
                if ui.button(format!("Remove basis {j}…")).clicked() {
                    action = Some(DictionaryAction::Remove);
                }
            });
        });
    if !(changed || normal_changed) {
        return (None, action);
    }
    // The normal is rebuilt from the angles only when they moved, so a parameter edit
    // keeps it bit for bit.
    let normal = if normal_changed {
        let (t, p) = (theta.to_radians(), phi.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    } else {
        n
    };
    (BasisFunction::new(brdf, normal).ok(), action)
}

/// Largest tilt of a basis normal the editor offers (the spec needs z > 0).
const MAX_TILT_DEG: f64 = 85.0;

/// Where a normal at (theta, phi) degrees sits on the hemisphere disk of radius 1
/// (orthographic view from above: x = sin theta cos phi, y = sin theta sin phi).
pub fn disk_position(theta_deg: f64, phi_deg: f64) -> (f64, f64) {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    (t.sin() * p.cos(), t.sin() * p.sin())
}

/// The normal under a disk position, its tilt limited to `MAX_TILT_DEG`.
pub fn normal_at_disk(x: f64, y: f64) -> (f64, f64) {
    let r = x.hypot(y).min(MAX_TILT_DEG.to_radians().sin());
    let theta = r.asin().to_degrees();
    let phi = if r > 0.0 {
        y.atan2(x).to_degrees().rem_euclid(360.0)
    } else {
        0.0
    };
    (theta, phi)
}

/// A small draggable hemisphere seen from above: the dot is the normal; drag it to
/// tilt (the rim is grazing, the centre the macro normal; +x to the right is the
/// tangent, +y up the bitangent).
fn hemisphere(ui: &mut Ui, theta: &mut f64, phi: &mut f64) -> bool {
    let size = 64.0;
    let (rect, response) = ui.allocate_exact_size(egui::vec2(size, size), egui::Sense::drag());
    let c = rect.center();
    let r = size * 0.5 - 3.0;
    let painter = ui.painter();
    let weak = ui.visuals().weak_text_color();
    painter.circle_stroke(c, r, egui::Stroke::new(1.0, weak));
    painter.circle_stroke(
        c,
        r * MAX_TILT_DEG.to_radians().sin() as f32 * 0.5,
        egui::Stroke::new(0.5, weak.gamma_multiply(0.5)),
    );
    painter.line_segment(
        [c - egui::vec2(r, 0.0), c + egui::vec2(r, 0.0)],
        egui::Stroke::new(0.5, weak),
    );
    painter.line_segment(
        [c - egui::vec2(0.0, r), c + egui::vec2(0.0, r)],
        egui::Stroke::new(0.5, weak),
    );
    let mut changed = false;
    if let Some(p) = response.interact_pointer_pos()
        && response.dragged()
    {
        let d = (p - c) / r;
        let (t, f) = normal_at_disk(f64::from(d.x), f64::from(-d.y));
        *theta = t;
        *phi = f;
        changed = true;
    }
    let (x, y) = disk_position(*theta, *phi);
    let dot = c + egui::vec2(x as f32, -(y as f32)) * r;
    painter.circle_filled(dot, 4.0, Color32::from_rgb(90, 170, 255));
    response.on_hover_text("drag to tilt the basis normal (centre: along the macro normal)");
    changed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disk_positions_and_normals_are_inverse_and_the_tilt_is_limited() {
        for (t, p) in [(0.0, 0.0), (30.0, 45.0), (60.0, 300.0), (85.0, 180.0)] {
            let (x, y) = disk_position(t, p);
            let (t2, p2) = normal_at_disk(x, y);
            assert!((t - t2).abs() < 1e-9, "{t} {t2}");
            if t > 0.0 {
                assert!((p - p2).abs() < 1e-9, "{p} {p2}");
            }
        }
        // Beyond the rim: clamped to the largest tilt, direction kept.
        let (t, p) = normal_at_disk(0.0, -3.0);
        assert!((t - MAX_TILT_DEG).abs() < 1e-9 && (p - 270.0).abs() < 1e-9);
    }
}
