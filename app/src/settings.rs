//! The studio's settings: what survives a restart (recent files, view options, the
//! library's folders), saved by eframe's storage. Apart from the window so the parts
//! that read them (menus, status bar, library, compare view) need not know the window.

use std::path::PathBuf;

/// What survives a restart.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct Settings {
    pub recent_packs: Vec<PathBuf>,
    pub recent_scenes: Vec<PathBuf>,
    pub exposure: f64,
    /// Render resolution relative to the viewport's pixels.
    pub resolution: f32,
    /// Samples per pixel after which the renderer rests.
    pub max_samples: u32,
    /// Frame, ray and latency timings in the status bar.
    pub show_timings: bool,
    /// The compare view: live image left of the divider, a reference right of it.
    pub compare: bool,
    /// Samples per pixel the compare view's reference is refined to.
    pub reference_spp: u32,
    /// The first frames through the viewport denoiser (saved images and the compare
    /// view's figures are always the unfiltered estimate).
    pub denoise: bool,
    /// The material library window is open.
    pub show_library: bool,
    /// Scenes that name the spmm mode on the CPU open on the GPU when wgpu offers a
    /// hardware adapter (not a software one such as llvmpipe) that renders them; the
    /// Device switch goes back to the CPU on request.
    pub gpu_by_default: bool,
    /// The designer's own library folders (the shipped packs are always listed).
    pub library_folders: Vec<PathBuf>,
    /// Where library thumbnails are cached (`None`: `library::default_cache_dir`).
    pub thumbnail_cache: Option<PathBuf>,
    /// Keep a recovery journal of every edit (docs/app.md, "Never losing work").
    pub journal: bool,
    /// Where journals go (`None`: `MESO_STATE_DIR`, else the platform's state folder).
    pub state_dir: Option<PathBuf>,
    /// Memory undo may hold, in MiB; the oldest steps beyond it are dropped.
    pub undo_budget_mb: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            recent_packs: Vec::new(),
            recent_scenes: Vec::new(),
            exposure: 0.0,
            resolution: 0.5,
            max_samples: 1024,
            show_timings: true,
            compare: false,
            reference_spp: 256,
            denoise: true,
            show_library: false,
            gpu_by_default: true,
            library_folders: Vec::new(),
            thumbnail_cache: None,
            journal: true,
            state_dir: None,
            undo_budget_mb: meso_session::DEFAULT_UNDO_BUDGET >> 20,
        }
    }
}

impl Settings {
    /// The folder session journals go to.
    pub fn sessions_dir(&self) -> PathBuf {
        self.state_dir
            .as_ref()
            .map_or_else(meso_session::journal::sessions_dir, |d| d.join("sessions"))
    }

    /// The defaults, with the GPU default off: tests open scenes on the device they
    /// name, never on whatever GPU the machine running them has.
    #[cfg(test)]
    pub fn for_tests() -> Self {
        Self {
            gpu_by_default: false,
            // Tests that journal name their own folder.
            journal: false,
            ..Self::default()
        }
    }
}
