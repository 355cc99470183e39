//! The lights and scene panel (left): the scene file and render mode, the edited
//! object's mesh and UV tiling, point and area lights (add, remove, move, size, colour
//! and strength), ambient occlusion and the background. Every change is returned as a
//! `SceneEdit` (or a request the studio carries out, such as opening a file).

use std::path::PathBuf;
use std::sync::Arc;

use egui::Ui;
use glam::{DVec2, DVec3};
use meso_core::render::{ModeKind, SceneEdit};
use meso_core::scene::{Ambient, Background, Light, Material};

use crate::document::Document;

/// Something the studio must do for the panel.
pub enum Request {
    Edit(SceneEdit),
    OpenSceneDialog,
    /// Replace the edited object's mesh with this OBJ.
    Mesh(PathBuf),
}

/// Meshes offered in the mesh menu: the project's own test meshes.
pub fn bundled_meshes() -> Vec<(&'static str, PathBuf)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/scenes/meshes");
    vec![
        ("bunny", dir.join("bunny_lowres.obj")),
        ("teapot", dir.join("teapot.obj")),
        ("tablecloth", dir.join("tablecloth.obj")),
    ]
}

/// A value with a label that screen readers (and tests) find it by.
fn labelled_drag(ui: &mut Ui, name: &str, drag: egui::DragValue<'_>) -> bool {
    let label = ui.label(name);
    ui.add(drag).labelled_by(label.id).changed()
}

fn vec3_editor(ui: &mut Ui, label: &str, v: &mut DVec3, speed: f64) -> bool {
    ui.horizontal(|ui| {
        ui.label(label);
        let mut changed = false;
        for (c, axis) in [(&mut v.x, "x"), (&mut v.y, "y"), (&mut v.z, "z")] {
            let drag = egui::DragValue::new(c).speed(speed).max_decimals(3);
            changed |= labelled_drag(ui, axis, drag);
        }
        changed
    })
    .inner
}

/// Colour (normalised) and strength (the largest channel) of an emission.
fn emission_editor(ui: &mut Ui, label: &str, e: &mut DVec3) -> bool {
    let strength = e.max_element();
    let mut colour = if strength > 0.0 {
        (*e / strength).as_vec3().to_array()
    } else {
        [1.0; 3]
    };
    let mut s = strength;
    let mut changed = false;
    ui.horizontal(|ui| {
        ui.label(label);
        changed |= egui::widgets::color_picker::color_edit_button_rgb(ui, &mut colour).changed();
        let drag = egui::DragValue::new(&mut s)
            .range(0.0..=1e6)
            .speed(0.05)
            .max_decimals(3);
        changed |= labelled_drag(ui, "strength", drag);
    });
    if changed {
        *e = DVec3::new(colour[0] as f64, colour[1] as f64, colour[2] as f64) * s;
    }
    changed
}

pub fn show(ui: &mut Ui, doc: &Document, mode: &mut ModeKind) -> Vec<Request> {
    let mut out = Vec::new();
    let scene = &doc.scene;
    ui.heading("Scene");
    ui.label(
        doc.scene_path
            .as_ref()
            .and_then(|p| p.file_name())
            .map_or("(built-in)".into(), |n| n.to_string_lossy()),
    );
    if ui.button("Open scene…").clicked() {
        out.push(Request::OpenSceneDialog);
    }
    egui::ComboBox::from_label("Render mode")
        .selected_text(mode.name())
        .show_ui(ui, |ui| {
            for m in ModeKind::ALL {
                ui.selectable_value(mode, m, m.name());
            }
        });

    if let Some(pack) = &doc.pack
        && let Material::Spmm {
            material,
            uv_scale,
            residual,
            npca,
        } = &scene.materials[pack.material]
    {
        ui.separator();
        ui.strong(format!("Object: {}", scene.material_names[pack.material]));
        ui.horizontal(|ui| {
            ui.label("Mesh");
            for (name, path) in bundled_meshes() {
                if ui.button(name).clicked() {
                    out.push(Request::Mesh(path));
                }
            }
        });
        let mut uv = *uv_scale;
        let changed = ui
            .horizontal(|ui| {
                ui.label("UV tiling");
                let a = labelled_drag(
                    ui,
                    "u",
                    egui::DragValue::new(&mut uv.x)
                        .range(0.01..=1000.0)
                        .speed(0.05),
                );
                let b = labelled_drag(
                    ui,
                    "v",
                    egui::DragValue::new(&mut uv.y)
                        .range(0.01..=1000.0)
                        .speed(0.05),
                );
                a || b
            })
            .inner;
        if changed {
            out.push(Request::Edit(SceneEdit::Material {
                index: pack.material,
                material: Material::Spmm {
                    material: Arc::clone(material),
                    uv_scale: uv.max(DVec2::splat(0.01)),
                    residual: *residual,
                    npca: *npca,
                },
            }));
        }
    }

    ui.separator();
    ui.heading("Lights");
    for (index, light) in scene.lights.iter().enumerate() {
        let mut l = *light;
        let mut changed = false;
        let mut remove = false;
        let title = match l {
            Light::Point { .. } => format!("light {index}: point"),
            Light::Area { .. } => format!("light {index}: area"),
        };
        egui::CollapsingHeader::new(title)
            .id_salt(("light", index))
            .default_open(index == 0)
            .show(ui, |ui| {
                match &mut l {
                    Light::Point {
                        position,
                        intensity,
                    } => {
                        changed |= vec3_editor(ui, "position", position, 0.01);
                        changed |= emission_editor(ui, "intensity (W/sr)", intensity);
                    }
                    Light::Area {
                        corner,
                        edge_u,
                        edge_v,
                        radiance,
                    } => {
                        // Move by the centre; size scales both edges about it.
                        let mut centre = *corner + (*edge_u + *edge_v) * 0.5;
                        if vec3_editor(ui, "centre", &mut centre, 0.01) {
                            *corner = centre - (*edge_u + *edge_v) * 0.5;
                            changed = true;
                        }
                        let size = edge_u.length().max(edge_v.length());
                        let mut s = size;
                        if ui
                            .add(
                                egui::Slider::new(&mut s, 0.01..=5.0)
                                    .logarithmic(true)
                                    .text("size (m)"),
                            )
                            .changed()
                            && size > 0.0
                        {
                            let k = s / size;
                            *edge_u *= k;
                            *edge_v *= k;
                            *corner = centre - (*edge_u + *edge_v) * 0.5;
                            changed = true;
                        }
                        changed |= emission_editor(ui, "radiance", radiance);
                    }
                }
                remove = ui.button("Remove").clicked();
            });
        if remove {
            out.push(Request::Edit(SceneEdit::RemoveLight(index)));
        } else if changed {
            out.push(Request::Edit(SceneEdit::Light { index, light: l }));
        }
    }
    ui.horizontal(|ui| {
        if ui.button("Add point light").clicked() {
            out.push(Request::Edit(SceneEdit::AddLight(Light::Point {
                position: scene.camera.position + DVec3::new(0.5, 1.0, 0.0),
                intensity: DVec3::splat(2.0),
            })));
        }
        if ui.button("Add area light").clicked() {
            let c = scene.camera.look_at + DVec3::new(0.0, 1.5, 0.0);
            out.push(Request::Edit(SceneEdit::AddLight(Light::Area {
                corner: c - DVec3::new(0.25, 0.0, 0.25),
                edge_u: DVec3::new(0.5, 0.0, 0.0),
                edge_v: DVec3::new(0.0, 0.0, 0.5),
                radiance: DVec3::splat(8.0),
            })));
        }
    });

    ui.separator();
    ui.heading("Ambient occlusion");
    let mut on = scene.ambient.is_some();
    let mut a = scene.ambient.unwrap_or(Ambient {
        radiance: DVec3::splat(0.25),
        radius: 0.5,
    });
    let mut changed = ui.checkbox(&mut on, "AO on").changed();
    ui.add_enabled_ui(on, |ui| {
        let mut r = if a.radius.is_finite() { a.radius } else { 1e3 };
        if ui
            .add(
                egui::Slider::new(&mut r, 0.01..=1e3)
                    .logarithmic(true)
                    .text("radius (m)"),
            )
            .changed()
        {
            a.radius = r;
            changed = true;
        }
        changed |= emission_editor(ui, "radiance", &mut a.radiance);
    });
    if changed {
        out.push(Request::Edit(SceneEdit::Ambient(on.then_some(a))));
    }

    ui.separator();
    if let Background::Color(c) = &scene.background {
        let mut c = *c;
        if emission_editor(ui, "background", &mut c) {
            out.push(Request::Edit(SceneEdit::Background(Background::Color(c))));
        }
    } else {
        ui.label("background: environment map");
    }
    out
}
