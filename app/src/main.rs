//! `meso-studio`: Meso's desktop material editor. Opens the scene given on the command
//! line, or the built-in default scene (the bunny in leather), with its SPMM pack in
//! the material panel and the progressive viewport (studio.rs), its GPU mode on the
//! window's wgpu device where it can be shared (window_device.rs; built with the `gpu`
//! feature, on by default). A thin shell: all it computes comes from the core crates'
//! public APIs.

use std::path::PathBuf;
#[cfg(feature = "gpu")]
use std::sync::Arc;

use meso_studio::studio::{Settings, Studio};
#[cfg(feature = "gpu")]
use meso_studio::window_device;

fn main() -> eframe::Result<()> {
    let scene = std::env::args_os().nth(1).map(PathBuf::from);
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("Meso Studio")
            .with_inner_size([1280.0, 800.0])
            .with_min_inner_size([900.0, 560.0]),
        // The window's device is asked for with the GPU mode's limits, so the mode
        // renders on it instead of a device of its own.
        #[cfg(feature = "gpu")]
        wgpu_options: window_device::wgpu_configuration(),
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
            #[cfg(feature = "gpu")]
            let studio = {
                let modes = window_device::modes_for(cc.wgpu_render_state.as_ref());
                let window = cc.wgpu_render_state.clone().zip(modes.gpu().cloned());
                Studio::with_maker(Some(cc.egui_ctx.clone()), scene, settings, Arc::new(modes))
                    .drawn_by(window)
            };
            #[cfg(not(feature = "gpu"))]
            let studio = Studio::new(Some(cc.egui_ctx.clone()), scene, settings);
            Ok(Box::new(App(studio)))
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
