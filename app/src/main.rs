//! `meso-studio [SCENE] [--run SCRIPT.toml [--headless]]`: Meso's desktop material
//! editor. Opens the scene given on the command line, or the built-in default scene
//! (the bunny in leather), with its SPMM pack in the material panel and the
//! progressive viewport (studio.rs), its GPU mode on the window's wgpu device where it
//! can be shared (window_device.rs; built with the `gpu` feature, on by default).
//! `--run` applies a script's edits as the panels do (docs/app.md); with
//! `--headless` it runs them on the document and its journal without a window
//! (headless.rs). A thin shell: all it computes comes from the core crates' public
//! APIs.

use std::path::PathBuf;
#[cfg(feature = "gpu")]
use std::sync::Arc;

use meso_session::script::Script;
use meso_studio::studio::{Settings, Studio};
#[cfg(feature = "gpu")]
use meso_studio::window_device;

mod headless;

/// The command line.
struct Args {
    scene: Option<PathBuf>,
    script: Option<PathBuf>,
    headless: bool,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        scene: None,
        script: None,
        headless: false,
    };
    let mut it = std::env::args_os().skip(1);
    while let Some(a) = it.next() {
        match a.to_str() {
            Some("--run") => {
                args.script = Some(
                    it.next()
                        .map(PathBuf::from)
                        .ok_or("--run needs a script file")?,
                )
            }
            Some("--headless") => args.headless = true,
            Some("--help" | "-h") => {
                return Err(
                    "usage: meso-studio [SCENE.toml] [--run SCRIPT.toml [--headless]]".into(),
                );
            }
            Some(s) if s.starts_with("--") => return Err(format!("unknown option `{s}`")),
            _ if args.scene.is_none() => args.scene = Some(PathBuf::from(a)),
            _ => return Err(format!("one scene only: `{}`", a.to_string_lossy())),
        }
    }
    if args.headless && args.script.is_none() {
        return Err("--headless needs --run SCRIPT.toml".into());
    }
    Ok(args)
}

fn main() -> std::process::ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("meso-studio: {e}");
            return std::process::ExitCode::from(2);
        }
    };
    let script = match args.script.as_deref().map(Script::read).transpose() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("meso-studio: {e}");
            return std::process::ExitCode::from(2);
        }
    };
    if args.headless {
        let script = script.expect("checked: --headless needs --run");
        return headless::run(args.scene, script);
    }
    match window(args.scene, script) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("meso-studio: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn window(scene: Option<PathBuf>, script: Option<Script>) -> eframe::Result<()> {
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
            let mut studio = {
                let modes = window_device::modes_for(cc.wgpu_render_state.as_ref());
                let window = cc.wgpu_render_state.clone().zip(modes.gpu().cloned());
                Studio::with_maker(Some(cc.egui_ctx.clone()), scene, settings, Arc::new(modes))
                    .drawn_by(window)
            };
            #[cfg(not(feature = "gpu"))]
            let mut studio = Studio::new(Some(cc.egui_ctx.clone()), scene, settings);
            if let Some(s) = script {
                studio.run_script(s);
            }
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

    fn on_exit(&mut self) {
        self.0.on_exit();
    }
}
