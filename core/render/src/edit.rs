//! Edits a render mode accepts while it accumulates, and what each one invalidated.
//! The rule (docs/rendering.md): restart only what the edit changes. An
//! emission change re-weights the film's layers and keeps every sample; a moved light
//! or a new ambient radius restarts that one layer (`layers.rs`); a material edit
//! restarts the pixels whose samples shaded the material; a camera, size or geometry
//! change restarts all. The values' rules live in their types (`Light::problem`, ...).

use crate::scene::{
    Ambient, Background, Camera, Environment, Light, Material, Problem, RenderSettings, Scene,
    TriangleMesh,
};

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
    /// Environment lighting on, off or changed; a strength change keeps every sample.
    Environment(Option<Environment>),
    Background(Background),
    /// The camera is being dragged: the SPMM residual is skipped (the seed's trick)
    /// until `Moving(false)`, which restarts the pixels that skipped it.
    Moving(bool),
    /// Points on each area light per frame (`[render] light_samples`, 1..=64).
    LightSamples(u32),
}

/// What an edit cost the accumulated image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Invalidation {
    /// Every sample kept; the image is re-weighted (emission or colour edits).
    Nothing,
    /// One layer restarts (a light moved or resized, the ambient radius changed, the
    /// environment turned or replaced).
    Layer(usize),
    /// These layers restart (a background switched to or from the environment).
    Layers(Vec<usize>),
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
    #[error("{0}")]
    Size(String),
    #[error("mesh {index}: {problem}")]
    Mesh { index: usize, problem: String },
    #[error("{what} {problem}")]
    Invalid {
        what: &'static str,
        problem: Problem,
    },
    #[error("uv_scale {0} must be positive and finite")]
    UvScale(String),
    #[error("light samples {0} is outside 1..={max}", max = crate::scene::MAX_LIGHT_SAMPLES)]
    LightSamples(u32),
    /// The mode cannot render what the edit brings (e.g. a material it cannot shade).
    #[error(transparent)]
    Unsupported(#[from] super::Unsupported),
    /// A resize whose film would not fit in memory.
    #[error(transparent)]
    TooLarge(#[from] super::FilmTooLarge),
}

impl SceneEdit {
    /// Whether the edit may change what a pixel's centre ray first sees (the
    /// denoiser's guides: `RenderMode::guides`): anything but the emitters and the
    /// light samples.
    pub fn changes_guides(&self) -> bool {
        !matches!(
            self,
            SceneEdit::Light { .. }
                | SceneEdit::AddLight(_)
                | SceneEdit::RemoveLight(_)
                | SceneEdit::Ambient(_)
                | SceneEdit::Environment(_)
                | SceneEdit::Background(_)
                | SceneEdit::LightSamples(_)
        )
    }

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
        let invalid = |what: &'static str, p: Option<Problem>| {
            p.map_or(Ok(()), |problem| Err(EditError::Invalid { what, problem }))
        };
        match self {
            SceneEdit::Camera(camera) => {
                invalid("camera", camera.problem())?;
                scene.camera = *camera;
            }
            SceneEdit::Resize { width, height } => {
                if let Some(p) = RenderSettings::size_problem(*width, *height) {
                    return Err(EditError::Size(p));
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
                if let Some((i, p)) = meshes
                    .iter()
                    .enumerate()
                    .find_map(|(i, m)| m.problem().map(|p| (i, p)))
                {
                    return Err(EditError::Mesh {
                        index: i,
                        problem: p,
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
                if let Material::Spmm { uv_scale, .. } | Material::Btf { uv_scale, .. } = material
                    && !(uv_scale.is_finite() && uv_scale.min_element() > 0.0)
                {
                    return Err(EditError::UvScale(uv_scale.to_string()));
                }
                *slot = material.clone();
            }
            SceneEdit::Light { index, light } => {
                invalid("light", light.problem())?;
                *scene
                    .lights
                    .get_mut(*index)
                    .ok_or_else(|| no_light(*index))? = *light;
            }
            SceneEdit::AddLight(light) => {
                invalid("light", light.problem())?;
                scene.lights.push(*light);
            }
            SceneEdit::RemoveLight(index) => {
                if *index >= lights {
                    return Err(no_light(*index));
                }
                scene.lights.remove(*index);
            }
            SceneEdit::Ambient(ambient) => {
                invalid("ambient", ambient.as_ref().and_then(|a| a.problem()))?;
                scene.ambient = *ambient;
            }
            SceneEdit::Environment(environment) => {
                invalid(
                    "environment",
                    environment.as_ref().and_then(|e| e.problem()),
                )?;
                scene.environment = environment.clone();
            }
            SceneEdit::Background(background) => {
                invalid("background", background.problem())?;
                scene.background = background.clone();
            }
            SceneEdit::Moving(_) => {}
            SceneEdit::LightSamples(n) => {
                if RenderSettings::light_samples_problem(*n).is_some() {
                    return Err(EditError::LightSamples(*n));
                }
                scene.render.light_samples = *n;
            }
        }
        Ok(())
    }
}
