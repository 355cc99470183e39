//! The material panel (right): the edited pack's clusters (pick one in the list, on
//! the texel map, or by clicking the object in the viewport), the chosen cluster's
//! dictionary (per basis: model, parameters within the spec ranges, normal as two
//! angles), a weight scale for all its texels shown as the cluster's mean weight
//! (colour picker and exact RGB entry), residual on/off and N_PCA, and the chosen
//! texel's lobe in the plane of incidence: all bases summed, and each basis.

use std::sync::Arc;

use egui::{Color32, ColorImage, TextureHandle, TextureOptions, Ui};
use glam::DVec3;
use meso_core::brdf::{AnalyticBrdf, BasisFunction, BrdfModel, LobePoint};
use meso_core::render::SceneEdit;
use meso_core::scene::Material;
use meso_core::spmm::SpmmMaterial;

use crate::document::Document;
use crate::explorer::{slider_is_logarithmic, smallest_positive};
use crate::lobe_plot::{self, Extra, Scale};

const LOBE_STEPS: usize = 181;
const BASIS_COLOURS: [Color32; 6] = [
    Color32::from_rgb(120, 200, 120),
    Color32::from_rgb(230, 200, 90),
    Color32::from_rgb(200, 120, 200),
    Color32::from_rgb(220, 220, 110),
    Color32::from_rgb(110, 200, 210),
    Color32::from_rgb(230, 110, 110),
];

pub struct MaterialPanel {
    pub cluster: usize,
    /// The texel whose lobe is shown (row-major); follows picks.
    pub texel: Option<usize>,
    pub theta_i_deg: f64,
    /// The texel map texture and the (material, cluster) it shows.
    map: Option<(TextureHandle, *const SpmmMaterial, usize)>,
}

impl Default for MaterialPanel {
    fn default() -> Self {
        Self {
            cluster: 0,
            texel: None,
            theta_i_deg: 40.0,
            map: None,
        }
    }
}

/// The chosen texel's lobe in the plane of incidence (phi = 0): per basis
/// w_lum rho_j(wi, wo) and their sum, as BTF values (cosine included).
pub fn texel_lobes(
    m: &SpmmMaterial,
    texel: usize,
    theta_i: f64,
) -> (Vec<LobePoint>, Vec<Vec<LobePoint>>) {
    let c = m.texel_cluster()[texel] as usize;
    let bases = &m.clusters()[c].bases;
    let wi = DVec3::new(-theta_i.sin(), 0.0, theta_i.cos());
    let angles: Vec<f64> = (0..LOBE_STEPS)
        .map(|k| {
            -std::f64::consts::FRAC_PI_2
                + std::f64::consts::PI * (k as f64 + 0.5) / LOBE_STEPS as f64
        })
        .collect();
    let per_basis: Vec<Vec<LobePoint>> = m
        .texel_weights(texel)
        .map(|(j, w)| {
            let lum =
                0.2126 * f64::from(w[0]) + 0.7152 * f64::from(w[1]) + 0.0722 * f64::from(w[2]);
            angles
                .iter()
                .map(|&t| LobePoint {
                    theta_o_rad: t,
                    value: lum * bases[usize::from(j)].eval(wi, DVec3::new(t.sin(), 0.0, t.cos())),
                })
                .collect()
        })
        .collect();
    let sum = angles
        .iter()
        .enumerate()
        .map(|(k, &t)| LobePoint {
            theta_o_rad: t,
            value: per_basis.iter().map(|b| b[k].value).sum(),
        })
        .collect();
    (sum, per_basis)
}

/// The SPMM material slot with `material` in place of its pack.
fn with_pack(slot: &Material, material: SpmmMaterial) -> Material {
    match slot {
        Material::Spmm {
            uv_scale,
            residual,
            npca,
            ..
        } => Material::Spmm {
            material: Arc::new(material),
            uv_scale: *uv_scale,
            residual: *residual,
            npca: *npca,
        },
        other => other.clone(),
    }
}

impl MaterialPanel {
    /// Shows the panel; returns the edits the user made this frame.
    pub fn show(&mut self, ui: &mut Ui, doc: &Document) -> Vec<SceneEdit> {
        let mut edits = Vec::new();
        let (Some(pack), Some(m)) = (&doc.pack, doc.material()) else {
            ui.label("The scene has no SPMM material to edit.");
            return edits;
        };
        let index = pack.material;
        let slot = &doc.scene.materials[index];
        let Material::Spmm {
            residual,
            npca,
            uv_scale,
            ..
        } = slot
        else {
            return edits;
        };
        self.cluster = self.cluster.min(m.clusters().len().saturating_sub(1));
        ui.heading(m.name());
        ui.label(format!(
            "{} · {} clusters · {}x{} texels · N_PCA {}{}",
            pack.path
                .as_ref()
                .and_then(|p| p.file_name())
                .map_or("unsaved".into(), |n| n.to_string_lossy()),
            m.clusters().len(),
            m.width(),
            m.height(),
            m.npca(),
            if m.edited() { " · edited" } else { "" }
        ));

        // Residual and N_PCA: settings of the scene's material slot.
        ui.add_enabled_ui(m.residual().is_some(), |ui| {
            let mut on = *residual;
            let mut k = *npca;
            let a = ui
                .checkbox(&mut on, "Residual")
                .on_hover_text("the per-cluster PCA residual (skipped while the camera moves)");
            let b = ui.add(
                egui::Slider::new(&mut k, 0..=m.npca())
                    .clamping(egui::SliderClamping::Edits)
                    .text("N_PCA"),
            );
            if a.changed() || b.changed() {
                edits.push(SceneEdit::Material {
                    index,
                    material: Material::Spmm {
                        material: Arc::clone(&m),
                        uv_scale: *uv_scale,
                        residual: on,
                        npca: k,
                    },
                });
            }
        });
        if m.residual().is_none() {
            ui.weak("this pack has no residual");
        }

        ui.separator();
        ui.strong("Clusters");
        ui.horizontal_top(|ui| {
            ui.vertical(|ui| {
                ui.set_width((ui.available_width() - 130.0).max(120.0));
                egui::ScrollArea::vertical()
                    .id_salt("clusters")
                    .max_height(120.0)
                    .show(ui, |ui| {
                        for c in 0..m.clusters().len() {
                            let texels = m
                                .texel_cluster()
                                .iter()
                                .filter(|&&t| t as usize == c)
                                .count();
                            let label = format!(
                                "{c}: {texels} texels, {} bases",
                                m.clusters()[c].bases.len()
                            );
                            if ui.selectable_label(self.cluster == c, label).clicked() {
                                self.cluster = c;
                                self.texel = None;
                            }
                        }
                    });
            });
            self.texel_map(ui, &m);
        });

        let c = self.cluster;
        ui.separator();
        ui.strong(format!("Cluster {c}: mean weight"));
        let mean = m.cluster_mean_weight(c);
        let mut rgb = mean.map(|v| v as f32);
        let mut changed = false;
        ui.horizontal(|ui| {
            let mut shown = rgb.map(|v| v.clamp(0.0, 1.0));
            if egui::widgets::color_picker::color_edit_button_rgb(ui, &mut shown).changed() {
                rgb = shown;
                changed = true;
            }
            for (k, name) in ["R", "G", "B"].into_iter().enumerate() {
                ui.add_enabled_ui(mean[k] > 0.0, |ui| {
                    let label = ui.label(name);
                    changed |= ui
                        .add(
                            egui::DragValue::new(&mut rgb[k])
                                .range(0.0..=f32::MAX)
                                .clamp_existing_to_range(false)
                                .speed(0.002),
                        )
                        .labelled_by(label.id)
                        .changed();
                });
            }
        });
        if changed {
            let scale = [0, 1, 2].map(|k| {
                if mean[k] > 0.0 {
                    f64::from(rgb[k]) / mean[k]
                } else {
                    1.0
                }
            });
            if let Ok(e) = m.with_cluster_weight_scale(c, scale) {
                edits.push(SceneEdit::Material {
                    index,
                    material: with_pack(slot, e),
                });
            }
        }

        ui.separator();
        let texel = self
            .texel
            .filter(|&t| m.texel_cluster().get(t).is_some_and(|&tc| tc as usize == c))
            .or_else(|| m.texel_cluster().iter().position(|&tc| tc as usize == c));
        if let Some(t) = texel {
            ui.strong(format!(
                "Lobe of texel ({}, {})",
                t % m.width() as usize,
                t / m.width() as usize
            ));
            ui.add(egui::Slider::new(&mut self.theta_i_deg, 0.0..=89.0).text("incidence (deg)"));
            let (sum, parts) = texel_lobes(&m, t, self.theta_i_deg.to_radians());
            let extra: Vec<Extra<'_>> = parts
                .iter()
                .enumerate()
                .map(|(k, p)| Extra {
                    points: p,
                    color: BASIS_COLOURS[k % BASIS_COLOURS.len()],
                })
                .collect();
            lobe_plot::show(
                ui,
                &sum,
                &extra,
                self.theta_i_deg.to_radians(),
                Scale::Linear,
                190.0,
            );
            ui.weak("blue: all bases summed (luminance of the weights, BTF incl. cos); thin: each basis");
        }
        ui.separator();
        ui.strong(format!("Cluster {c}: dictionary"));
        for (j, basis) in m.clusters()[c].bases.iter().enumerate() {
            if let Some(b) = basis_editor(ui, c, j, basis)
                && let Ok(e) = m.with_basis(c, j, b)
            {
                edits.push(SceneEdit::Material {
                    index,
                    material: with_pack(slot, e),
                });
            }
        }

        edits
    }

    /// The texel grid coloured by each texel's summed weights, the chosen cluster at
    /// full strength and the rest dimmed; a click chooses the texel and its cluster.
    fn texel_map(&mut self, ui: &mut Ui, m: &Arc<SpmmMaterial>) {
        let key = Arc::as_ptr(m);
        if self
            .map
            .as_ref()
            .is_none_or(|(_, k, c)| *k != key || *c != self.cluster)
        {
            let pixels: Vec<Color32> = (0..m.texel_cluster().len())
                .map(|t| {
                    let w = m.texel_weights(t).fold([0.0f32; 3], |a, (_, w)| {
                        [a[0] + w[0], a[1] + w[1], a[2] + w[2]]
                    });
                    let dim = if m.texel_cluster()[t] as usize == self.cluster {
                        1.0
                    } else {
                        0.25
                    };
                    let g = |v: f32| ((v * dim).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0) as u8;
                    Color32::from_rgb(g(w[0]), g(w[1]), g(w[2]))
                })
                .collect();
            let image = ColorImage {
                size: [m.width() as usize, m.height() as usize],
                source_size: egui::vec2(m.width() as f32, m.height() as f32),
                pixels,
            };
            let texture = ui
                .ctx()
                .load_texture("texel-map", image, TextureOptions::NEAREST);
            self.map = Some((texture, key, self.cluster));
        }
        if let Some((texture, _, _)) = &self.map {
            let side = ui.available_width().min(120.0);
            let response = ui.add(
                egui::Image::new((texture.id(), egui::vec2(side, side)))
                    .sense(egui::Sense::click()),
            );
            if response.clicked()
                && let Some(p) = response.interact_pointer_pos()
            {
                let rel = (p - response.rect.min) / response.rect.size();
                let x = ((rel.x * m.width() as f32) as u32).min(m.width() - 1);
                let y = ((rel.y * m.height() as f32) as u32).min(m.height() - 1);
                let t = (y * m.width() + x) as usize;
                self.texel = Some(t);
                self.cluster = m.texel_cluster()[t] as usize;
            }
            response
                .on_hover_text("texels coloured by their weights; the chosen cluster is bright");
        }
    }
}

/// The editor of one basis function; returns the edited basis when it changed.
fn basis_editor(
    ui: &mut Ui,
    cluster: usize,
    j: usize,
    basis: &BasisFunction,
) -> Option<BasisFunction> {
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
            let mut model = brdf.model();
            ui.horizontal(|ui| {
                let label = ui.label("model");
                egui::ComboBox::from_id_salt(("model", cluster, j))
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
                brdf = AnalyticBrdf::with_defaults(model);
                changed = true;
            }
            for (spec, mut value) in brdf.model().param_specs().iter().zip(brdf.param_values()) {
                let slider = egui::Slider::new(&mut value, spec.min..=spec.max)
                    .clamping(egui::SliderClamping::Edits)
                    .text(spec.name)
                    .logarithmic(slider_is_logarithmic(spec))
                    .smallest_positive(smallest_positive(spec))
                    .max_decimals(6);
                if ui.add(slider).on_hover_text(spec.doc).changed()
                    && let Ok(b) = brdf.with_param(spec.name, value)
                {
                    brdf = b;
                    changed = true;
                }
            }
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
        });
    if !(changed || normal_changed) {
        return None;
    }
    // The normal is rebuilt from the angles only when they moved, so a parameter edit
    // keeps it bit for bit.
    let normal = if normal_changed {
        let (t, p) = (theta.to_radians(), phi.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    } else {
        n
    };
    BasisFunction::new(brdf, normal).ok()
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

    #[test]
    fn the_texel_lobe_is_the_sum_of_its_bases() {
        let m = meso_core::spmm::pack::read_pack(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../materials/leather.spmm"
        )))
        .expect("the shipped leather pack");
        let (sum, parts) = texel_lobes(&m, 0, 0.6);
        assert_eq!(parts.len(), m.texel_weights(0).count());
        for (k, p) in sum.iter().enumerate() {
            let s: f64 = parts.iter().map(|b| b[k].value).sum();
            assert!((p.value - s).abs() <= 1e-12 * s.abs().max(1e-12));
        }
        assert!(sum.iter().any(|p| p.value > 0.0));
    }
}
