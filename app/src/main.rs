//! `meso-studio`: Meso's desktop editor. Today it opens the BRDF explorer
//! (explorer.rs); the SPMM material editor over the progressive viewport grows from it.
//! A thin shell: everything it computes comes from `meso-core`'s public API.

mod explorer;
mod lobe_plot;
mod sphere_preview;

use explorer::Explorer;

fn main() -> eframe::Result<()> {
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("Meso Studio")
            .with_inner_size([1280.0, 800.0])
            .with_min_inner_size([800.0, 500.0]),
        ..Default::default()
    };
    eframe::run_native(
        "Meso Studio",
        options,
        Box::new(|cc| {
            // Remember the explorer's settings across restarts.
            let explorer = cc
                .storage
                .and_then(|s| eframe::get_value::<explorer::Settings>(s, eframe::APP_KEY))
                .map(Explorer::from_settings)
                .unwrap_or_default();
            Ok(Box::new(explorer))
        }),
    )
}

impl eframe::App for Explorer {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.show(ui);
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        eframe::set_value(storage, eframe::APP_KEY, &self.settings());
    }
}
