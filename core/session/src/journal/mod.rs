//! The recovery journal: every edit that reaches a document, appended to a file per
//! session as it happens (docs/formats/journal.md). A file is a magic line then
//! framed records — length, FNV-1a checksum, payload — so a file cut anywhere, or
//! ending in a torn write, reads as every whole record before the cut. The header
//! names the scene file and the edited pack's file (with a hash of its bytes, so a
//! pack changed since is refused, not mis-applied); pack edits are `PackDelta`s, scene
//! edits JSON `SceneRecord`s. The live writer is `writer.rs`; reading, listing and
//! replaying are here and in `crate::recover`.

pub mod records;
pub mod writer;

use std::path::{Path, PathBuf};

use meso_materials::hash::fnv1a64;
use serde::{Deserialize, Serialize};

pub use records::{SceneRecord, Sources};
pub use writer::Journal;

/// The first bytes of every journal file.
pub const MAGIC: &[u8; 8] = b"MESOJRN1";

/// Length (u32) and checksum (u64) before each payload.
const FRAME: usize = 12;

/// Records larger than this are damage, not data (a delta of every texel of the
/// largest pack is far below it).
const MAX_RECORD: usize = 1 << 31;

/// Where a session's pack came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PackFile {
    /// The scene's material slot that holds it.
    pub slot: usize,
    pub path: PathBuf,
    /// FNV-1a 64 of the file's bytes, hexadecimal.
    pub hash: String,
    /// The residual precision it is saved with: f16, f32 or i8.
    pub precision: String,
}

/// The first record of a journal.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub format: u32,
    /// Seconds since the Unix epoch.
    pub started: u64,
    pub pid: u32,
    /// The scene file (absolute), if the scene came from one.
    pub scene: Option<PathBuf>,
    /// The edited pack's file when the journal starts; `None` with `embedded_pack`
    /// when it has none (the pack then follows in the journal).
    pub pack: Option<PackFile>,
    #[serde(default)]
    pub embedded_pack: Option<usize>,
}

/// One record after the header.
#[derive(Clone, Debug, PartialEq)]
pub enum Record {
    /// Part of the state the journal starts from (scene edits made before a save
    /// rebased it): replayed, not counted as an edit.
    Base(SceneRecord),
    /// The camera: replayed, not counted.
    View(SceneRecord),
    /// A scene edit.
    Edit(SceneRecord),
    /// The edited pack (in `slot`) changed by this delta's bytes.
    Pack { slot: usize, delta: Vec<u8> },
    /// The edited pack is now this file's (a pack opened or put on an object).
    File(PackFile),
    /// The edited pack has no file: these are its bytes (`.spmm`, f32).
    Embedded { slot: usize, bytes: Vec<u8> },
    /// An edit the journal could not record (its asset's source is unknown).
    Unrecorded(String),
}

impl Record {
    /// Whether it counts as an edit (`meso recover list`'s `edits`).
    pub fn is_edit(&self) -> bool {
        matches!(
            self,
            Record::Edit(_) | Record::Pack { .. } | Record::File(_) | Record::Unrecorded(_)
        )
    }

    fn encode(&self) -> Vec<u8> {
        let json = |tag: u8, v: &dyn erased::Json| {
            let mut out = vec![tag];
            out.extend(v.to_json());
            out
        };
        match self {
            Record::Base(r) => json(b'B', r),
            Record::View(r) => json(b'V', r),
            Record::Edit(r) => json(b'E', r),
            Record::Pack { slot, delta } => {
                let mut out = vec![b'P'];
                out.extend((*slot as u32).to_le_bytes());
                out.extend_from_slice(delta);
                out
            }
            Record::File(f) => json(b'F', f),
            Record::Embedded { slot, bytes } => {
                let mut out = vec![b'W'];
                out.extend((*slot as u32).to_le_bytes());
                out.extend_from_slice(bytes);
                out
            }
            Record::Unrecorded(what) => json(b'U', what),
        }
    }

    fn decode(payload: &[u8]) -> Result<Self, String> {
        let (&tag, body) = payload.split_first().ok_or("an empty record")?;
        let json = |b: &[u8]| serde_json::from_slice::<SceneRecord>(b).map_err(|e| e.to_string());
        let slot_and = |b: &[u8]| -> Result<(usize, Vec<u8>), String> {
            let (s, rest) = b
                .split_at_checked(4)
                .ok_or("a record too short for its slot")?;
            Ok((
                u32::from_le_bytes(s.try_into().expect("4 bytes")) as usize,
                rest.to_vec(),
            ))
        };
        Ok(match tag {
            b'B' => Record::Base(json(body)?),
            b'V' => Record::View(json(body)?),
            b'E' => Record::Edit(json(body)?),
            b'P' => {
                let (slot, delta) = slot_and(body)?;
                Record::Pack { slot, delta }
            }
            b'F' => Record::File(serde_json::from_slice(body).map_err(|e| e.to_string())?),
            b'W' => {
                let (slot, bytes) = slot_and(body)?;
                Record::Embedded { slot, bytes }
            }
            b'U' => Record::Unrecorded(serde_json::from_slice(body).map_err(|e| e.to_string())?),
            t => return Err(format!("unknown record kind {t:#04x}")),
        })
    }
}

/// JSON bodies of any serializable record part.
mod erased {
    pub trait Json {
        fn to_json(&self) -> Vec<u8>;
    }
    impl<T: serde::Serialize> Json for T {
        fn to_json(&self) -> Vec<u8> {
            serde_json::to_vec(self).expect("records serialize")
        }
    }
}

/// A payload framed for the file.
pub(crate) fn frame(payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(FRAME + payload.len());
    out.extend((payload.len() as u32).to_le_bytes());
    out.extend(fnv1a64(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

pub(crate) fn header_bytes(h: &Header) -> Vec<u8> {
    let mut payload = vec![b'H'];
    payload.extend(serde_json::to_vec(h).expect("headers serialize"));
    frame(&payload)
}

pub(crate) fn record_bytes(r: &Record) -> Vec<u8> {
    frame(&r.encode())
}

/// A journal as read: its header, its whole records, and where it was cut if it ends
/// in a partial or damaged record.
#[derive(Debug)]
pub struct Contents {
    pub header: Header,
    pub records: Vec<Record>,
    /// Byte offset of the first record that could not be read, if any.
    pub cut_at: Option<usize>,
}

impl Contents {
    pub fn edits(&self) -> usize {
        self.records.iter().filter(|r| r.is_edit()).count()
    }

    /// Every pack file the journal names.
    pub fn packs(&self) -> Vec<PathBuf> {
        let mut out: Vec<PathBuf> = self.header.pack.iter().map(|p| p.path.clone()).collect();
        for r in &self.records {
            if let Record::File(f) = r
                && !out.contains(&f.path)
            {
                out.push(f.path.clone());
            }
        }
        out
    }
}

/// Why a journal cannot be read at all.
#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    #[error("`{path}`: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("`{path}` is not a Meso journal: {why}")]
    NotAJournal { path: PathBuf, why: String },
}

/// Reads whole records up to the first cut or damage; only a missing or foreign
/// header is an error.
pub fn parse(path: &Path, bytes: &[u8]) -> Result<Contents, JournalError> {
    let not = |why: &str| JournalError::NotAJournal {
        path: path.to_path_buf(),
        why: why.to_string(),
    };
    let rest = bytes
        .strip_prefix(MAGIC.as_slice())
        .ok_or_else(|| not("it does not start with MESOJRN1"))?;
    let mut at = MAGIC.len();
    let mut payloads = Vec::new();
    let mut cut_at = None;
    let mut rest = rest;
    while !rest.is_empty() {
        let whole = rest.len() >= FRAME && {
            let len = u32::from_le_bytes(rest[..4].try_into().expect("4 bytes")) as usize;
            let sum = u64::from_le_bytes(rest[4..12].try_into().expect("8 bytes"));
            len <= MAX_RECORD
                && rest.len() - FRAME >= len
                && fnv1a64(&rest[FRAME..FRAME + len]) == sum
        };
        if !whole {
            cut_at = Some(at);
            break;
        }
        let len = u32::from_le_bytes(rest[..4].try_into().expect("4 bytes")) as usize;
        payloads.push((at, &rest[FRAME..FRAME + len]));
        at += FRAME + len;
        rest = &rest[FRAME + len..];
    }
    let mut payloads = payloads.into_iter();
    let header = match payloads.next() {
        Some((_, p)) if p.first() == Some(&b'H') => serde_json::from_slice::<Header>(&p[1..])
            .map_err(|e| not(&format!("its header: {e}")))?,
        _ => return Err(not("its header record is missing or cut")),
    };
    let mut records = Vec::new();
    for (offset, p) in payloads {
        match Record::decode(p) {
            Ok(r) => records.push(r),
            Err(_) => {
                cut_at = Some(offset);
                break;
            }
        }
    }
    Ok(Contents {
        header,
        records,
        cut_at,
    })
}

/// Reads a journal file.
pub fn read(path: &Path) -> Result<Contents, JournalError> {
    let bytes = std::fs::read(path).map_err(|source| JournalError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse(path, &bytes)
}

/// The folder that holds session journals: `$MESO_STATE_DIR/sessions`, else
/// `$XDG_STATE_HOME/meso/sessions`, else `~/.local/state/meso/sessions`.
pub fn sessions_dir() -> PathBuf {
    let base = std::env::var_os("MESO_STATE_DIR")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| {
            std::env::var_os("XDG_STATE_HOME")
                .filter(|v| !v.is_empty())
                .map(|d| PathBuf::from(d).join("meso"))
        })
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/state/meso")))
        .unwrap_or_else(|| std::env::temp_dir().join("meso-state"));
    base.join("sessions")
}

/// The journal files in `dir`, oldest first.
pub fn journal_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "journal"))
        .collect();
    files.sort();
    files
}

/// Whether a session still writes the journal (it holds the file's lock).
pub fn is_live(path: &Path) -> bool {
    let Ok(file) = std::fs::File::open(path) else {
        return false;
    };
    match file.try_lock_shared() {
        Ok(()) => {
            let _ = file.unlock();
            false
        }
        Err(std::fs::TryLockError::WouldBlock) => true,
        Err(std::fs::TryLockError::Error(_)) => false,
    }
}

/// Hexadecimal FNV-1a 64 of a file's bytes, as headers write it.
pub fn file_hash(bytes: &[u8]) -> String {
    format!("{:016x}", fnv1a64(bytes))
}
