//! Meso Studio, the desktop material editor, as a library: the window (`studio`)
//! over the document (`meso_session`: undo, the recovery journal, scripts; the
//! restore offer, pack conflicts and scripted runs in `recovery`), the render thread and the modes
//! it runs (`meso_viewport`, with the lights a mode renders without in `disabled`), the
//! viewport and the compare view's reference (`reference`), the window's wgpu device
//! that the GPU mode shares (`window_device`), the material and scene panels (with the scene's other materials in `scene_materials` and the shared BRDF and colour editors in `brdf_editor`), background jobs (`jobs`), and the BRDF explorer. `main.rs` runs it in eframe;
//! benchmarks and tests drive it headless.

pub mod brdf_editor;
pub mod canvas;
pub mod chrome;
pub mod compare;
pub mod dictionary;
pub mod disabled;
/// The document lives below the window (`meso-session`), with its undo and journal.
pub use meso_session::document;
pub mod explorer;
pub mod jobs;
pub mod library;
pub mod library_window;
pub mod loader;
pub mod lobe_plot;
pub mod material_panel;
pub mod mode_switch;
pub mod recovery;
pub mod reference;
pub mod render_link;
pub mod scene_materials;
pub mod scene_panel;
pub mod settings;
pub mod sphere_preview;
pub mod status_bar;
pub mod studio;
pub mod viewport;
#[cfg(feature = "gpu")]
pub mod window_device;
