//! Lights (and the ambient term) left out of the scene a render mode sees, because the
//! mode cannot render them and the user chose to switch with them disabled. The
//! document keeps every light; the mode gets a scene without the disabled ones, and
//! every edit is translated from the document's light indices to the mode's (a
//! disabled light's edits stay in the document only). Per mode: switching builds a new
//! set from that mode's `Unsupported` answer.

use meso_render::scene::Scene;
use meso_render::{SceneEdit, Unrenderable, Unsupported};

#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Disabled {
    /// Document indices of the disabled lights, ascending.
    lights: Vec<usize>,
    pub ambient: bool,
}

impl Disabled {
    /// What to leave out so that the mode renders the rest (the parts that are lights
    /// or the ambient term; the caller checks `only_lights` first).
    pub fn from_unsupported(u: &Unsupported) -> Self {
        let mut d = Self::default();
        for p in &u.parts {
            match p {
                Unrenderable::Light { index, .. } => d.lights.push(*index),
                Unrenderable::Ambient => d.ambient = true,
                _ => {}
            }
        }
        d.lights.sort_unstable();
        d.lights.dedup();
        d
    }

    pub fn is_empty(&self) -> bool {
        self.lights.is_empty() && !self.ambient
    }

    pub fn light(&self, doc_index: usize) -> bool {
        self.lights.binary_search(&doc_index).is_ok()
    }

    /// Leaves a light just added to the document (at `doc_index`) out of the mode.
    pub fn disable_light(&mut self, doc_index: usize) {
        if let Err(at) = self.lights.binary_search(&doc_index) {
            self.lights.insert(at, doc_index);
        }
    }

    /// The scene the mode renders: the document's without the disabled parts.
    pub fn scene_for_mode(&self, doc: &Scene) -> Scene {
        let mut s = doc.clone();
        if !self.lights.is_empty() {
            s.lights = doc
                .lights
                .iter()
                .enumerate()
                .filter(|(i, _)| !self.light(*i))
                .map(|(_, l)| *l)
                .collect();
        }
        if self.ambient {
            s.ambient = None;
        }
        s
    }

    /// The mode's index of an enabled document light.
    fn mode_index(&self, doc_index: usize) -> usize {
        doc_index - self.lights.iter().take_while(|&&d| d < doc_index).count()
    }

    /// The edit the mode should get for a document edit (already applied to the
    /// document), or `None` if it concerns only disabled parts. Keeps the index map
    /// in step with removals.
    pub fn translate(&mut self, edit: SceneEdit) -> Option<SceneEdit> {
        if self.is_empty() {
            return Some(edit);
        }
        match edit {
            SceneEdit::Light { index, light } => (!self.light(index)).then(|| SceneEdit::Light {
                index: self.mode_index(index),
                light,
            }),
            SceneEdit::RemoveLight(index) => {
                let was_disabled = self.light(index);
                let mode_index = self.mode_index(index);
                self.lights.retain(|&d| d != index);
                for d in &mut self.lights {
                    if *d > index {
                        *d -= 1;
                    }
                }
                (!was_disabled).then_some(SceneEdit::RemoveLight(mode_index))
            }
            SceneEdit::Ambient(_) if self.ambient => None,
            other => Some(other),
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use meso_render::scene::Light;
    use meso_render::{Device, ModeKind};

    use super::*;

    fn point(x: f64) -> Light {
        Light::Point {
            position: DVec3::new(x, 1.0, 0.0),
            intensity: DVec3::ONE,
        }
    }

    fn scene() -> Scene {
        meso_render::scene::load_scene(&crate::studio::default_scene_path()).expect("default scene")
    }

    /// Applies `edit` to the document and its translation to the mode's scene; the two
    /// must stay "the document without the disabled lights".
    fn step(doc: &mut Scene, mode: &mut Scene, d: &mut Disabled, edit: SceneEdit) {
        edit.apply_to(doc).expect("valid on the document");
        if let Some(e) = d.translate(edit) {
            e.apply_to(mode).expect("valid on the mode");
        }
        assert_eq!(d.scene_for_mode(doc).lights, mode.lights);
    }

    #[test]
    fn edits_reach_the_right_light_through_removals_and_additions() {
        let mut doc = scene();
        doc.lights = (0..5).map(|i| point(i as f64)).collect();
        let mut d = Disabled::from_unsupported(&Unsupported {
            mode: ModeKind::Adaptive,
            device: Device::Cpu,
            parts: vec![
                Unrenderable::Light {
                    index: 3,
                    kind: "point",
                },
                Unrenderable::Light {
                    index: 1,
                    kind: "point",
                },
            ],
        });
        let mut mode = d.scene_for_mode(&doc);
        assert_eq!(mode.lights, vec![point(0.0), point(2.0), point(4.0)]);
        // Light 4 of the document is the mode's light 2.
        let l = SceneEdit::Light {
            index: 4,
            light: point(40.0),
        };
        step(&mut doc, &mut mode, &mut d, l);
        assert_eq!(mode.lights[2], point(40.0));
        // A disabled light's edit stays in the document.
        step(
            &mut doc,
            &mut mode,
            &mut d,
            SceneEdit::Light {
                index: 1,
                light: point(10.0),
            },
        );
        assert_eq!(doc.lights[1], point(10.0));
        // Removing an enabled light before a disabled one shifts the map.
        step(&mut doc, &mut mode, &mut d, SceneEdit::RemoveLight(0));
        assert!(d.light(0) && d.light(2));
        step(&mut doc, &mut mode, &mut d, SceneEdit::RemoveLight(2));
        assert!(d.light(0) && !d.light(2));
        step(&mut doc, &mut mode, &mut d, SceneEdit::AddLight(point(7.0)));
        step(
            &mut doc,
            &mut mode,
            &mut d,
            SceneEdit::Light {
                index: 1,
                light: point(2.5),
            },
        );
        assert_eq!(mode.lights, vec![point(2.5), point(40.0), point(7.0)]);
    }

    #[test]
    fn a_disabled_ambient_term_is_left_out_and_its_edits_are_kept_back() {
        let doc = scene();
        let mut d = Disabled::default();
        assert!(d.translate(SceneEdit::Ambient(None)).is_some());
        d.ambient = true;
        assert!(d.scene_for_mode(&doc).ambient.is_none());
        assert!(d.translate(SceneEdit::Ambient(None)).is_none());
    }
}
