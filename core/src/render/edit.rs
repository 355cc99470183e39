//! Edits a render mode accepts while it accumulates, and what each one invalidated.
//! The rule (DESIGN.md, the seed's section 4): restart only what the edit changes. An
//! emission change re-weights the film's layers and keeps every sample; a moved light
//! or a new ambient radius restarts that one layer; a material edit restarts the pixels
//! whose samples shaded the material; a camera, size or geometry change restarts all.

use crate::scene::{Ambient, Background, Camera, Light, Material, Scene, TriangleMesh};

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

impl SceneEdit {
    /// Checks the edit against `scene` and applies it to the scene's description (the
    /// one place edits change a `Scene`: render modes and the editor's document both
    /// use it). `Resize` and `Moving` concern the render, not the scene: no change.
    /// On error the scene is untouched.
    pub fn apply_to(&self, scene: &mut Scene) -> Result<(), EditError> {
        let lights = scene.lights.len();
        let no_light = |index| EditError::NoSuchLight {
            index,
            count: lights,
        };
        let invalid = |p: Option<String>| p.map_or(Ok(()), |p| Err(EditError::Invalid(p)));
        match self {
            SceneEdit::Camera(camera) => {
                invalid(camera.problem())?;
                scene.camera = *camera;
            }
            SceneEdit::Resize { width, height } => {
                if !((1..=16384).contains(width) && (1..=16384).contains(height)) {
                    return Err(EditError::Size {
                        width: *width,
                        height: *height,
                    });
                }
            }
            SceneEdit::Meshes(meshes) => {
                let count = scene.materials.len();
                if let Some(m) = meshes.iter().find(|m| m.material >= count) {
                    return Err(EditError::MeshMaterial {
                        material: m.material,
                        count,
                    });
                }
                scene.meshes = meshes.clone();
            }
            SceneEdit::Material { index, material } => {
                let count = scene.materials.len();
                let slot = scene
                    .materials
                    .get_mut(*index)
                    .ok_or(EditError::NoSuchMaterial {
                        index: *index,
                        count,
                    })?;
                if let Material::Spmm {
                    uv_scale, material, ..
                } = material
                    && !(uv_scale.is_finite() && uv_scale.min_element() > 0.0)
                {
                    return Err(EditError::Invalid(format!(
                        "uv_scale {uv_scale} of `{}` must be positive and finite",
                        material.name()
                    )));
                }
                *slot = material.clone();
            }
            SceneEdit::Light { index, light } => {
                invalid(light.problem())?;
                *scene
                    .lights
                    .get_mut(*index)
                    .ok_or_else(|| no_light(*index))? = *light;
            }
            SceneEdit::AddLight(light) => {
                invalid(light.problem())?;
                scene.lights.push(*light);
            }
            SceneEdit::RemoveLight(index) => {
                if *index >= lights {
                    return Err(no_light(*index));
                }
                scene.lights.remove(*index);
            }
            SceneEdit::Ambient(ambient) => {
                invalid(ambient.as_ref().and_then(|a| a.problem()))?;
                scene.ambient = *ambient;
            }
            SceneEdit::Background(background) => {
                if let Background::Color(c) = background
                    && !(c.is_finite() && c.min_element() >= 0.0)
                {
                    return Err(EditError::Invalid(format!(
                        "background colour {c} must be finite and non-negative"
                    )));
                }
                scene.background = background.clone();
            }
            SceneEdit::Moving(_) => {}
        }
        Ok(())
    }
}
