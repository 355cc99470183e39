//! Meso Studio, the desktop material editor, as a library: the window (`studio`)
//! over the document (`document`), the render thread (`render_worker`), the viewport,
//! the material and scene panels, and the BRDF explorer. `main.rs` runs it in eframe;
//! benchmarks and tests drive it headless.

pub mod document;
pub mod explorer;
pub mod jobs;
pub mod lobe_plot;
pub mod material_panel;
pub mod render_worker;
pub mod scene_panel;
pub mod sphere_preview;
pub mod studio;
pub mod viewport;
