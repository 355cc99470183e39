//! Reading journals back: the sessions a folder holds (`meso recover list`, the
//! studio's offer at start), the edited pack a journal ends with (`meso recover
//! apply`), a journal replayed into a freshly opened document (the studio's
//! restore), and discarding one. A pack file that changed since the journal named it
//! is refused by its hash, never patched.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::UNIX_EPOCH;

use glam::DVec2;
use meso_materials::spmm::pack::{self, ResidualPrecision};
use meso_materials::spmm::{PackDelta, SpmmMaterial, Step};
use meso_render::SceneEdit;
use meso_render::scene::Material;
use serde::Serialize;

use crate::document::{Document, EditedPack};
use crate::journal::records::{self, ReplayContext};
use crate::journal::{self, Contents, PackFile, Record};

/// A pack's settings in its scene slot: uv scale, residual on, PCA terms.
type PackSettings = (DVec2, bool, usize);

/// One session as `meso recover list --json` prints it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Session {
    pub journal: PathBuf,
    pub scene: Option<PathBuf>,
    pub packs: Vec<PathBuf>,
    pub edits: usize,
    /// UTC, `YYYY-MM-DDTHH:MM:SSZ`.
    pub started: String,
    /// When the journal was last written (UTC).
    pub last_edit: String,
    /// The session is still running (it holds the journal's lock).
    pub live: bool,
}

/// The sessions journaled in `dir`, oldest first, and the files there that could not
/// be read as journals (with why).
pub fn list(dir: &Path) -> (Vec<Session>, Vec<String>) {
    let mut sessions = Vec::new();
    let mut unreadable = Vec::new();
    for path in journal::journal_files(dir) {
        match journal::read(&path) {
            Ok(c) => {
                let modified = std::fs::metadata(&path)
                    .and_then(|m| m.modified())
                    .ok()
                    .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
                    .map_or(c.header.started, |d| d.as_secs());
                sessions.push(Session {
                    live: journal::is_live(&path),
                    scene: c.header.scene.clone(),
                    packs: c.packs(),
                    edits: c.edits(),
                    started: meso_materials::utc::from_unix(c.header.started),
                    last_edit: meso_materials::utc::from_unix(modified),
                    journal: path,
                });
            }
            Err(e) => unreadable.push(e.to_string()),
        }
    }
    (sessions, unreadable)
}

/// Sessions that ended without saving and have edits to restore.
pub fn restorable(dir: &Path) -> Vec<Session> {
    list(dir)
        .0
        .into_iter()
        .filter(|s| !s.live && s.edits > 0)
        .collect()
}

/// Removes a journal; refused while its session is running.
pub fn discard(path: &Path) -> Result<(), String> {
    journal::read(path).map_err(|e| e.to_string())?;
    if journal::is_live(path) {
        return Err(format!(
            "`{}` belongs to a running session: close that studio first",
            path.display()
        ));
    }
    std::fs::remove_file(path).map_err(|e| format!("`{}`: {e}", path.display()))
}

fn precision_named(name: &str) -> ResidualPrecision {
    match name {
        "f32" => ResidualPrecision::F32,
        "i8" => ResidualPrecision::I8,
        _ => ResidualPrecision::F16,
    }
}

/// Reads the pack a file record names, checking it is still the file journaled.
fn read_checked(f: &PackFile) -> Result<(Arc<SpmmMaterial>, ResidualPrecision), String> {
    let bytes = std::fs::read(&f.path).map_err(|e| format!("`{}`: {e}", f.path.display()))?;
    let hash = journal::file_hash(&bytes);
    if hash != f.hash {
        return Err(format!(
            "`{}` changed since the session journaled it (hash {hash}, journaled {}): its edits cannot be applied to another file",
            f.path.display(),
            f.hash
        ));
    }
    let m = pack::decode_pack(&bytes).map_err(|e| format!("`{}`: {e}", f.path.display()))?;
    Ok((Arc::new(m), precision_named(&f.precision)))
}

fn embedded(bytes: &[u8]) -> Result<Arc<SpmmMaterial>, String> {
    pack::decode_pack(bytes)
        .map(Arc::new)
        .map_err(|e| format!("the journal's embedded pack: {e}"))
}

fn stepped(m: &SpmmMaterial, delta: &[u8], at: usize) -> Result<SpmmMaterial, String> {
    PackDelta::decode(delta)
        .and_then(|d| m.stepped(&d, Step::Forward))
        .map_err(|e| format!("pack edit {at}: {e}"))
}

/// The edited pack as the journal ends with it, and the precision to write it with.
pub fn pack_of(c: &Contents) -> Result<(Arc<SpmmMaterial>, ResidualPrecision), String> {
    let mut current: Option<(usize, Arc<SpmmMaterial>, ResidualPrecision)> = match &c.header.pack {
        Some(f) => {
            let (m, p) = read_checked(f)?;
            Some((f.slot, m, p))
        }
        None => None,
    };
    for (i, r) in c.records.iter().enumerate() {
        match r {
            Record::File(f) => {
                let (m, p) = read_checked(f)?;
                current = Some((f.slot, m, p));
            }
            Record::Embedded { slot, bytes } => {
                let p = current.as_ref().map_or(ResidualPrecision::F16, |c| c.2);
                current = Some((*slot, embedded(bytes)?, p));
            }
            Record::Pack { slot, delta } => {
                let (s, m, p) = current
                    .take()
                    .ok_or_else(|| format!("record {}: a pack edit before any pack", i + 1))?;
                if s != *slot {
                    return Err(format!(
                        "record {}: a pack edit of material {slot}, but the edited pack is material {s}",
                        i + 1
                    ));
                }
                current = Some((s, Arc::new(stepped(&m, delta, i + 1)?), p));
            }
            _ => {}
        }
    }
    current
        .map(|(_, m, p)| (m, p))
        .ok_or_else(|| "the journal edits no pack".to_string())
}

/// What a replay brought back.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Replayed {
    /// Records replayed.
    pub records: usize,
    /// Edits the journal could not record, by name (nothing to replay).
    pub lost: Vec<String>,
    /// The journal ended in a cut record (a crash mid-write): what came before it
    /// was replayed.
    pub cut: bool,
}

impl Document {
    /// Replays a journal into this document, freshly opened from the journal's scene
    /// file, as one undo step (undoing it gives the files' state back). The edits
    /// go through `apply` like any other, so they are journaled again.
    pub fn replay(&mut self, c: &Contents) -> Result<Replayed, String> {
        let mut out = Replayed {
            cut: c.cut_at.is_some(),
            ..Default::default()
        };
        self.close_group();
        if let Some(f) = &c.header.pack {
            let here = self.pack.as_ref().and_then(EditedPack::file_record);
            if here.as_ref() != Some(f) {
                self.replay_file(f)?;
            }
        }
        for (i, r) in c.records.iter().enumerate() {
            let at = |e: String| format!("journal record {}: {e}", i + 1);
            match r {
                Record::Base(s) | Record::Edit(s) | Record::View(s) => {
                    let ctx = ReplayContext {
                        opened: self.opened(),
                        edited_pack: self.material(),
                    };
                    let edit = records::edit_of(s, &ctx).map_err(at)?;
                    let applied = if matches!(r, Record::View(_)) {
                        self.apply_view(&edit)
                    } else {
                        self.apply(&edit)
                    };
                    applied.map_err(|e| at(e.to_string()))?;
                }
                Record::Pack { slot, delta } => {
                    let (m, settings) = self.spmm_at(*slot).map_err(at)?;
                    let next = stepped(&m, delta, i + 1)?;
                    self.put(*slot, Arc::new(next), settings).map_err(at)?;
                }
                Record::File(f) => self.replay_file(f).map_err(at)?,
                Record::Embedded { slot, bytes } => {
                    let m = embedded(bytes).map_err(at)?;
                    let settings = self
                        .spmm_at(*slot)
                        .map_or((DVec2::new(4.0, 4.0), true, m.npca()), |s| s.1);
                    self.put(*slot, m, settings).map_err(at)?;
                }
                Record::Unrecorded(what) => out.lost.push(what.clone()),
            }
            out.records += 1;
        }
        self.close_group();
        Ok(out)
    }

    /// The SPMM material on `slot` with its settings.
    fn spmm_at(&self, slot: usize) -> Result<(Arc<SpmmMaterial>, PackSettings), String> {
        match self.scene.materials.get(slot) {
            Some(Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            }) => Ok((Arc::clone(material), (*uv_scale, *residual, *npca))),
            _ => Err(format!("material {slot} is not an SPMM pack")),
        }
    }

    fn put(
        &mut self,
        slot: usize,
        material: Arc<SpmmMaterial>,
        (uv_scale, residual, npca): PackSettings,
    ) -> Result<(), String> {
        self.apply(&SceneEdit::Material {
            index: slot,
            material: Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            },
        })
        .map_err(|e| e.to_string())
    }

    /// The edited pack becomes the file a record names (checked by its hash).
    fn replay_file(&mut self, f: &PackFile) -> Result<(), String> {
        let (m, precision) = read_checked(f)?;
        let settings = self
            .spmm_at(f.slot)
            .map_or((DVec2::new(4.0, 4.0), true, m.npca()), |s| s.1);
        self.put(f.slot, Arc::clone(&m), settings)?;
        self.set_edited_pack(f.slot, &f.path, m, precision);
        Ok(())
    }
}
