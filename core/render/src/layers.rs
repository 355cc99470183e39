//! The film's layers and what emitter edits cost them, shared by every mode with a
//! layered film. Radiance is linear in each emitter, so a mode accumulates each one for
//! unit emission in its own layer: the background, the ambient term, the environment
//! (unit strength), then the lights. Up to `MANY_LIGHTS` lights each own a layer; above
//! that the film is bounded: `OWN_LIGHT_LAYERS` lights (the brightest, then the most
//! recently edited) own a layer and the rest add, weighted by their emission at the time
//! of sampling, to one shared layer (docs/rendering.md, "Many lights").

use glam::DVec3;

use super::edit::{Invalidation, SceneEdit};
use super::film::LayeredFilm;
use crate::scene::{Background, Environment, Light, Scene};

pub const BACKGROUND: usize = 0;
pub const AMBIENT: usize = 1;
/// The environment's lighting, and what rays that leave the scene see of it when the
/// scene has no `[background]` table.
pub const ENVIRONMENT: usize = 2;
pub const FIRST_LIGHT: usize = 3;

/// Up to this many lights each own a film layer (and the spmm mode traces one shadow
/// ray to each); above it the film is bounded and lights are sampled stochastically.
pub const MANY_LIGHTS: usize = 16;

/// Lights with a layer of their own in a bounded film. Two keeps a 10,000-light film
/// within 1.5x the bytes of a one-light film (6 layers against 4: 192 against 136
/// bytes per pixel, `Film::bytes_for`).
pub const OWN_LIGHT_LAYERS: usize = 2;

/// The shared layer of a bounded film: every light without a layer of its own, each
/// sample already weighted by its light's emission.
pub const SHARED_LIGHTS: usize = FIRST_LIGHT + OWN_LIGHT_LAYERS;

/// The layer count of a film for `scene`.
pub fn layer_count(scene: &Scene) -> usize {
    if scene.lights.len() <= MANY_LIGHTS {
        FIRST_LIGHT + scene.lights.len()
    } else {
        SHARED_LIGHTS + 1
    }
}

/// A light's power for ranking and selection: mean emission over the channels times
/// `4 pi` (point) or `pi A` (one-sided area light).
pub fn light_power(light: &Light) -> f64 {
    let e = light.emission().element_sum() / 3.0;
    match light {
        Light::Point { .. } => 4.0 * std::f64::consts::PI * e,
        Light::Area { edge_u, edge_v, .. } => {
            std::f64::consts::PI * edge_u.cross(*edge_v).length() * e
        }
    }
}

/// Which layer light `k` adds to, and the factor its unit-emission samples are
/// multiplied by first (one, or its emission in the shared layer).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightTarget {
    pub layer: usize,
    pub factor: DVec3,
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
/// they are still valid, and which lights own a layer.
#[derive(Clone, Debug)]
pub struct Layers {
    /// The radius the ambient layer's samples were traced with.
    ambient_radius: Option<f64>,
    /// The environment the environment layer's samples were traced with.
    environment: Option<Environment>,
    /// `None`: one layer per light. `Some`: a bounded film, own slot `s` (layer
    /// `FIRST_LIGHT + s`) holding light `own[s]` if any.
    own: Option<Vec<Option<usize>>>,
    /// When each own slot was last given or edited (least recent is evicted first).
    used: Vec<u64>,
    clock: u64,
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
        let mut layers = Self {
            ambient_radius: scene.ambient.map(|a| a.radius),
            environment: scene.environment.clone(),
            own: None,
            used: vec![0; OWN_LIGHT_LAYERS],
            clock: 0,
        };
        layers.lay_out_lights(scene);
        layers
    }

    /// One layer per light, or a bounded film whose own slots go to the brightest
    /// lights (the dimmer of them first in line for eviction).
    fn lay_out_lights(&mut self, scene: &Scene) {
        if scene.lights.len() <= MANY_LIGHTS {
            self.own = None;
            return;
        }
        let mut order: Vec<usize> = (0..scene.lights.len()).collect();
        order.sort_by(|&a, &b| {
            light_power(&scene.lights[b]).total_cmp(&light_power(&scene.lights[a]))
        });
        let mut own = vec![None; OWN_LIGHT_LAYERS];
        let base = self.clock;
        for (s, &k) in order.iter().take(OWN_LIGHT_LAYERS).enumerate() {
            own[s] = Some(k);
            // The brightest counts as used last: the dimmer ones are evicted first.
            self.used[s] = base + (OWN_LIGHT_LAYERS - s) as u64;
        }
        self.clock = base + OWN_LIGHT_LAYERS as u64;
        self.own = Some(own);
    }

    /// The film's layer count.
    pub fn layer_count(&self, scene: &Scene) -> usize {
        match self.own {
            None => FIRST_LIGHT + scene.lights.len(),
            Some(_) => SHARED_LIGHTS + 1,
        }
    }

    /// True for a bounded film (more than `MANY_LIGHTS` lights).
    pub fn bounded(&self) -> bool {
        self.own.is_some()
    }

    /// Where each light's samples go.
    pub fn light_targets(&self, scene: &Scene) -> Vec<LightTarget> {
        (0..scene.lights.len())
            .map(|k| match &self.own {
                None => LightTarget {
                    layer: FIRST_LIGHT + k,
                    factor: DVec3::ONE,
                },
                Some(own) => match own.iter().position(|&o| o == Some(k)) {
                    Some(s) => LightTarget {
                        layer: FIRST_LIGHT + s,
                        factor: DVec3::ONE,
                    },
                    None => LightTarget {
                        layer: SHARED_LIGHTS,
                        factor: scene.lights[k].emission(),
                    },
                },
            })
            .collect()
    }

    /// The weight of each layer: the current emissions (one for the shared layer,
    /// whose samples carry their emission).
    pub fn weights(&self, scene: &Scene) -> Vec<DVec3> {
        let mut w = vec![DVec3::ZERO; self.layer_count(scene)];
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
        match &self.own {
            None => {
                for (k, light) in scene.lights.iter().enumerate() {
                    w[FIRST_LIGHT + k] = light.emission();
                }
            }
            Some(own) => {
                for (s, k) in own.iter().enumerate() {
                    if let Some(k) = k {
                        w[FIRST_LIGHT + s] = scene.lights[*k].emission();
                    }
                }
                w[SHARED_LIGHTS] = DVec3::ONE;
            }
        }
        w
    }

    /// The layers sampled every frame: the ambient and environment layers only while
    /// the scene has them, own slots only while they hold a light.
    pub fn active(&self, scene: &Scene) -> Vec<usize> {
        (0..self.layer_count(scene))
            .filter(|&l| match l {
                AMBIENT => scene.ambient.is_some(),
                ENVIRONMENT => scene.environment.is_some(),
                l if (FIRST_LIGHT..SHARED_LIGHTS).contains(&l) => self
                    .own
                    .as_ref()
                    .is_none_or(|o| o[l - FIRST_LIGHT].is_some()),
                _ => true,
            })
            .collect()
    }

    /// The own slot of light `k` in a bounded film.
    fn slot_of(&self, k: usize) -> Option<usize> {
        self.own.as_ref()?.iter().position(|&o| o == Some(k))
    }

    /// Gives light `k` the least recently used own slot (its former light joins the
    /// shared layer); restarts that slot and the shared layer.
    fn promote(&mut self, film: &mut impl LayeredFilm, k: usize) -> Invalidation {
        let s = (0..OWN_LIGHT_LAYERS)
            .min_by_key(|&s| self.used[s])
            .expect("at least one own slot");
        self.clock += 1;
        self.used[s] = self.clock;
        self.own.as_mut().expect("a bounded film")[s] = Some(k);
        film.reset_layer(FIRST_LIGHT + s);
        film.reset_layer(SHARED_LIGHTS);
        Invalidation::Layers(vec![FIRST_LIGHT + s, SHARED_LIGHTS])
    }

    /// A light count crossed `MANY_LIGHTS`: the light layers are laid out again and
    /// restart; the other layers keep their samples.
    fn relayout(&mut self, film: &mut impl LayeredFilm, scene: &Scene) -> Invalidation {
        self.lay_out_lights(scene);
        let count = self.layer_count(scene);
        film.keep_layers(count, FIRST_LIGHT);
        Invalidation::Layers((FIRST_LIGHT..count).collect())
    }

    /// Restarts what an emitter edit invalidates, after `edit.apply_to(scene)`;
    /// `None` for edits that are not about emitters (the mode handles those).
    ///
    /// In a bounded film an edit of a light in the shared layer first promotes it to
    /// an own slot: the shared sum holds the light's old emission and cannot be
    /// re-weighted, so it restarts either way, and promotion makes the next edits of
    /// the same light (a slider drag) free or restart only its slot.
    pub fn apply(
        &mut self,
        film: &mut impl LayeredFilm,
        before: &Before,
        edit: &SceneEdit,
        scene: &Scene,
    ) -> Option<Invalidation> {
        Some(match edit {
            SceneEdit::Light { index, light } => {
                let old = before.light.expect("apply_to checked the index");
                let emission_only = old.with_emission(light.emission()) == *light;
                match (&self.own, self.slot_of(*index)) {
                    (None, _) if emission_only => Invalidation::Nothing,
                    (None, _) => {
                        film.reset_layer(FIRST_LIGHT + index);
                        Invalidation::Layer(FIRST_LIGHT + index)
                    }
                    (Some(_), Some(s)) => {
                        self.clock += 1;
                        self.used[s] = self.clock;
                        if emission_only {
                            Invalidation::Nothing
                        } else {
                            film.reset_layer(FIRST_LIGHT + s);
                            Invalidation::Layer(FIRST_LIGHT + s)
                        }
                    }
                    (Some(_), None) => self.promote(film, *index),
                }
            }
            SceneEdit::AddLight(_) => {
                let n = scene.lights.len();
                if n == MANY_LIGHTS + 1 {
                    self.relayout(film, scene)
                } else if self.own.is_some() {
                    self.promote(film, n - 1)
                } else {
                    film.push_layer();
                    Invalidation::Layer(film.layers() - 1)
                }
            }
            SceneEdit::RemoveLight(index) => {
                let n = scene.lights.len();
                if self.own.is_some() && n <= MANY_LIGHTS {
                    return Some(self.relayout(film, scene));
                }
                let Some(own) = &mut self.own else {
                    film.remove_layer(FIRST_LIGHT + index);
                    return Some(Invalidation::Nothing);
                };
                let mut invalidation = Invalidation::Layer(SHARED_LIGHTS);
                for (s, o) in own.iter_mut().enumerate() {
                    match *o {
                        Some(k) if k == *index => {
                            // Its slot is no longer sampled nor weighted; the shared
                            // sum never held it.
                            *o = None;
                            film.reset_layer(FIRST_LIGHT + s);
                            self.used[s] = 0;
                            invalidation = Invalidation::Nothing;
                        }
                        Some(k) if k > *index => *o = Some(k - 1),
                        _ => {}
                    }
                }
                if invalidation != Invalidation::Nothing {
                    film.reset_layer(SHARED_LIGHTS);
                }
                invalidation
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
