//! Edits a render mode accepts while it accumulates, and what each one invalidated.
//! The rule (DESIGN.md, the seed's section 4): restart only what the edit changes. An
//! emission change re-weights the film's layers and keeps every sample; a moved light
//! or a new ambient radius restarts that one layer; a material edit restarts the pixels
//! whose samples shaded the material; a camera, size or geometry change restarts all.

use crate::scene::{Ambient, Background, Camera, Light, Material, TriangleMesh};

#[derive(Clone, Debug)]
pub enum SceneEdit {
    Camera(Camera),
    /// A new image size (the app renders a smaller preview while the camera moves).
    Resize {
        width: u32,
        height: u32,
    },
    /// New geometry; the same topology is refitted, anything else rebuilt.
    Meshes(Vec<TriangleMesh>),
    /// Replaces material `index` (same slot, same meshes).
    Material {
        index: usize,
        material: Material,
    },
    /// Replaces light `index`.
    Light {
        index: usize,
        light: Light,
    },
    AddLight(Light),
    RemoveLight(usize),
    Ambient(Option<Ambient>),
    Background(Background),
    /// The camera is being dragged: the SPMM residual is skipped (the seed's trick)
    /// until `Moving(false)`, which restarts the pixels that skipped it.
    Moving(bool),
}

/// What an edit cost the accumulated image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Invalidation {
    /// Every sample kept; the image is re-weighted (emission or colour edits).
    Nothing,
    /// One layer restarts (a light moved or resized, the ambient radius changed).
    Layer(usize),
    /// These many pixels restart (they shaded the edited material).
    Pixels(usize),
    /// Everything restarts.
    All,
}

/// An edit that does not fit the scene.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum EditError {
    #[error("material {index} does not exist (the scene has {count})")]
    NoSuchMaterial { index: usize, count: usize },
    #[error("light {index} does not exist (the scene has {count})")]
    NoSuchLight { index: usize, count: usize },
    #[error("the new meshes use material {material}, but the scene has {count}")]
    MeshMaterial { material: usize, count: usize },
    #[error("image size {width}x{height} is outside 1..=16384")]
    Size { width: u32, height: u32 },
    #[error("{0}")]
    Invalid(String),
}
