//! The document the editor edits: the scene as edited so far (its own copy, changed by
//! the same `SceneEdit::apply_to` the renderer uses), the SPMM pack being edited and
//! where it lives on disk, a version bumped by every edit, and undo/redo.
//!
//! Undo keeps what edits change (`undo.rs`: lights, ambient, environment, background,
//! materials, an edited pack as a delta) under a memory budget, grouped so that one
//! slider drag is one step. Undoing replays the difference as ordinary edits, so the
//! renderer restarts only what changed. The camera is a view, not an edit: it is not
//! undone. With a journal folder (`journal_to`), every edit is also journaled
//! (`journal/`): the journal starts at the first edit after the document opens or is
//! saved clean, and a clean save or close removes it.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::SystemTime;

use meso_materials::spmm::SpmmMaterial;
use meso_materials::spmm::pack::{self, ResidualPrecision};
use meso_render::scene::{Ambient, Background, Environment, Light, Material, Scene};
use meso_render::{EditError, SceneEdit};

use crate::journal::records::{self, Opened, RecordContext, SceneRecord, Sources};
use crate::journal::writer::Start;
use crate::journal::{self, Header, Journal, PackFile, Record};
use crate::undo::{self, History, Step};

/// What undo restores.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// Which material is the edited pack, and its file (a library assignment moves it).
    pub(crate) pack: Option<EditedPack>,
    pub(crate) materials: Vec<Material>,
    pub(crate) lights: Vec<Light>,
    pub(crate) ambient: Option<Ambient>,
    pub(crate) environment: Option<Environment>,
    pub(crate) background: Background,
    pub(crate) light_samples: u32,
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
    pub(crate) fn of(scene: &Scene, pack: &Option<EditedPack>) -> Self {
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
    pub(crate) fn edits_to(&self, target: &Snapshot) -> Vec<SceneEdit> {
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

/// A pack file as the document last read or wrote it, to tell whether another
/// program changed it since.
#[derive(Clone, Debug, PartialEq)]
pub struct DiskState {
    /// FNV-1a 64 of its bytes (hexadecimal), as journal headers name it.
    pub hash: String,
    len: u64,
    modified: Option<SystemTime>,
}

impl DiskState {
    fn of(path: &Path, bytes: &[u8]) -> Self {
        Self {
            hash: journal::file_hash(bytes),
            len: bytes.len() as u64,
            modified: std::fs::metadata(path).and_then(|m| m.modified()).ok(),
        }
    }

    /// Whether `path` still holds these bytes: the same size and time, or else the
    /// same hash (a file touched but not changed is the same). A missing file differs.
    fn still_at(&self, path: &Path) -> bool {
        let Ok(meta) = std::fs::metadata(path) else {
            return false;
        };
        if meta.len() == self.len && meta.modified().ok() == self.modified {
            return true;
        }
        std::fs::read(path).is_ok_and(|b| journal::file_hash(&b) == self.hash)
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
    /// Its file as last read or written (`None`: no file, or it could not be read).
    disk: Option<DiskState>,
}

impl EditedPack {
    fn read(material: usize, path: Option<PathBuf>, saved: Arc<SpmmMaterial>) -> Self {
        let bytes = path.as_ref().and_then(|f| std::fs::read(f).ok());
        Self {
            material,
            precision: bytes
                .as_ref()
                .map_or(ResidualPrecision::F16, |b| pack::residual_precision(b)),
            disk: path
                .as_ref()
                .zip(bytes.as_ref())
                .map(|(p, b)| DiskState::of(p, b)),
            path,
            saved,
        }
    }

    pub(crate) fn file_record(&self) -> Option<PackFile> {
        Some(PackFile {
            slot: self.material,
            path: absolute(self.path.as_ref()?),
            hash: self.disk.as_ref()?.hash.clone(),
            precision: self.precision.name().to_string(),
        })
    }
}

fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

/// Why a save did not happen; the edits and the file on disk are both intact.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SaveError {
    #[error(
        "`{0}` changed on disk since it was opened (another program wrote it): reload it, overwrite it, or save as another file"
    )]
    ChangedOnDisk(PathBuf),
    #[error("saving failed, the edits are kept: {0}")]
    Write(String),
}

/// Writes a pack's bytes to a path whole or not at all (tests inject failures).
pub type PackWriter = dyn Fn(&Path, &[u8]) -> Result<(), String> + Send;

fn atomic_writer() -> Box<PackWriter> {
    Box::new(|path, bytes| {
        meso_materials::atomic::write_bytes_atomic(path, bytes).map_err(|e| e.to_string())
    })
}

/// How much undo holds (`Document::undo_stats`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UndoStats {
    pub steps: usize,
    pub redo_steps: usize,
    pub bytes: usize,
    pub budget: usize,
    /// Oldest steps dropped to stay within the budget.
    pub dropped: usize,
}

/// The edited pack's settings in its scene slot and which object it is.
#[derive(Clone, Debug, PartialEq)]
struct PackState {
    slot: usize,
    path: Option<PathBuf>,
    material: Arc<SpmmMaterial>,
    settings: (glam::DVec2, bool, usize),
}

pub struct Document {
    pub scene: Scene,
    pub scene_path: Option<PathBuf>,
    pub pack: Option<EditedPack>,
    /// Bumped by every applied edit.
    pub version: u64,
    history: History,
    /// The state before the open undo group (a drag in progress), if one is open.
    open_group: Option<Snapshot>,
    /// The state the scene file gave, what journal records name as the scene's.
    opened: Snapshot,
    opened_assets: Opened,
    sources: Sources,
    journal_dir: Option<PathBuf>,
    journal: Option<Journal>,
    /// Why the journal could not be started, shown by the editor.
    journal_error: Option<String>,
    writer: Box<PackWriter>,
}

impl Document {
    pub fn new(scene: Scene, scene_path: Option<PathBuf>) -> Self {
        let pack = scene
            .materials
            .iter()
            .position(|m| matches!(m, Material::Spmm { .. }))
            .map(|i| {
                EditedPack::read(
                    i,
                    scene.material_files.get(i).cloned().flatten(),
                    spmm_of(&scene.materials[i]).expect("position found an SPMM material"),
                )
            });
        let budget = std::env::var("MESO_UNDO_BUDGET_MB")
            .ok()
            .and_then(|v| v.trim().parse::<usize>().ok())
            .map_or(undo::DEFAULT_BUDGET, |mb| mb << 20);
        Self {
            opened: Snapshot::of(&scene, &pack),
            opened_assets: Opened::of(&scene),
            scene,
            scene_path,
            pack,
            version: 1,
            history: History::new(budget),
            open_group: None,
            sources: Sources::default(),
            journal_dir: None,
            journal: None,
            journal_error: None,
            writer: atomic_writer(),
        }
    }

    /// Journals every edit from now on in `dir` (`journal::sessions_dir()` in the
    /// studio); the journal file starts at the first edit.
    pub fn journal_to(&mut self, dir: &Path) {
        self.journal_dir = Some(dir.to_path_buf());
    }

    /// The journal being written, if an edit started one.
    pub fn journal(&self) -> Option<&Journal> {
        self.journal.as_ref()
    }

    /// Why journaling fails, if it does (shown until it works again).
    pub fn journal_error(&self) -> Option<String> {
        self.journal_error
            .clone()
            .or_else(|| self.journal.as_ref().and_then(|j| j.status().error))
    }

    /// Ends the session's journal: removed (the user saved or chose to discard), or
    /// kept for `meso recover`.
    pub fn close_journal(&mut self, remove: bool) {
        if let Some(j) = self.journal.take() {
            j.close(remove);
        }
    }

    /// Replaces how packs are written (tests inject full disks).
    pub fn set_pack_writer(&mut self, writer: Box<PackWriter>) {
        self.writer = writer;
    }

    /// Notes that `asset` (an environment map, a measured BRDF) was read from
    /// `path`, so the journal can name it.
    pub fn note_source<T: std::any::Any + Send + Sync>(&mut self, asset: &Arc<T>, path: &Path) {
        self.sources.note(asset, &absolute(path));
    }

    pub fn set_undo_budget(&mut self, bytes: usize) {
        self.history.set_budget(bytes);
    }

    pub fn undo_stats(&self) -> UndoStats {
        UndoStats {
            steps: self.history.undo_len() + usize::from(self.open_group.is_some()),
            redo_steps: self.history.redo_len(),
            bytes: self.history.bytes(),
            budget: self.history.budget(),
            dropped: self.history.dropped,
        }
    }

    /// The edited pack's material, if the scene has one.
    pub fn material(&self) -> Option<Arc<SpmmMaterial>> {
        self.pack
            .as_ref()
            .and_then(|p| spmm_of(&self.scene.materials[p.material]))
    }

    fn pack_state(&self) -> Option<PackState> {
        let p = self.pack.as_ref()?;
        match &self.scene.materials[p.material] {
            Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            } => Some(PackState {
                slot: p.material,
                path: p.path.clone(),
                material: Arc::clone(material),
                settings: (*uv_scale, *residual, *npca),
            }),
            _ => None,
        }
    }

    /// Applies an edit as part of the open undo group (opening one if none is).
    pub fn apply(&mut self, edit: &SceneEdit) -> Result<(), EditError> {
        self.begin_journal();
        let before = self.pack_state();
        let snapshot = self
            .open_group
            .is_none()
            .then(|| Snapshot::of(&self.scene, &self.pack));
        edit.apply_to(&mut self.scene)?;
        if let Some(s) = snapshot {
            self.history.clear_redo();
            self.open_group = Some(s);
        }
        self.version += 1;
        self.journal_after(std::slice::from_ref(edit), before);
        Ok(())
    }

    /// Ends the undo group: the next edit starts a new step. The app calls it when no
    /// pointer button is held.
    pub fn close_group(&mut self) {
        if let Some(before) = self.open_group.take() {
            let now = Snapshot::of(&self.scene, &self.pack);
            self.history.push(Step::compact(before, &now));
            if let Some(j) = &self.journal {
                j.seal();
            }
        }
    }

    /// Applies a view-only edit (camera, size, moving): no undo step; a camera is
    /// journaled (if a journal runs) so a restore shows the same view.
    pub fn apply_view(&mut self, edit: &SceneEdit) -> Result<(), EditError> {
        edit.apply_to(&mut self.scene)?;
        self.version += 1;
        if self.journal.is_some() {
            let before = self.pack_state();
            self.journal_after(std::slice::from_ref(edit), before);
        }
        Ok(())
    }

    pub fn can_undo(&self) -> bool {
        self.history.undo_len() > 0 || self.open_group.is_some()
    }
    pub fn can_redo(&self) -> bool {
        self.history.redo_len() > 0
    }

    /// Steps back; returns the edits that did it (for the renderer).
    pub fn undo(&mut self) -> Vec<SceneEdit> {
        self.step(true)
    }

    pub fn redo(&mut self) -> Vec<SceneEdit> {
        self.step(false)
    }

    fn step(&mut self, back: bool) -> Vec<SceneEdit> {
        self.close_group();
        let popped = if back {
            self.history.pop_undo()
        } else {
            self.history.pop_redo()
        };
        let Some(step) = popped else {
            return Vec::new();
        };
        self.begin_journal();
        let before = self.pack_state();
        let current = Snapshot::of(&self.scene, &self.pack);
        let target = step.expand(&current);
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
                t.disk = c.disk.clone();
                Some(t)
            }
            (t, _) => t,
        };
        let now = Snapshot::of(&self.scene, &self.pack);
        let kept = Step::compact(current, &now);
        if back {
            self.history.push_redo(kept);
        } else {
            self.history.push_undo_keeping_redo(kept);
        }
        self.version += 1;
        self.journal_after(&edits, before);
        if let Some(j) = &self.journal {
            j.seal();
        }
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

    /// The edited pack's file, if another program changed it since the document last
    /// read or wrote it.
    pub fn pack_changed_on_disk(&self) -> Option<PathBuf> {
        let p = self.pack.as_ref()?;
        let (path, disk) = (p.path.as_ref()?, p.disk.as_ref()?);
        (!disk.still_at(path)).then(|| path.clone())
    }

    /// Writes the edited pack to `path` (atomic), refusing to overwrite its own file
    /// if another program changed it since (`save_pack_over` does). On failure
    /// nothing changes: the edits stay in memory (and in the journal) and the file
    /// on disk is intact.
    pub fn save_pack(&mut self, path: &Path) -> Result<(), SaveError> {
        if let Some(p) = &self.pack
            && p.path.as_deref().map(absolute) == Some(absolute(path))
            && p.disk.as_ref().is_some_and(|d| !d.still_at(path))
        {
            return Err(SaveError::ChangedOnDisk(path.to_path_buf()));
        }
        self.save_pack_over(path)
    }

    /// `save_pack` without the check: the user chose to overwrite.
    pub fn save_pack_over(&mut self, path: &Path) -> Result<(), SaveError> {
        let Some(m) = self.material() else {
            return Ok(());
        };
        let precision = self
            .pack
            .as_ref()
            .expect("material() found the pack")
            .precision;
        let bytes = pack::encode_pack(&m, precision);
        (self.writer)(path, &bytes).map_err(SaveError::Write)?;
        let p = self.pack.as_mut().expect("material() found the pack");
        p.path = Some(path.to_path_buf());
        p.saved = Arc::clone(&m);
        p.disk = Some(DiskState::of(path, &bytes));
        self.sources.note(&m, &absolute(path));
        self.after_save();
        Ok(())
    }

    /// A save leaves the journal with only what is still unsaved: nothing (it is
    /// removed) or the scene edits, which no file holds (it starts again from them).
    fn after_save(&mut self) {
        if self.journal.is_none() {
            return;
        }
        let start = self.journal_start();
        if start.base.is_empty() && !self.dirty() {
            self.close_journal(true);
        } else if let Some(j) = &self.journal {
            j.rebase(start);
        }
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
        self.sources.note(&material, &absolute(path));
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
        let slot = self.pack.as_ref().expect("checked above").material;
        self.pack = Some(EditedPack {
            precision,
            ..EditedPack::read(slot, Some(path.to_path_buf()), material)
        });
        self.journal_pack_file();
        Ok(edit)
    }

    /// Reads the edited pack's file again, in place of the edits (one undo step, so
    /// they can be brought back).
    pub fn reload_pack(&mut self) -> Result<SceneEdit, String> {
        let path = self
            .pack
            .as_ref()
            .and_then(|p| p.path.clone())
            .ok_or("the edited pack has no file")?;
        let (material, precision) = read_pack_file(&path)?;
        self.install_pack(&path, material, precision)
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
        self.pack = Some(EditedPack::read(index, path, material));
        self.journal_pack_file();
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
        match &material {
            Material::Spmm { material: m, .. } => self.sources.note(m, &absolute(path)),
            Material::Merl { brdf, .. } => self.sources.note(brdf, &absolute(path)),
            _ => {}
        }
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
                    precision,
                    ..EditedPack::read(index, Some(path.to_path_buf()), Arc::clone(m))
                });
                self.journal_pack_file();
            }
            _ if self.pack.as_ref().is_some_and(|p| p.material == index) => self.pack = None,
            _ => {}
        }
        Ok(edit)
    }
}

// ---- the journal ----

impl Document {
    /// The state a journal starts from: the header (scene file, the edited pack's
    /// file), the scene edits since the file as base records, and the pack as its
    /// file holds it.
    fn journal_start(&self) -> Start {
        let now = Snapshot::of(&self.scene, &self.pack);
        let ctx = RecordContext {
            opened: &self.opened_assets,
            sources: &self.sources,
            edited_slot: self.pack.as_ref().map(|p| p.material),
        };
        // The edited pack's content is the header's file; its slot needs a record
        // only for settings the scene file did not give.
        let settings = |m: &Material| match m {
            Material::Spmm {
                uv_scale,
                residual,
                npca,
                ..
            } => Some((*uv_scale, *residual, *npca)),
            _ => None,
        };
        let mut base: Vec<Record> = self
            .opened
            .edits_to(&now)
            .iter()
            .filter(|e| match e {
                SceneEdit::Material { index, material } if ctx.edited_slot == Some(*index) => {
                    settings(material).is_none()
                        || settings(material)
                            != self.opened.materials.get(*index).and_then(settings)
                }
                _ => true,
            })
            .map(|e| match records::record_of(e, &ctx) {
                Ok(Some(r)) => Record::Base(r),
                Ok(None) => unreachable!("snapshot differences are document edits"),
                Err(what) => Record::Unrecorded(what),
            })
            .collect();
        if self.scene.camera != self.opened_assets.camera
            && let Ok(Some(r)) = records::record_of(&SceneEdit::Camera(self.scene.camera), &ctx)
        {
            base.push(Record::View(r));
        }
        let file = self.pack.as_ref().and_then(EditedPack::file_record);
        let embedded = match (&self.pack, &file) {
            (Some(p), None) => Some(p.material),
            _ => None,
        };
        let pack = self.pack.as_ref().map(|p| {
            let m = if file.is_some() {
                Arc::clone(&p.saved)
            } else {
                self.material()
                    .expect("the edited pack is an SPMM material")
            };
            (p.material, m)
        });
        Start {
            header: Header {
                format: 1,
                started: SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_secs()),
                pid: std::process::id(),
                scene: self.scene_path.as_deref().map(absolute),
                pack: file,
                embedded_pack: embedded,
            },
            base,
            pack,
        }
    }

    /// Starts the journal at the first edit, if the document journals.
    fn begin_journal(&mut self) {
        if self.journal.is_some() {
            return;
        }
        let Some(dir) = self.journal_dir.clone() else {
            return;
        };
        let start = self.journal_start();
        let base_pack = start.pack.clone();
        match Journal::create(&dir, start) {
            Ok(j) => {
                if let (Some((slot, base)), Some(m)) = (base_pack, self.material())
                    && !Arc::ptr_eq(&base, &m)
                {
                    j.pack(slot, m);
                }
                self.journal = Some(j);
                self.journal_error = None;
            }
            Err(e) => self.journal_error = Some(e),
        }
    }

    /// Journals `edits`, just applied: scene edits as records, the edited pack's
    /// settings when they changed, its new content as a delta, and a switch to
    /// another pack file as a file record.
    fn journal_after(&mut self, edits: &[SceneEdit], before: Option<PackState>) {
        let Some(j) = &self.journal else { return };
        let now = self.pack_state();
        let same_pack = |a: &Option<PackState>, b: &Option<PackState>| match (a, b) {
            (Some(a), Some(b)) => a.slot == b.slot && a.path == b.path,
            (None, None) => true,
            _ => false,
        };
        if !same_pack(&before, &now) {
            self.journal_pack_file();
        }
        let ctx = RecordContext {
            opened: &self.opened_assets,
            sources: &self.sources,
            edited_slot: now.as_ref().map(|p| p.slot),
        };
        for e in edits {
            if let (SceneEdit::Material { index, .. }, Some(p)) = (e, &now)
                && *index == p.slot
                && before.as_ref().is_some_and(|b| b.settings == p.settings)
            {
                continue; // only the content changed: the delta below says it
            }
            match records::record_of(e, &ctx) {
                Ok(Some(r @ SceneRecord::Camera { .. })) => j.record(Record::View(r)),
                Ok(Some(r)) => j.record(Record::Edit(r)),
                Ok(None) => {}
                Err(what) => j.record(Record::Unrecorded(what)),
            }
        }
        if let Some(p) = now
            && before.is_none_or(|b| !Arc::ptr_eq(&b.material, &p.material))
        {
            j.pack(p.slot, p.material);
        }
    }

    /// Tells the journal the edited pack is now its file's (or, with no file, its
    /// whole content).
    fn journal_pack_file(&self) {
        let (Some(j), Some(p)) = (&self.journal, &self.pack) else {
            return;
        };
        match p.file_record() {
            Some(f) => j.pack_file(f, Arc::clone(&p.saved)),
            None => {
                if let Some(m) = self.material() {
                    j.embed(p.material, m);
                }
            }
        }
        if let Some(m) = self.material() {
            j.pack(p.material, m);
        }
    }

    /// Makes the pack on `slot` (read from `path`) the edited pack.
    pub(crate) fn set_edited_pack(
        &mut self,
        slot: usize,
        path: &Path,
        material: Arc<SpmmMaterial>,
        precision: ResidualPrecision,
    ) {
        self.sources.note(&material, &absolute(path));
        self.pack = Some(EditedPack {
            precision,
            ..EditedPack::read(slot, Some(path.to_path_buf()), material)
        });
        self.journal_pack_file();
    }

    /// The scene file's state and what journal records name as the scene's.
    pub fn opened(&self) -> &Opened {
        &self.opened_assets
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
