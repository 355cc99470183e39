//! `meso-studio`: Meso's desktop material editor. Opens the scene given on the command
//! line, or the built-in default scene (the bunny in leather), with its SPMM pack in
//! the material panel and the progressive viewport (studio.rs). A thin shell: all it
//! computes comes from `meso-core`'s public API.

use std::path::PathBuf;

use meso_studio::studio::{Settings, Studio};

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
            Ok(Box::new(App(Studio::new(
                Some(cc.egui_ctx.clone()),
                scene,
                settings,
            ))))
        }),
    )
}

/// The studio as an eframe application.
struct App(Studio);

impl eframe::App for App {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.0.show(ui);
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        eframe::set_value(storage, eframe::APP_KEY, &self.0.settings);
    }
}
