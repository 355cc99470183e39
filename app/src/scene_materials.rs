//! The scene panel's Materials section: every material of the scene except the edited
//! pack (the material panel edits that one), with what its kind lets a designer
//! change: an analytic BRDF's model, parameters and albedo, a MERL table's tint, a
//! mirror's reflectance, a BTF's tiling; another SPMM pack can be made the edited
//! one. Each change is one `SceneEdit::Material`,
//! so it is undone like any edit and the mode restarts what it invalidates (the spmm
//! mode: only the pixels that show the material).

use egui::Ui;
use glam::DVec2;
use meso_render::SceneEdit;
use meso_render::scene::Material;

use crate::brdf_editor::{brdf_editor, rgb_editor};
use crate::document::Document;

/// What the section asks for.
pub enum Action {
    Edit(SceneEdit),
    /// Make the SPMM pack on this material slot the edited pack.
    EditPack(usize),
}

/// Shows the section, marking `target` (where the library puts a material: the
/// object last clicked); returns what was asked for.
pub fn show(ui: &mut Ui, doc: &Document, target: Option<usize>) -> Vec<Action> {
    let scene = &doc.scene;
    let edited = doc.pack.as_ref().map(|p| p.material);
    let mut out = Vec::new();
    ui.heading("Materials");
    for (index, material) in scene.materials.iter().enumerate() {
        if Some(index) == edited {
            continue;
        }
        let name = &scene.material_names[index];
        let file = scene.material_files.get(index).and_then(|f| f.as_ref());
        let file_name = file
            .and_then(|f| f.file_name())
            .map(|f| f.to_string_lossy().into_owned());
        let mut title = format!("{name} · {}", material.kind_name());
        if target == Some(index) {
            title += " (selected)";
        }
        egui::CollapsingHeader::new(title)
            .id_salt(("scene material", index))
            .default_open(true)
            .show(ui, |ui| {
                if let Some(file) = &file_name {
                    ui.label(format!("from {file}"));
                }
                if let Material::Spmm { .. } = material {
                    let button = ui.button(format!("Edit {name} in the material panel"));
                    if button.clicked() {
                        out.push(Action::EditPack(index));
                    }
                } else if let Some(edit) = editor(ui, name, material) {
                    out.push(Action::Edit(SceneEdit::Material {
                        index,
                        material: edit,
                    }));
                }
            });
    }
    out
}

/// The editor of one material named `name`; the edited material when something
/// changed.
fn editor(ui: &mut Ui, name: &str, material: &Material) -> Option<Material> {
    let mut edited = material.clone();
    let changed = match &mut edited {
        Material::Brdf { brdf, albedo } => {
            let model = brdf_editor(ui, ("scene material", name), brdf);
            let colour = rgb_editor(ui, "albedo", &format!("{name} albedo"), albedo);
            model || colour
        }
        Material::Merl { tint, .. } => rgb_editor(ui, "tint", &format!("{name} tint"), tint),
        Material::Mirror { reflectance } => rgb_editor(
            ui,
            "reflectance",
            &format!("{name} reflectance"),
            reflectance,
        ),
        Material::Btf { uv_scale, .. } => tiling_editor(ui, uv_scale),
        // Packs are edited in the material panel (`Action::EditPack`).
        Material::Spmm { .. } => false,
    };
    changed.then_some(edited)
}

/// A texture's tiling, u and v, each at least 0.01 as scene files require.
fn tiling_editor(ui: &mut Ui, uv: &mut DVec2) -> bool {
    ui.horizontal(|ui| {
        ui.label("UV tiling");
        let mut changed = false;
        for value in [&mut uv.x, &mut uv.y] {
            changed |= ui
                .add(
                    egui::DragValue::new(value)
                        .range(0.01..=1000.0)
                        .clamp_existing_to_range(false)
                        .speed(0.05),
                )
                .changed();
        }
        changed
    })
    .inner
}
