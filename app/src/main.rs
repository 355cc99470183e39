//! `meso-studio`: Meso's desktop material editor. Opens the scene given on the command
//! line, or the built-in default scene (the bunny in leather), with its SPMM pack in
//! the material panel and the progressive viewport (studio.rs). A thin shell: all it
//! computes comes from `meso-core`'s public API.

mod document;
mod explorer;
mod lobe_plot;
mod material_panel;
mod render_worker;
mod scene_panel;
mod sphere_preview;
mod studio;
mod viewport;

use std::path::PathBuf;

use studio::{Settings, Studio};

fn main() -> eframe::Result<()> {
    let scene = std::env::args_os().nth(1).map(PathBuf::from);
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("Meso Studio")
            .with_inner_size([1280.0, 800.0])
            .with_min_inner_size([900.0, 560.0]),
        ..Default::default()
    };
    eframe::run_native(
        "Meso Studio",
        options,
        Box::new(move |cc| {
            let settings = cc
                .storage
                .and_then(|s| eframe::get_value::<Settings>(s, eframe::APP_KEY))
                .unwrap_or_default();
            Ok(Box::new(Studio::new(
                Some(cc.egui_ctx.clone()),
                scene,
                settings,
            )))
        }),
    )
}

impl eframe::App for Studio {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.show(ui);
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        eframe::set_value(storage, eframe::APP_KEY, &self.settings);
    }
}
