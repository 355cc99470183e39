//! The material library's window: the library (made when first shown, over the
//! shipped folder and the designer's, with the thumbnail cache the settings name),
//! folders added and removed (remembered in the settings), and the entries the
//! designer assigns, handed back to the studio. Apart from library.rs, which knows
//! nothing of the settings or the window.

use std::path::{Path, PathBuf};

use crate::library::{self, Entry, Library, LibraryRequest, ThumbnailCache};
use crate::settings::Settings;

/// The library, once shown.
pub struct LibraryWindow {
    library: Option<Library>,
    repaint: Option<egui::Context>,
}

/// The shipped folder, then the designer's.
fn folders(settings: &Settings) -> Vec<PathBuf> {
    std::iter::once(library::shipped_dir())
        .chain(settings.library_folders.iter().cloned())
        .collect()
}

impl LibraryWindow {
    pub fn new(repaint: Option<egui::Context>) -> Self {
        Self {
            library: None,
            repaint,
        }
    }

    /// The material library (opened, listing its folders and starting thumbnails).
    pub fn library(&mut self, settings: &Settings) -> &mut Library {
        self.library.get_or_insert_with(|| {
            let cache = ThumbnailCache::new(
                settings
                    .thumbnail_cache
                    .clone()
                    .unwrap_or_else(library::default_cache_dir),
            );
            Library::open(&folders(settings), cache, self.repaint.clone())
        })
    }

    /// Adds a folder to the library (remembered across runs).
    pub fn add_folder(&mut self, settings: &mut Settings, dir: &Path) {
        if !settings.library_folders.iter().any(|f| f == dir) {
            settings.library_folders.push(dir.to_path_buf());
        }
        self.library(settings).rescan(&folders(settings));
    }

    /// The window, while `settings.show_library`; `target` names the material slot
    /// entries go on. Returns the entries to assign there.
    pub fn show(
        &mut self,
        ctx: &egui::Context,
        settings: &mut Settings,
        target: &str,
    ) -> Vec<Entry> {
        if !settings.show_library {
            return Vec::new();
        }
        let mut open = true;
        let mut requests = Vec::new();
        let lib = self.library(settings);
        egui::Window::new("Material library")
            .open(&mut open)
            .default_pos([290.0, 60.0])
            .default_size([420.0, 520.0])
            .vscroll(true)
            .show(ctx, |ui| requests = lib.show(ui, target));
        settings.show_library &= open;
        let mut assign = Vec::new();
        for r in requests {
            match r {
                LibraryRequest::Assign(entry) => assign.push(entry),
                LibraryRequest::AddFolderDialog => {
                    if let Some(dir) = rfd::FileDialog::new().pick_folder() {
                        self.add_folder(settings, &dir);
                    }
                }
                LibraryRequest::RemoveFolder(dir) => {
                    settings.library_folders.retain(|f| *f != dir);
                    self.library(settings).rescan(&folders(settings));
                }
            }
        }
        assign
    }
}
