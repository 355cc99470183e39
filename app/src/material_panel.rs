//! The material panel (right): the edited pack's clusters (pick one in the list, on
//! the texel map, or by clicking the object in the viewport), the chosen cluster's
//! dictionary (per basis: model, parameters within the spec ranges, normal as two
//! angles; add, duplicate, remove), a weight scale for all its texels shown as the
//! cluster's mean weight (colour picker and exact RGB entry), one row per basis (its
//! mean weight as a colour and exact RGB, a multiplier, mute and solo), the weight
//! brush's settings and the selection mask (`PaintState`; strokes are painted in the
//! viewport or on the texel map), residual on/off and N_PCA (and, for an edited
//! cluster with a fitted residual, the choice to keep it or turn it off), and the
//! chosen texel's lobe in the plane of incidence: all bases summed, and each basis.

use std::sync::Arc;

use egui::{Color32, ColorImage, TextureHandle, TextureOptions, Ui};
use glam::DVec3;
use meso_materials::brdf::LobePoint;
use meso_materials::spmm::{Falloff, SpmmMaterial, TexelMask, WeightTarget};
use meso_render::SceneEdit;
use meso_render::geometry::{Brush, BrushUnits};
use meso_render::scene::Material;

use crate::dictionary::Dictionary;
use crate::document::Document;
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
    /// The texel map texture and the (material, cluster, selection shown) it shows.
    map: Option<(TextureHandle, *const SpmmMaterial, usize, bool)>,
    pub paint: PaintState,
    /// The chosen cluster's dictionary editor.
    dictionary: Dictionary,
    /// Clusters whose fitted residual the designer chose to keep after editing.
    residual_kept: Vec<usize>,
}

impl Default for MaterialPanel {
    fn default() -> Self {
        Self {
            cluster: 0,
            texel: None,
            theta_i_deg: 40.0,
            map: None,
            paint: PaintState::default(),
            dictionary: Dictionary::default(),
            residual_kept: Vec::new(),
        }
    }
}

/// What a brush stroke does to the weights under it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PaintOp {
    /// Multiplies the target's weights by the factor (no new weights).
    Scale,
    /// Adds the amount to the target basis's weight (paints a basis in).
    Add,
    /// Paints the selection mask instead of weights.
    Select,
}

/// The weight brush and the selection mask.
pub struct PaintState {
    /// Left-drag in the viewport paints instead of orbiting.
    pub on: bool,
    pub brush: Brush,
    pub op: PaintOp,
    /// `None`: every basis (the whole mixture) of any cluster under the brush;
    /// `Some(j)`: basis j of the chosen cluster.
    pub basis: Option<usize>,
    /// Scale factor or added weight, per channel.
    pub amount: [f32; 3],
    /// Limit strokes and per-basis scales to the selection.
    pub limit_to_selection: bool,
    pub selection: Option<TexelMask>,
    /// The stroke in progress: the pack it started from and the texels it covered, so
    /// that overlapping dabs never compound and the whole stroke is one edit of the
    /// starting pack.
    stroke: Option<(Arc<SpmmMaterial>, TexelMask)>,
}

impl Default for PaintState {
    fn default() -> Self {
        Self {
            on: false,
            brush: Brush::default(),
            op: PaintOp::Scale,
            basis: None,
            amount: [1.5; 3],
            limit_to_selection: false,
            selection: None,
            stroke: None,
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

/// A weight scale for all of cluster `c`'s texels, shown as the cluster's mean weight
/// (colour picker and exact RGB entry).
fn mean_weight(
    ui: &mut Ui,
    m: &Arc<SpmmMaterial>,
    c: usize,
    slot: &Material,
    index: usize,
    edits: &mut Vec<SceneEdit>,
) {
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
}

impl MaterialPanel {
    /// The selection, when edits are limited to it and it fits `m`.
    fn limit<'a>(&'a self, m: &SpmmMaterial) -> Option<&'a TexelMask> {
        self.paint.selection.as_ref().filter(|s| {
            self.paint.limit_to_selection && (s.width(), s.height()) == (m.width(), m.height())
        })
    }

    /// Continues (or starts) a brush stroke: `dab` adds the texels it covers to the
    /// stroke's mask (and says whether it landed on the pack); returns the edit that
    /// applies the whole stroke so far to the pack it started from. With the `Select`
    /// operation the stroke paints the selection and returns no edit.
    pub fn stroke_edit(
        &mut self,
        doc: &crate::document::Document,
        dab: impl FnOnce(&mut TexelMask) -> bool,
    ) -> Option<SceneEdit> {
        let (Some(pack), Some(m)) = (&doc.pack, doc.material()) else {
            return None;
        };
        let slot = &doc.scene.materials[pack.material];
        if self.paint.op == PaintOp::Select {
            let sel = self
                .paint
                .selection
                .get_or_insert_with(|| TexelMask::empty(m.width(), m.height()));
            dab(sel);
            self.map = None;
            return None;
        }
        let (base, mask) = self
            .paint
            .stroke
            .get_or_insert_with(|| (Arc::clone(&m), TexelMask::empty(m.width(), m.height())));
        if !dab(mask) {
            return None;
        }
        let (base, mask) = (Arc::clone(base), mask.clone());
        let covered = match self.limit(&base) {
            Some(sel) => mask.intersected(sel).ok()?,
            None => mask,
        };
        let target = WeightTarget {
            cluster: self.paint.basis.map(|_| self.cluster),
            basis: self.paint.basis,
            texels: Some(&covered),
        };
        let amount = self.paint.amount.map(f64::from);
        let edited = match self.paint.op {
            PaintOp::Scale => base.with_weight_scale(&target, amount),
            PaintOp::Add | PaintOp::Select => base.with_weight_added(&target, amount),
        }
        .ok()?;
        Some(SceneEdit::Material {
            index: pack.material,
            material: with_pack(slot, edited),
        })
    }

    /// Ends the stroke in progress (the pointer was released).
    pub fn end_stroke(&mut self) {
        self.paint.stroke = None;
    }

    /// Shows the panel; returns the edits the user made this frame.
    pub fn show(&mut self, ui: &mut Ui, doc: &Document) -> Vec<SceneEdit> {
        let mut edits = Vec::new();
        let (Some(pack), Some(m)) = (&doc.pack, doc.material()) else {
            ui.label("The scene has no SPMM material to edit (its other materials are in the scene panel).");
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
            self.texel_map(ui, &m, doc, &mut edits);
        });

        let c = self.cluster;
        mean_weight(ui, &m, c, slot, index, &mut edits);
        self.basis_rows(ui, &m, slot, index, &mut edits);
        self.residual_notice(ui, &m, slot, index, &mut edits);
        self.paint_ui(ui, &m, slot, index, &mut edits);

        self.lobe(ui, &m, c);
        let (pending, removed) = self.dictionary.show(ui, &m, c);
        if removed {
            self.paint.basis = None;
        }
        if let Some(e) = pending {
            edits.push(SceneEdit::Material {
                index,
                material: with_pack(slot, e),
            });
        }

        edits
    }

    /// The chosen texel's lobe (else the cluster's first texel's) in the plane of
    /// incidence: all bases summed, and each basis.
    fn lobe(&mut self, ui: &mut Ui, m: &Arc<SpmmMaterial>, c: usize) {
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
            let (sum, parts) = texel_lobes(m, t, self.theta_i_deg.to_radians());
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
    }

    /// One row per basis of the chosen cluster: its mean weight as a colour and exact
    /// RGB (editing them scales the basis's weights), a multiplier, mute and solo.
    fn basis_rows(
        &mut self,
        ui: &mut Ui,
        m: &Arc<SpmmMaterial>,
        slot: &Material,
        index: usize,
        edits: &mut Vec<SceneEdit>,
    ) {
        let c = self.cluster;
        ui.strong(format!("Cluster {c}: weights per basis"));
        let mut view = m.view().clone();
        let mut view_changed = false;
        let mut scale: Option<(usize, [f64; 3])> = None;
        // Two lines per basis, so the panel keeps its width: name, colour, mute and
        // solo; then the exact mean weight and the multiplier.
        for (j, basis) in m.clusters()[c].bases.iter().enumerate() {
            let mean = m.basis_mean_weight(c, j);
            let mut rgb = mean.map(|v| v as f32);
            let mut changed = false;
            ui.horizontal(|ui| {
                ui.label(format!("{j} {}", basis.brdf().model().name()));
                let mut shown = rgb.map(|v| v.clamp(0.0, 1.0));
                if egui::widgets::color_picker::color_edit_button_rgb(ui, &mut shown).changed() {
                    rgb = shown;
                    changed = true;
                }
                let mut muted = view.muted(c, j);
                if ui
                    .checkbox(&mut muted, format!("mute {j}"))
                    .on_hover_text(
                        "hide this basis in the view; the pack keeps its weights until applied",
                    )
                    .changed()
                {
                    view.set_muted(c, j, muted);
                    view_changed = true;
                }
                let mut solo = view.soloed(c, j);
                if ui
                    .checkbox(&mut solo, format!("solo {j}"))
                    .on_hover_text("show only the soloed bases of this cluster (no residual)")
                    .changed()
                {
                    view.set_solo(c, j, solo);
                    view_changed = true;
                }
            });
            ui.horizontal(|ui| {
                ui.add_space(12.0);
                for (k, name) in ["R", "G", "B"].into_iter().enumerate() {
                    ui.add_enabled_ui(mean[k] > 0.0, |ui| {
                        let label = ui.label(format!("{name}{j}"));
                        changed |= ui
                            .add(
                                egui::DragValue::new(&mut rgb[k])
                                    .range(0.0..=f32::MAX)
                                    .clamp_existing_to_range(false)
                                    .max_decimals(4)
                                    .speed(0.002),
                            )
                            .labelled_by(label.id)
                            .changed();
                    });
                }
                let label = ui.label(format!("×{j}"));
                let mut factor = 1.0f64;
                if ui
                    .add(
                        egui::DragValue::new(&mut factor)
                            .range(0.0..=100.0)
                            .speed(0.01)
                            .max_decimals(3),
                    )
                    .labelled_by(label.id)
                    .on_hover_text("multiply this basis's weights (all channels)")
                    .changed()
                {
                    scale = Some((j, [factor; 3]));
                }
            });
            if changed {
                scale = Some((
                    j,
                    [0, 1, 2].map(|k| {
                        if mean[k] > 0.0 {
                            f64::from(rgb[k]) / mean[k]
                        } else {
                            1.0
                        }
                    }),
                ));
            }
        }
        if let Some((j, s)) = scale {
            let target = WeightTarget {
                texels: self.limit(m),
                ..WeightTarget::basis(c, j)
            };
            if let Ok(e) = m.with_weight_scale(&target, s) {
                edits.push(SceneEdit::Material {
                    index,
                    material: with_pack(slot, e),
                });
            }
        }
        if view_changed && let Ok(e) = m.with_view(view) {
            edits.push(SceneEdit::Material {
                index,
                material: with_pack(slot, e),
            });
        }
        if !m.view().is_empty() {
            ui.horizontal_wrapped(|ui| {
                ui.weak("mute/solo change the view only;");
                if ui
                    .button("Apply to the pack")
                    .on_hover_text(
                        "remove the hidden bases' weights (and a soloed cluster's residual)",
                    )
                    .clicked()
                    && let Ok(e) = m.with_view_applied()
                {
                    edits.push(SceneEdit::Material {
                        index,
                        material: with_pack(slot, e),
                    });
                }
            });
        }
    }

    /// A cluster whose dictionary or weights were edited and whose fitted residual adds
    /// something: it was fitted for the original mixture, so ask whether to keep it
    /// (never dropped silently). Clusters left alone keep their residual unasked.
    fn residual_notice(
        &mut self,
        ui: &mut Ui,
        m: &Arc<SpmmMaterial>,
        slot: &Material,
        index: usize,
        edits: &mut Vec<SceneEdit>,
    ) {
        let c = self.cluster;
        if !(m.cluster_edited(c) && m.cluster_has_residual(c)) || self.residual_kept.contains(&c) {
            return;
        }
        ui.horizontal_wrapped(|ui| {
            ui.colored_label(
                ui.visuals().warn_fg_color,
                format!("Cluster {c}'s residual was fitted for the original mixture."),
            );
            if ui.button("Keep residual").clicked() {
                self.residual_kept.push(c);
            }
            if ui.button("Turn residual off for this cluster").clicked()
                && let Ok(e) = m.with_cluster_residual_off(c)
            {
                edits.push(SceneEdit::Material {
                    index,
                    material: with_pack(slot, e),
                });
            }
        });
    }

    /// The brush (radius and its units, strength, falloff, what it does, to which
    /// bases) and the selection mask.
    fn paint_ui(
        &mut self,
        ui: &mut Ui,
        m: &Arc<SpmmMaterial>,
        slot: &Material,
        index: usize,
        edits: &mut Vec<SceneEdit>,
    ) {
        let c = self.cluster;
        ui.separator();
        let p = &mut self.paint;
        ui.checkbox(&mut p.on, "Paint weights").on_hover_text(
            "left-drag on the object (or on the texel map) paints; right-drag still pans",
        );
        if !p.on {
            return;
        }
        ui.horizontal(|ui| {
            ui.selectable_value(&mut p.op, PaintOp::Scale, "Scale");
            ui.selectable_value(&mut p.op, PaintOp::Add, "Add");
            ui.selectable_value(&mut p.op, PaintOp::Select, "Select");
        });
        if p.op == PaintOp::Add && p.basis.is_none() {
            p.basis = Some(0);
        }
        if p.op != PaintOp::Select {
            let bases = m.clusters()[c].bases.len();
            let label = ui.label("bases");
            egui::ComboBox::from_id_salt("paint-bases")
                .selected_text(match p.basis {
                    Some(j) => format!("cluster {c} basis {j}"),
                    None => "whole mixture".into(),
                })
                .show_ui(ui, |ui| {
                    if p.op == PaintOp::Scale {
                        ui.selectable_value(&mut p.basis, None, "whole mixture");
                    }
                    for j in 0..bases {
                        ui.selectable_value(
                            &mut p.basis,
                            Some(j),
                            format!("cluster {c} basis {j}"),
                        );
                    }
                })
                .response
                .labelled_by(label.id);
            if p.basis.is_some_and(|j| j >= bases) {
                p.basis = None;
            }
            ui.horizontal(|ui| {
                ui.label(if p.op == PaintOp::Scale {
                    "factor"
                } else {
                    "weight"
                });
                for (k, name) in ["R", "G", "B"].into_iter().enumerate() {
                    let label = ui.label(format!("brush {name}"));
                    ui.add(
                        egui::DragValue::new(&mut p.amount[k])
                            .range(if p.op == PaintOp::Scale {
                                0.0..=100.0
                            } else {
                                -10.0..=10.0
                            })
                            .speed(0.01),
                    )
                    .labelled_by(label.id);
                }
            });
        }
        ui.horizontal(|ui| {
            ui.add(
                egui::Slider::new(&mut p.brush.radius, 0.5..=64.0)
                    .logarithmic(true)
                    .text("radius"),
            );
            ui.selectable_value(&mut p.brush.units, BrushUnits::Texels, "texels");
            ui.selectable_value(&mut p.brush.units, BrushUnits::ScreenPixels, "pixels");
        });
        ui.add(egui::Slider::new(&mut p.brush.strength, 0.0..=1.0).text("strength"));
        ui.horizontal(|ui| {
            ui.label("falloff");
            for f in Falloff::ALL {
                ui.selectable_value(&mut p.brush.falloff, f, f.name());
            }
        });
        ui.horizontal_wrapped(|ui| {
            if ui.button(format!("Select cluster {c}")).clicked() {
                p.selection = Some(TexelMask::of_cluster(m, c));
                self.map = None;
            }
            if p.selection.is_some() && ui.button("Clear selection").clicked() {
                p.selection = None;
                self.map = None;
            }
        });
        if let Some(sel) = &p.selection {
            ui.checkbox(
                &mut p.limit_to_selection,
                format!(
                    "limit edits to the selection ({} texels)",
                    sel.covered().count()
                ),
            );
        }
        let _ = (slot, index, edits);
    }

    /// The texel grid coloured by each texel's summed weights, the chosen cluster at
    /// full strength and the rest dimmed; a click chooses the texel and its cluster.
    fn texel_map(
        &mut self,
        ui: &mut Ui,
        m: &Arc<SpmmMaterial>,
        doc: &Document,
        map_edits: &mut Vec<SceneEdit>,
    ) {
        let key = Arc::as_ptr(m);
        let show_selection = self.paint.on && self.paint.selection.is_some();
        if self
            .map
            .as_ref()
            .is_none_or(|(_, k, c, s)| *k != key || *c != self.cluster || *s != show_selection)
        {
            let selection = self.paint.selection.as_ref().filter(|_| show_selection);
            let pixels: Vec<Color32> = (0..m.texel_cluster().len())
                .map(|t| {
                    let w = m.texel_weights(t).fold([0.0f32; 3], |a, (_, w)| {
                        [a[0] + w[0], a[1] + w[1], a[2] + w[2]]
                    });
                    let dim = match selection {
                        Some(s) => 0.25 + 0.75 * s.strengths().get(t).copied().unwrap_or(0.0),
                        None if m.texel_cluster()[t] as usize == self.cluster => 1.0,
                        None => 0.25,
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
            self.map = Some((texture, key, self.cluster, show_selection));
        }
        if let Some((texture, _, _, _)) = &self.map {
            let side = ui.available_width().min(120.0);
            let response = ui.add(
                egui::Image::new((texture.id(), egui::vec2(side, side)))
                    .sense(egui::Sense::click_and_drag()),
            );
            if self.paint.on
                && (response.dragged() || response.clicked())
                && let Some(p) = response.interact_pointer_pos()
            {
                let rel = (p - response.rect.min) / response.rect.size();
                let centre = glam::DVec2::new(
                    f64::from(rel.x) * f64::from(m.width()),
                    f64::from(rel.y) * f64::from(m.height()),
                );
                let brush = self.paint.brush;
                let edit = self.stroke_edit(doc, |mask| {
                    mask.stamp(centre, brush.radius, brush.strength, brush.falloff);
                    true
                });
                map_edits.extend(edit);
                if response.drag_stopped() || response.clicked() {
                    self.end_stroke();
                }
                return;
            }
            if response.drag_stopped() {
                self.end_stroke();
            }
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

#[cfg(test)]
#[path = "material_panel_tests.rs"]
mod tests;
