//! The progressive skeleton every mode shares, CPU and GPU: the scene it renders, its
//! BVH, the camera, a film (host `Film` or a device's) with its layers, the frame
//! counters, the moving flag and the preparation report; the preparation steps every
//! CPU mode takes; and the edit steps every mode takes (the scene edited, emitter edits
//! through the layers, the camera following a new view or size). A mode holds one and
//! writes only what is its own: how it shades, what an edit costs its own data.

use crate::edit::{EditError, Invalidation, SceneEdit};
use crate::film::{Film, LayeredFilm, memory_limit_bytes};
use crate::geometry::{PinholeCamera, SceneBvh};
use crate::layers::{Before, Layers};
use crate::scene::{Material, RenderSettings, Scene};
use crate::{ModeError, PreparationReport, Prepare, Unsupported};

/// A film a progressive mode accumulates into: the layers' operations and its size.
pub trait ProgressiveFilm: LayeredFilm {
    fn width(&self) -> u32;
    fn height(&self) -> u32;
    /// Why this film could not become `width` x `height` (its own memory counted as
    /// free, since it is released first); checked before anything changes.
    fn resize_problem(&self, width: u32, height: u32) -> Result<(), EditError>;
    /// Takes the new size; the samples are forgotten by the restart that follows.
    fn resize(&mut self, width: u32, height: u32);
}

impl ProgressiveFilm for Film {
    fn width(&self) -> u32 {
        Film::width(self)
    }
    fn height(&self) -> u32 {
        Film::height(self)
    }
    fn resize_problem(&self, width: u32, height: u32) -> Result<(), EditError> {
        let free = memory_limit_bytes() + self.bytes();
        Ok(Film::check(width, height, self.layers(), free)?)
    }
    fn resize(&mut self, width: u32, height: u32) {
        Film::resize(self, width, height);
    }
}

/// What every progressive mode holds.
pub struct Progressive<F> {
    pub scene: Scene,
    pub bvh: SceneBvh,
    /// The scene's camera at the film's size.
    pub camera: PinholeCamera,
    pub film: F,
    pub layers: Layers,
    pub samples_per_frame: u32,
    /// Index of the next sample (frame-major), where random numbers derive from it.
    pub next_sample: u64,
    /// Frames since the last restart.
    pub frames: u32,
    /// The camera is being dragged (modes may shade more cheaply meanwhile).
    pub moving: bool,
    pub preparation: PreparationReport,
}

/// What an edit leaves to the mode once the common steps are done.
#[derive(Debug)]
pub enum Edited {
    /// The layers took an emitter edit (a light, the ambient term, the environment,
    /// the background): what it invalidated.
    Emitters(Invalidation),
    /// The camera moved (`camera` follows).
    Camera,
    /// The film took a new size (`camera` follows).
    Resized,
    /// New meshes in the scene; the BVH is still the old one.
    Meshes,
    /// Material `index` changed from `before`.
    Material { index: usize, before: Material },
    /// The moving flag changed (`moving` holds the new one).
    Moving,
    /// Another number of light samples per shading point.
    LightSamples,
    /// Nothing changed (the moving flag set to what it was).
    Nothing,
}

impl<F: ProgressiveFilm> Progressive<F> {
    /// The skeleton over what the mode prepared, at the film's size, before any frame.
    pub fn new(
        scene: Scene,
        bvh: SceneBvh,
        film: F,
        layers: Layers,
        preparation: PreparationReport,
    ) -> Self {
        let camera = PinholeCamera::new(&scene.camera, film.width(), film.height());
        Self {
            scene,
            bvh,
            camera,
            film,
            layers,
            samples_per_frame: 1,
            next_sample: 0,
            frames: 0,
            moving: false,
            preparation,
        }
    }

    /// The edit steps every mode takes, once the mode has refused what it cannot
    /// render: a resize checked against the film's memory, the scene edited (on error
    /// nothing changed), emitter edits through the layers, the camera following a new
    /// view or size, the moving flag kept. The rest is the mode's (`Edited`).
    pub fn apply(&mut self, edit: &SceneEdit) -> Result<Edited, EditError> {
        if let SceneEdit::Resize { width, height } = *edit {
            self.film.resize_problem(width, height)?;
        }
        let before = Before::of(&self.scene, edit);
        let material_before = match edit {
            SceneEdit::Material { index, .. } => self.scene.materials.get(*index).cloned(),
            _ => None,
        };
        edit.apply_to(&mut self.scene)?;
        if let Some(invalidation) = self
            .layers
            .apply(&mut self.film, &before, edit, &self.scene)
        {
            return Ok(Edited::Emitters(invalidation));
        }
        Ok(match *edit {
            SceneEdit::Camera(camera) => {
                self.camera = PinholeCamera::new(&camera, self.film.width(), self.film.height());
                Edited::Camera
            }
            SceneEdit::Resize { width, height } => {
                self.camera = PinholeCamera::new(&self.scene.camera, width, height);
                self.film.resize(width, height);
                Edited::Resized
            }
            SceneEdit::Meshes(_) => Edited::Meshes,
            SceneEdit::Material { index, .. } => Edited::Material {
                index,
                before: material_before.expect("apply_to checked the index"),
            },
            SceneEdit::Moving(moving) if moving == self.moving => Edited::Nothing,
            SceneEdit::Moving(moving) => {
                self.moving = moving;
                Edited::Moving
            }
            SceneEdit::LightSamples(_) => Edited::LightSamples,
            SceneEdit::Light { .. }
            | SceneEdit::AddLight(_)
            | SceneEdit::RemoveLight(_)
            | SceneEdit::Ambient(_)
            | SceneEdit::Environment(_)
            | SceneEdit::Background(_) => unreachable!("emitter edits are the layers' to handle"),
        })
    }

    /// The counters of a restart (the mode forgets its film's samples, its own way).
    pub fn restart_counters(&mut self) {
        self.frames = 0;
        self.next_sample = 0;
    }
}

impl Progressive<Film> {
    /// The preparation every CPU mode starts with: the one size rule, what the mode
    /// cannot render (`supports`), the layers, a film that fits in memory (refused
    /// before the BVH or the film takes any), and the BVH as the stage `bvh`.
    pub fn prepare(
        scene: Scene,
        width: u32,
        height: u32,
        prepare: &Prepare,
        supports: fn(&Scene) -> Result<(), Unsupported>,
    ) -> Result<Self, ModeError> {
        if let Some(p) = RenderSettings::size_problem(width, height) {
            return Err(ModeError::Size(p));
        }
        supports(&scene)?;
        let layers = Layers::new(&scene);
        let film = Film::try_new(
            width,
            height,
            layers.layer_count(&scene),
            memory_limit_bytes(),
        )?;
        let mut report = PreparationReport::default();
        let bvh = prepare.bvh(&scene.meshes, &mut report)?;
        Ok(Self::new(scene, bvh, film, layers, report))
    }
}
