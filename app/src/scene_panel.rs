//! The lights and scene panel (left): the scene file and render mode (with the
//! progress of a mode being prepared), the edited object's mesh and UV tiling, point
//! and area lights (add, remove, move, size, colour and strength; marked when the
//! mode renders without them), ambient occlusion, the environment (map, strength,
//! rotation) and the background. Every change is returned as a `SceneEdit` (or a
//! request the studio carries out, such as opening a file or switching modes).

use std::path::PathBuf;
use std::sync::Arc;

use egui::Ui;
use glam::{DVec2, DVec3};
use meso_render::scene::{Ambient, Background, Environment, Light, Material, Scene};
use meso_render::{Device, ModeKind, SceneEdit};

use crate::disabled::Disabled;
use crate::document::Document;
use crate::scene_materials;

/// Something the studio must do for the panel.
pub enum Request {
    Edit(SceneEdit),
    OpenSceneDialog,
    /// Replace the edited object's mesh with this OBJ.
    Mesh(PathBuf),
    /// Switch the renderer to this mode (checked, then prepared in the background).
    SwitchMode(ModeKind, Device),
    /// Stop preparing the mode being switched to.
    CancelSwitch,
    /// Turn the environment on (with the last map, or the first shipped one).
    EnvironmentOn,
    /// Read this map (in the background) and light the scene with it.
    EnvironmentMap(PathBuf),
    EnvironmentFileDialog,
    /// Edit the SPMM pack on this material slot in the material panel.
    EditPack(usize),
}

/// A mode switch in progress, as the panel shows it.
pub struct Switching {
    /// "biscale (cpu)".
    pub target: String,
    /// The stage and fraction the preparation last reported.
    pub progress: Option<(String, f32)>,
    pub cancelling: bool,
}

/// What the panel shows besides the document.
pub struct PanelState<'a> {
    /// The mode rendering now.
    pub mode: (ModeKind, Device),
    pub switching: Option<Switching>,
    /// What the current mode renders without.
    pub disabled: &'a Disabled,
    /// The maps shipped with Meso (name, file).
    pub environments: &'a [(String, PathBuf)],
    /// The file name of the environment map in use, if the studio read it.
    pub environment_name: Option<String>,
    /// The material slot the library and dropped materials go on (the object last
    /// clicked, else the edited pack's).
    pub target_material: Option<usize>,
}

/// The environment maps under `materials/env/` of the workspace (EXR), by name.
pub fn shipped_environments() -> Vec<(String, PathBuf)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../materials/env");
    let mut maps: Vec<_> = std::fs::read_dir(&dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("exr")))
        .filter_map(|p| Some((p.file_stem()?.to_string_lossy().into_owned(), p)))
        .collect();
    maps.sort();
    maps
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
            .clamp_existing_to_range(false)
            .speed(0.05)
            .max_decimals(3);
        changed |= labelled_drag(ui, "strength", drag);
    });
    if changed {
        *e = DVec3::new(colour[0] as f64, colour[1] as f64, colour[2] as f64) * s;
    }
    changed
}

/// The mode and device pickers, and the preparation's progress with its Cancel.
fn mode_ui(ui: &mut Ui, state: &PanelState<'_>, out: &mut Vec<Request>) {
    let (mut kind, mut device) = state.mode;
    egui::ComboBox::from_label("Render mode")
        .selected_text(kind.name())
        .show_ui(ui, |ui| {
            for m in ModeKind::ALL {
                ui.selectable_value(&mut kind, m, m.name());
            }
        });
    egui::ComboBox::from_label("Device")
        .selected_text(device.name())
        .show_ui(ui, |ui| {
            for d in Device::ALL {
                ui.selectable_value(&mut device, d, d.name());
            }
        });
    if (kind, device) != state.mode {
        out.push(Request::SwitchMode(kind, device));
    }
    if let Some(s) = &state.switching {
        let (stage, fraction) = s.progress.clone().unwrap_or(("starting".into(), 0.0));
        ui.label(if s.cancelling {
            format!("cancelling the switch to {}…", s.target)
        } else {
            format!("switching to {}…", s.target)
        });
        ui.horizontal(|ui| {
            ui.add(
                egui::ProgressBar::new(fraction)
                    .text(format!("{:.0}% · {stage}", fraction * 100.0))
                    .desired_width(180.0),
            );
            if ui
                .add_enabled(!s.cancelling, egui::Button::new("Cancel"))
                .clicked()
            {
                out.push(Request::CancelSwitch);
            }
        });
        ui.weak("the current mode keeps rendering until it is ready");
    }
}

/// On/off, the map, strength and rotation of the environment lighting.
fn environment_ui(ui: &mut Ui, doc: &Document, state: &PanelState<'_>, out: &mut Vec<Request>) {
    ui.heading("Environment");
    let env = doc.scene.environment.as_ref();
    let mut on = env.is_some();
    if ui.checkbox(&mut on, "environment on").changed() {
        out.push(if on {
            Request::EnvironmentOn
        } else {
            Request::Edit(SceneEdit::Environment(None))
        });
    }
    ui.horizontal_wrapped(|ui| {
        ui.label("map");
        for (name, path) in state.environments {
            let current = state.environment_name.as_deref() == Some(name.as_str()) && on;
            if ui.selectable_label(current, name.as_str()).clicked() {
                out.push(Request::EnvironmentMap(path.clone()));
            }
        }
        if ui.button("File…").clicked() {
            out.push(Request::EnvironmentFileDialog);
        }
    });
    let Some(e) = env else { return };
    if let Some(name) = &state.environment_name {
        ui.weak(format!("{name}: {}x{}", e.map.width(), e.map.height()));
    }
    let mut strength = e.strength;
    if ui
        .add(
            egui::Slider::new(&mut strength, 0.0..=16.0)
                .clamping(egui::SliderClamping::Edits)
                .logarithmic(true)
                .text("environment strength"),
        )
        .changed()
    {
        out.push(Request::Edit(SceneEdit::Environment(Some(Environment {
            strength,
            ..e.clone()
        }))));
    }
    let mut rotate = e.rotate_y_deg;
    if ui
        .add(
            egui::Slider::new(&mut rotate, -180.0..=180.0)
                .clamping(egui::SliderClamping::Edits)
                .text("environment rotation (deg)"),
        )
        .changed()
    {
        out.push(Request::Edit(SceneEdit::Environment(Some(Environment {
            rotate_y_deg: rotate,
            ..e.clone()
        }))));
    }
}

/// The background: the environment, or a colour (or the scene file's own map).
fn background_ui(ui: &mut Ui, scene: &Scene, out: &mut Vec<Request>) {
    ui.separator();
    let mut from_env = matches!(scene.background, Background::FromEnvironment);
    if ui
        .checkbox(&mut from_env, "background shows the environment")
        .changed()
    {
        out.push(Request::Edit(SceneEdit::Background(if from_env {
            Background::FromEnvironment
        } else {
            Background::Color(DVec3::new(0.02, 0.02, 0.025))
        })));
    }
    match &scene.background {
        Background::Color(c) => {
            let mut c = *c;
            if emission_editor(ui, "background", &mut c) {
                out.push(Request::Edit(SceneEdit::Background(Background::Color(c))));
            }
        }
        Background::Environment(_) => {
            ui.label("background: its own map (from the scene file)");
        }
        Background::FromEnvironment => {}
    }
}

/// The edited pack's object: its mesh (one of the bundled ones) and UV tiling.
fn object_ui(ui: &mut Ui, doc: &Document, out: &mut Vec<Request>) {
    let scene = &doc.scene;
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
                        .clamp_existing_to_range(false)
                        .speed(0.05),
                );
                let b = labelled_drag(
                    ui,
                    "v",
                    egui::DragValue::new(&mut uv.y)
                        .range(0.01..=1000.0)
                        .clamp_existing_to_range(false)
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
}

/// The ambient occlusion term: on/off, radius, radiance.
fn ambient_ui(ui: &mut Ui, doc: &Document, state: &PanelState<'_>, out: &mut Vec<Request>) {
    let scene = &doc.scene;
    ui.separator();
    ui.heading("Ambient occlusion");
    if state.disabled.ambient {
        ui.label(format!("disabled in {}", state.mode.0.name()));
    }
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
                    .clamping(egui::SliderClamping::Edits)
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
}

pub fn show(ui: &mut Ui, doc: &Document, state: &PanelState<'_>) -> Vec<Request> {
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
    mode_ui(ui, state, &mut out);

    object_ui(ui, doc, &mut out);

    ui.separator();
    ui.heading("Lights");
    for (index, light) in scene.lights.iter().enumerate() {
        let mut l = *light;
        let mut changed = false;
        let mut remove = false;
        let mut title = match l {
            Light::Point { .. } => format!("light {index}: point"),
            Light::Area { .. } => format!("light {index}: area"),
        };
        if state.disabled.light(index) {
            title += &format!(" (disabled in {})", state.mode.0.name());
        }
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
                                    .clamping(egui::SliderClamping::Edits)
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

    // Points on each area light per frame (`[render] light_samples`): soft shadows
    // clean up in fewer frames; every sample restarts with a new count.
    let mut n = scene.render.light_samples;
    let drag = egui::DragValue::new(&mut n).range(1..=meso_render::scene::MAX_LIGHT_SAMPLES);
    let row = ui.horizontal(|ui| labelled_drag(ui, "light samples per frame", drag));
    row.response.on_hover_text(
        "points drawn on each area light per frame: soft shadows clean up in fewer frames",
    );
    if row.inner && n != scene.render.light_samples {
        out.push(Request::Edit(SceneEdit::LightSamples(n)));
    }

    ambient_ui(ui, doc, state, &mut out);

    ui.separator();
    environment_ui(ui, doc, state, &mut out);

    background_ui(ui, &doc.scene, &mut out);
    ui.separator();
    out.extend(
        scene_materials::show(ui, doc, state.target_material)
            .into_iter()
            .map(|a| match a {
                scene_materials::Action::Edit(e) => Request::Edit(e),
                scene_materials::Action::EditPack(index) => Request::EditPack(index),
            }),
    );
    out
}
