//! The document the editor edits: the scene as edited so far (its own copy, changed by
//! the same `SceneEdit::apply_to` the renderer uses), the SPMM pack being edited and
//! where it lives on disk, a version bumped by every edit, and undo/redo.
//!
//! Undo stores whole snapshots of what edits change (materials, lights, ambient,
//! environment, background; cheap: packs and maps are shared `Arc`s), grouped so that one slider drag is one
//! step. Undoing replays the difference as ordinary edits, so the renderer restarts
//! only what changed. The camera is a view, not an edit: it is not undone.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use meso_materials::spmm::SpmmMaterial;
use meso_materials::spmm::pack::{self, ResidualPrecision};
use meso_render::scene::{Ambient, Background, Environment, Light, Material, Scene};
use meso_render::{EditError, SceneEdit};

/// What undo restores.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// Which material is the edited pack, and its file (a library assignment moves it).
    pack: Option<EditedPack>,
    materials: Vec<Material>,
    lights: Vec<Light>,
    ambient: Option<Ambient>,
    environment: Option<Environment>,
    background: Background,
    light_samples: u32,
}

/// The same lighting: the same map object, strength, rotation and sampling.
fn same_environment(a: &Option<Environment>, b: &Option<Environment>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(x), Some(y)) => x.same_but_strength(y) && x.strength == y.strength,
        _ => false,
    }
}

fn same_material(a: &Material, b: &Material) -> bool {
    match (a, b) {
        (
            Material::Brdf { brdf, albedo },
            Material::Brdf {
                brdf: b2,
                albedo: a2,
            },
        ) => brdf == b2 && albedo == a2,
        (
            Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            },
            Material::Spmm {
                material: m2,
                uv_scale: u2,
                residual: r2,
                npca: n2,
            },
        ) => Arc::ptr_eq(material, m2) && uv_scale == u2 && residual == r2 && npca == n2,
        (Material::Mirror { reflectance }, Material::Mirror { reflectance: r2 }) => {
            reflectance == r2
        }
        (Material::Merl { brdf, tint }, Material::Merl { brdf: b2, tint: t2 }) => {
            Arc::ptr_eq(brdf, b2) && tint == t2
        }
        _ => false,
    }
}

fn same_background(a: &Background, b: &Background) -> bool {
    match (a, b) {
        (Background::Color(x), Background::Color(y)) => x == y,
        (Background::Environment(x), Background::Environment(y)) => Arc::ptr_eq(x, y),
        (Background::FromEnvironment, Background::FromEnvironment) => true,
        _ => false,
    }
}

impl Snapshot {
    fn of(scene: &Scene, pack: &Option<EditedPack>) -> Self {
        Self {
            pack: pack.clone(),
            materials: scene.materials.clone(),
            lights: scene.lights.clone(),
            ambient: scene.ambient,
            environment: scene.environment.clone(),
            background: scene.background.clone(),
            light_samples: scene.render.light_samples,
        }
    }

    /// The edits that turn `self` into `target`.
    fn edits_to(&self, target: &Snapshot) -> Vec<SceneEdit> {
        let mut edits = Vec::new();
        for (index, (a, b)) in self.materials.iter().zip(&target.materials).enumerate() {
            if !same_material(a, b) {
                edits.push(SceneEdit::Material {
                    index,
                    material: b.clone(),
                });
            }
        }
        for (index, (a, b)) in self.lights.iter().zip(&target.lights).enumerate() {
            if a != b {
                edits.push(SceneEdit::Light { index, light: *b });
            }
        }
        for index in (target.lights.len()..self.lights.len()).rev() {
            edits.push(SceneEdit::RemoveLight(index));
        }
        for light in target.lights.iter().skip(self.lights.len()) {
            edits.push(SceneEdit::AddLight(*light));
        }
        if self.ambient != target.ambient {
            edits.push(SceneEdit::Ambient(target.ambient));
        }
        if !same_environment(&self.environment, &target.environment) {
            edits.push(SceneEdit::Environment(target.environment.clone()));
        }
        if !same_background(&self.background, &target.background) {
            edits.push(SceneEdit::Background(target.background.clone()));
        }
        if self.light_samples != target.light_samples {
            edits.push(SceneEdit::LightSamples(target.light_samples));
        }
        edits
    }
}

/// The SPMM pack being edited: which scene material holds it and its file.
#[derive(Clone, Debug)]
pub struct EditedPack {
    pub material: usize,
    pub path: Option<PathBuf>,
    pub precision: ResidualPrecision,
    /// The pack as last read or written, to tell whether there are unsaved edits.
    saved: Arc<SpmmMaterial>,
}

pub struct Document {
    pub scene: Scene,
    pub scene_path: Option<PathBuf>,
    pub pack: Option<EditedPack>,
    /// Bumped by every applied edit.
    pub version: u64,
    undo: Vec<Snapshot>,
    redo: Vec<Snapshot>,
    /// An undo group is open (a drag in progress): further edits join it.
    group_open: bool,
}

impl Document {
    pub fn new(scene: Scene, scene_path: Option<PathBuf>) -> Self {
        let pack = scene
            .materials
            .iter()
            .position(|m| matches!(m, Material::Spmm { .. }))
            .map(|i| EditedPack {
                material: i,
                path: scene.material_files.get(i).cloned().flatten(),
                precision: scene
                    .material_files
                    .get(i)
                    .cloned()
                    .flatten()
                    .and_then(|f| std::fs::read(f).ok())
                    .map_or(ResidualPrecision::F16, |b| pack::residual_precision(&b)),
                saved: spmm_of(&scene.materials[i]).expect("position found an SPMM material"),
            });
        Self {
            scene,
            scene_path,
            pack,
            version: 1,
            undo: Vec::new(),
            redo: Vec::new(),
            group_open: false,
        }
    }

    /// The edited pack's material, if the scene has one.
    pub fn material(&self) -> Option<Arc<SpmmMaterial>> {
        self.pack
            .as_ref()
            .and_then(|p| spmm_of(&self.scene.materials[p.material]))
    }

    /// Applies an edit as part of the open undo group (opening one if none is).
    pub fn apply(&mut self, edit: &SceneEdit) -> Result<(), EditError> {
        let before = (!self.group_open).then(|| Snapshot::of(&self.scene, &self.pack));
        edit.apply_to(&mut self.scene)?;
        if let Some(s) = before {
            self.undo.push(s);
            self.redo.clear();
            self.group_open = true;
        }
        self.version += 1;
        Ok(())
    }

    /// Ends the undo group: the next edit starts a new step. The app calls it when no
    /// pointer button is held.
    pub fn close_group(&mut self) {
        self.group_open = false;
    }

    /// Applies a view-only edit (camera, size, moving): no undo step.
    pub fn apply_view(&mut self, edit: &SceneEdit) -> Result<(), EditError> {
        edit.apply_to(&mut self.scene)?;
        self.version += 1;
        Ok(())
    }

    pub fn can_undo(&self) -> bool {
        !self.undo.is_empty()
    }
    pub fn can_redo(&self) -> bool {
        !self.redo.is_empty()
    }

    /// Steps back; returns the edits that did it (for the renderer).
    pub fn undo(&mut self) -> Vec<SceneEdit> {
        self.step(true)
    }

    pub fn redo(&mut self) -> Vec<SceneEdit> {
        self.step(false)
    }

    fn step(&mut self, back: bool) -> Vec<SceneEdit> {
        self.group_open = false;
        let (from, to) = if back {
            (&mut self.undo, &mut self.redo)
        } else {
            (&mut self.redo, &mut self.undo)
        };
        let Some(target) = from.pop() else {
            return Vec::new();
        };
        let current = Snapshot::of(&self.scene, &self.pack);
        to.push(current.clone());
        let edits = current.edits_to(&target);
        for e in &edits {
            // Snapshots were valid scenes, so their edits are valid too.
            e.apply_to(&mut self.scene)
                .expect("a snapshot's edits apply to the scene");
        }
        // The edited pack follows; the same file keeps what was saved since.
        self.pack = match (target.pack, &current.pack) {
            (Some(mut t), Some(c)) if t.material == c.material && t.path == c.path => {
                t.saved = Arc::clone(&c.saved);
                Some(t)
            }
            (t, _) => t,
        };
        self.version += 1;
        edits
    }

    /// Whether the edited pack differs from its file (a full comparison unless both
    /// are the same object: callers that ask every frame cache it by `dirty_key`);
    /// a mute or solo alone is not an unsaved change.
    pub fn dirty(&self) -> bool {
        match (&self.pack, self.material()) {
            (Some(p), Some(m)) => !Arc::ptr_eq(&p.saved, &m) && !p.saved.stores_same(&m),
            _ => false,
        }
    }

    /// Changes whenever `dirty()` may change: the edited and the saved pack objects.
    pub fn dirty_key(&self) -> (usize, usize) {
        (
            self.material().map_or(0, |m| Arc::as_ptr(&m) as usize),
            self.pack
                .as_ref()
                .map_or(0, |p| Arc::as_ptr(&p.saved) as usize),
        )
    }

    /// Writes the edited pack to `path` (atomic). On failure nothing changes: the edits
    /// stay in memory and the previous file is intact.
    pub fn save_pack(&mut self, path: &Path) -> Result<(), pack::PackError> {
        let Some(m) = self.material() else {
            return Ok(());
        };
        let p = self.pack.as_mut().expect("material() found the pack");
        pack::write_pack(path, &m, p.precision)?;
        p.path = Some(path.to_path_buf());
        p.saved = m;
        Ok(())
    }

    /// The edit that puts `material` (read from `path`) in place of the edited pack;
    /// the pack's file becomes `path`.
    pub fn install_pack(
        &mut self,
        path: &Path,
        material: Arc<SpmmMaterial>,
        precision: ResidualPrecision,
    ) -> Result<SceneEdit, String> {
        let Some(p) = &self.pack else {
            return Err("the scene has no SPMM material to put a pack on".into());
        };
        let Material::Spmm {
            uv_scale,
            residual,
            npca,
            ..
        } = self.scene.materials[p.material].clone()
        else {
            return Err("the edited material is not an SPMM material".into());
        };
        let edit = SceneEdit::Material {
            index: p.material,
            material: Material::Spmm {
                material: Arc::clone(&material),
                uv_scale,
                residual,
                npca: if npca == 0 { material.npca() } else { npca },
            },
        };
        self.apply(&edit).map_err(|e| e.to_string())?;
        self.close_group();
        let p = self.pack.as_mut().expect("checked above");
        p.path = Some(path.to_path_buf());
        p.precision = precision;
        p.saved = material;
        Ok(edit)
    }
}

impl Document {
    /// Makes the SPMM pack on material slot `index` the edited pack (its file as the
    /// scene named it). Refused while the edited pack has unsaved changes, which would
    /// otherwise no longer be offered for saving. Changes no material, so it is not an
    /// undo step.
    pub fn edit_pack(&mut self, index: usize) -> Result<(), String> {
        let Some(material) = self.scene.materials.get(index).and_then(spmm_of) else {
            return Err(format!("material {index} is not an SPMM pack"));
        };
        if self.dirty() {
            return Err(
                "the edited pack has unsaved changes: save them (File, Save pack) \
                        or undo them before editing another pack"
                    .into(),
            );
        }
        let path = self.scene.material_files.get(index).cloned().flatten();
        let precision = path
            .as_ref()
            .and_then(|f| std::fs::read(f).ok())
            .map_or(ResidualPrecision::F16, |b| pack::residual_precision(&b));
        self.pack = Some(EditedPack {
            material: index,
            path,
            precision,
            saved: material,
        });
        Ok(())
    }

    /// Puts `material` (read from `path`) on material slot `index`, as one undo step:
    /// an SPMM pack becomes the edited pack (its file `path`); another kind put on the
    /// edited pack's slot leaves no pack to edit. Returns the edit for the renderer.
    pub fn assign(
        &mut self,
        index: usize,
        material: Material,
        path: &Path,
        precision: ResidualPrecision,
    ) -> Result<SceneEdit, String> {
        let edit = SceneEdit::Material {
            index,
            material: material.clone(),
        };
        self.close_group();
        self.apply(&edit).map_err(|e| e.to_string())?;
        self.close_group();
        match &material {
            Material::Spmm { material: m, .. } => {
                self.pack = Some(EditedPack {
                    material: index,
                    path: Some(path.to_path_buf()),
                    precision,
                    saved: Arc::clone(m),
                })
            }
            _ if self.pack.as_ref().is_some_and(|p| p.material == index) => self.pack = None,
            _ => {}
        }
        Ok(edit)
    }
}

fn spmm_of(m: &Material) -> Option<Arc<SpmmMaterial>> {
    match m {
        Material::Spmm { material, .. } => Some(Arc::clone(material)),
        _ => None,
    }
}

/// Reads and validates a pack file (slow for large packs: run it as a job).
pub fn read_pack_file(path: &Path) -> Result<(Arc<SpmmMaterial>, ResidualPrecision), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("`{}`: {e}", path.display()))?;
    let material = pack::decode_pack(&bytes).map_err(|e| format!("`{}`: {e}", path.display()))?;
    Ok((Arc::new(material), pack::residual_precision(&bytes)))
}
