//! Editors shared by the panels: one analytic BRDF (model and parameters on sliders
//! within docs/brdf.md's ranges) and an RGB value that may exceed 1 (a colour button
//! for picking, exact entry for every value; nothing is clamped unless picked).

use std::hash::Hash;

use egui::Ui;
use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel, ParamSpec};

/// Logarithmic where the spec says so, and also for ranges many times wider than the
/// default's magnitude (Lafortune's cx, cy, cz in [-1000, 1000] around -1 or 1), so
/// that the useful values are not crowded into a few pixels of the rail.
pub(crate) fn slider_is_logarithmic(spec: &ParamSpec) -> bool {
    spec.log_scale || (spec.default != 0.0 && spec.max - spec.min > 100.0 * spec.default.abs())
}

/// For a logarithmic slider whose range reaches zero: six decades below the largest
/// magnitude (exponent n of Blinn-Phong: 0.1 .. 1e5).
pub(crate) fn smallest_positive(spec: &ParamSpec) -> f64 {
    if spec.min > 0.0 {
        spec.min
    } else {
        spec.max.abs().max(spec.min.abs()) * 1e-6
    }
}

/// A model picker (`salt` keeps pickers of several BRDFs apart) and a slider per
/// parameter; a new model starts at its defaults. True if `brdf` changed.
pub(crate) fn brdf_editor(
    ui: &mut Ui,
    salt: impl Hash + std::fmt::Debug,
    brdf: &mut AnalyticBrdf,
) -> bool {
    let mut changed = false;
    let mut model = brdf.model();
    ui.horizontal(|ui| {
        let label = ui.label("model");
        egui::ComboBox::from_id_salt(("model", salt))
            .selected_text(model.name())
            .show_ui(ui, |ui| {
                for m in BrdfModel::ALL {
                    ui.selectable_value(&mut model, m, m.name());
                }
            })
            .response
            .labelled_by(label.id);
    });
    if model != brdf.model() {
        *brdf = AnalyticBrdf::with_defaults(model);
        changed = true;
    }
    for (spec, mut value) in brdf.model().param_specs().iter().zip(brdf.param_values()) {
        let slider = egui::Slider::new(&mut value, spec.min..=spec.max)
            .clamping(egui::SliderClamping::Edits)
            .text(spec.name)
            .logarithmic(slider_is_logarithmic(spec))
            .smallest_positive(smallest_positive(spec))
            .max_decimals(6);
        // The range is the spec's, so a value the slider gives is accepted.
        if ui.add(slider).on_hover_text(spec.doc).changed()
            && let Ok(b) = brdf.with_param(spec.name, value)
        {
            *brdf = b;
            changed = true;
        }
    }
    changed
}

/// `label`, a colour button (showing `v` clamped to [0, 1]; picking sets all three)
/// and exact non-negative entry of R, G and B, named `{name} R` and so on for
/// assistive technology and tests. True if `v` changed.
pub(crate) fn rgb_editor(ui: &mut Ui, label: &str, name: &str, v: &mut DVec3) -> bool {
    let mut changed = false;
    ui.horizontal(|ui| {
        ui.label(label);
        let mut shown = v
            .as_vec3()
            .clamp(glam::Vec3::ZERO, glam::Vec3::ONE)
            .to_array();
        if egui::widgets::color_picker::color_edit_button_rgb(ui, &mut shown).changed() {
            *v = glam::Vec3::from_array(shown).as_dvec3();
            changed = true;
        }
        for (value, channel) in [(&mut v.x, "R"), (&mut v.y, "G"), (&mut v.z, "B")] {
            ui.label(channel);
            let drag = egui::DragValue::new(value)
                .range(0.0..=f64::MAX)
                .clamp_existing_to_range(false)
                .speed(0.002)
                .max_decimals(4);
            changed |= ui
                .add(drag)
                .accessible_name(format!("{name} {channel}"))
                .changed();
        }
    });
    changed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wide_ranges_get_logarithmic_sliders() {
        let lafortune = BrdfModel::Lafortune.param_specs();
        assert!(lafortune.iter().all(slider_is_logarithmic));
        let cook = BrdfModel::CookTorrance.param_specs();
        assert!(slider_is_logarithmic(&cook[0]) && !slider_is_logarithmic(&cook[1]));
        let n = &BrdfModel::BlinnPhong.param_specs()[0];
        assert!((smallest_positive(n) - 0.1).abs() < 1e-12);
    }
}
