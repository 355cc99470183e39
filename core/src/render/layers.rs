//! The film's layers and what emitter edits cost them, shared by every mode with a
//! layered film. Radiance is linear in each emitter, so a mode accumulates each one for
//! unit emission in its own layer: the background, the ambient term, the environment
//! (unit strength), then one layer per light. The image weights each layer by the
//! emitter's current value, so an emission, colour or strength edit keeps every sample;
//! an edit that changes where light comes from restarts only its layer.

use glam::DVec3;

use super::edit::{Invalidation, SceneEdit};
use super::film::Film;
use crate::scene::{Background, Environment, Light, Scene};

pub const BACKGROUND: usize = 0;
pub const AMBIENT: usize = 1;
/// The environment's lighting, and what rays that leave the scene see of it when the
/// scene has no `[background]` table.
pub const ENVIRONMENT: usize = 2;
pub const FIRST_LIGHT: usize = 3;

/// The layer count of a film for `scene`.
pub fn layer_count(scene: &Scene) -> usize {
    FIRST_LIGHT + scene.lights.len()
}

/// Where a ray that leaves the scene adds its radiance, and that radiance per unit of
/// the layer's weight; `None` if it sees black.
pub fn escaped(scene: &Scene, dir: DVec3) -> Option<(usize, DVec3)> {
    match &scene.background {
        Background::Color(_) => Some((BACKGROUND, DVec3::ONE)),
        Background::Environment(img) => {
            let (x, y) = crate::environment::pixel_of(img.width(), img.height(), dir);
            let p = img.get(x, y);
            Some((
                BACKGROUND,
                DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64),
            ))
        }
        Background::FromEnvironment => scene
            .environment
            .as_ref()
            .map(|e| (ENVIRONMENT, e.radiance_unit(dir))),
    }
}

/// What the emitter layers' samples were traced with, so an edit can tell whether
/// they are still valid.
#[derive(Clone, Debug)]
pub struct Layers {
    /// The radius the ambient layer's samples were traced with.
    ambient_radius: Option<f64>,
    /// The environment the environment layer's samples were traced with.
    environment: Option<Environment>,
}

/// What an emitter edit needs to know of the scene before it.
#[derive(Clone, Debug)]
pub struct Before {
    light: Option<Light>,
    background_was_colour: bool,
    background_was_environment: bool,
}

impl Before {
    /// Reads what `edit` will change; call before `SceneEdit::apply_to`.
    pub fn of(scene: &Scene, edit: &SceneEdit) -> Self {
        Self {
            light: match edit {
                SceneEdit::Light { index, .. } => scene.lights.get(*index).copied(),
                _ => None,
            },
            background_was_colour: matches!(scene.background, Background::Color(_)),
            background_was_environment: matches!(scene.background, Background::FromEnvironment),
        }
    }
}

impl Layers {
    pub fn new(scene: &Scene) -> Self {
        Self {
            ambient_radius: scene.ambient.map(|a| a.radius),
            environment: scene.environment.clone(),
        }
    }

    /// The weight of each layer: the current emissions.
    pub fn weights(scene: &Scene) -> Vec<DVec3> {
        let mut w = vec![DVec3::ZERO; layer_count(scene)];
        w[BACKGROUND] = match &scene.background {
            Background::Color(c) => *c,
            Background::Environment(_) => DVec3::ONE,
            Background::FromEnvironment => DVec3::ZERO,
        };
        w[AMBIENT] = scene.ambient.map_or(DVec3::ZERO, |a| a.radiance);
        w[ENVIRONMENT] = scene
            .environment
            .as_ref()
            .map_or(DVec3::ZERO, |e| DVec3::splat(e.strength));
        for (k, light) in scene.lights.iter().enumerate() {
            w[FIRST_LIGHT + k] = light.emission();
        }
        w
    }

    /// The layers sampled every frame: the ambient and environment layers only while
    /// the scene has them.
    pub fn active(scene: &Scene) -> Vec<usize> {
        (0..layer_count(scene))
            .filter(|&l| match l {
                AMBIENT => scene.ambient.is_some(),
                ENVIRONMENT => scene.environment.is_some(),
                _ => true,
            })
            .collect()
    }

    /// Restarts what an emitter edit invalidates, after `edit.apply_to(scene)`;
    /// `None` for edits that are not about emitters (the mode handles those).
    pub fn apply(
        &mut self,
        film: &mut Film,
        before: &Before,
        edit: &SceneEdit,
        scene: &Scene,
    ) -> Option<Invalidation> {
        Some(match edit {
            SceneEdit::Light { index, light } => {
                let old = before.light.expect("apply_to checked the index");
                if old.with_emission(light.emission()) == *light {
                    Invalidation::Nothing
                } else {
                    film.reset_layer(FIRST_LIGHT + index);
                    Invalidation::Layer(FIRST_LIGHT + index)
                }
            }
            SceneEdit::AddLight(_) => {
                film.push_layer();
                Invalidation::Layer(film.layers() - 1)
            }
            SceneEdit::RemoveLight(index) => {
                film.remove_layer(FIRST_LIGHT + index);
                Invalidation::Nothing
            }
            // Off: the layer is weighted zero and keeps its samples; on again with the
            // radius its samples were traced with: nothing to redo.
            SceneEdit::Ambient(None) => Invalidation::Nothing,
            SceneEdit::Ambient(Some(a)) if Some(a.radius) == self.ambient_radius => {
                Invalidation::Nothing
            }
            SceneEdit::Ambient(Some(a)) => {
                self.ambient_radius = Some(a.radius);
                film.reset_layer(AMBIENT);
                Invalidation::Layer(AMBIENT)
            }
            // The same rule for the environment: only its strength weights the layer.
            SceneEdit::Environment(None) => Invalidation::Nothing,
            SceneEdit::Environment(Some(e))
                if self
                    .environment
                    .as_ref()
                    .is_some_and(|old| old.same_but_strength(e)) =>
            {
                Invalidation::Nothing
            }
            SceneEdit::Environment(Some(e)) => {
                self.environment = Some(e.clone());
                film.reset_layer(ENVIRONMENT);
                Invalidation::Layer(ENVIRONMENT)
            }
            SceneEdit::Background(Background::Color(_)) if before.background_was_colour => {
                Invalidation::Nothing
            }
            SceneEdit::Background(b) => {
                film.reset_layer(BACKGROUND);
                // Escaping rays of a scene without a background table sit in the
                // environment layer: a switch to or from that restarts it too.
                let involves_environment =
                    before.background_was_environment || matches!(b, Background::FromEnvironment);
                if involves_environment && scene.environment.is_some() {
                    film.reset_layer(ENVIRONMENT);
                    self.environment = scene.environment.clone();
                    Invalidation::Layers(vec![BACKGROUND, ENVIRONMENT])
                } else {
                    Invalidation::Layer(BACKGROUND)
                }
            }
            _ => return None,
        })
    }
}
