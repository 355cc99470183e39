//! The live journal of one session: a thread that owns the file (locked, so others
//! see the session is live), turns the edited pack's newest state into a delta from
//! the state it last wrote, and writes what came in within a quarter of a second,
//! synced to the disk. The editor never waits for it: a message costs an `Arc`
//! clone. A write that fails (a full disk) is rolled back to the last whole record
//! and tried again with the next batch; the error is shown meanwhile.

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use meso_materials::spmm::SpmmMaterial;
use meso_materials::spmm::pack::{self, ResidualPrecision};

use super::{Header, MAGIC, PackFile, Record, header_bytes, record_bytes};

/// How long an edit may wait before it is on the disk.
pub const WRITE_WITHIN: Duration = Duration::from_millis(250);

enum Msg {
    Record(Record),
    Pack {
        slot: usize,
        material: Arc<SpmmMaterial>,
    },
    /// The edited pack is now this file's (`material` is its content).
    File(PackFile, Arc<SpmmMaterial>),
    /// The edited pack has no file: its whole content.
    Embed(usize, Arc<SpmmMaterial>),
    Rebase(Box<Start>),
    /// An undo step ended: the pack's state so far is one record.
    Seal,
    Flush(Sender<Result<(), String>>),
    Close {
        remove: bool,
        done: Sender<()>,
    },
}

/// What a journal starts from: its header, base records, and the edited pack as the
/// header's file holds it (deltas are taken from it).
pub struct Start {
    pub header: Header,
    pub base: Vec<Record>,
    pub pack: Option<(usize, Arc<SpmmMaterial>)>,
}

/// What the editor may show about its journal.
#[derive(Clone, Debug, Default)]
pub struct JournalStatus {
    /// Edits written since the journal (re)started.
    pub edits: usize,
    /// The last write error, cleared by the next write that succeeds.
    pub error: Option<String>,
}

/// A session's journal while the session lives.
pub struct Journal {
    path: PathBuf,
    tx: Sender<Msg>,
    thread: Option<JoinHandle<()>>,
    status: Arc<Mutex<JournalStatus>>,
}

impl Journal {
    /// Starts a journal in `dir` (created if missing), named by its start time and
    /// process id.
    pub fn create(dir: &Path, start: Start) -> Result<Journal, String> {
        std::fs::create_dir_all(dir).map_err(|e| format!("`{}`: {e}", dir.display()))?;
        let mut name = format!("{}-{}", start.header.started, start.header.pid);
        let mut n = 1;
        while dir.join(format!("{name}.journal")).exists() {
            n += 1;
            name = format!("{}-{}-{n}", start.header.started, start.header.pid);
        }
        let path = dir.join(format!("{name}.journal"));
        let (file, embedded) = write_start(&path, &start)?;
        let status = Arc::new(Mutex::new(JournalStatus::default()));
        let (tx, rx) = mpsc::channel();
        let mut w = Writer {
            path: path.clone(),
            file,
            good_len: embedded,
            base: start.pack,
            pending: None,
            buffer: Vec::new(),
            buffered_edits: 0,
            since: None,
            status: Arc::clone(&status),
        };
        let thread = std::thread::Builder::new()
            .name("meso-journal".into())
            .spawn(move || w.run(&rx))
            .map_err(|e| format!("cannot start the journal's thread: {e}"))?;
        Ok(Journal {
            path,
            tx,
            thread: Some(thread),
            status,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn status(&self) -> JournalStatus {
        self.status.lock().expect("journal status").clone()
    }

    pub fn record(&self, record: Record) {
        let _ = self.tx.send(Msg::Record(record));
    }

    /// The edited pack (in `slot`) as it is now; written as a delta.
    pub fn pack(&self, slot: usize, material: Arc<SpmmMaterial>) {
        let _ = self.tx.send(Msg::Pack { slot, material });
    }

    /// The edited pack is now `file`'s, whose content is `material`.
    pub fn pack_file(&self, file: PackFile, material: Arc<SpmmMaterial>) {
        let _ = self.tx.send(Msg::File(file, material));
    }

    /// The edited pack, without a file, is now `material` whole.
    pub fn embed(&self, slot: usize, material: Arc<SpmmMaterial>) {
        let _ = self.tx.send(Msg::Embed(slot, material));
    }

    /// Ends an edit (an undo step): the pack's changes so far become one record,
    /// and the next edit's start a new one. Within a step (a drag) they merge.
    pub fn seal(&self) {
        let _ = self.tx.send(Msg::Seal);
    }

    /// Starts the journal again from `start` (after a save): the file is replaced
    /// whole, atomically.
    pub fn rebase(&self, start: Start) {
        let _ = self.tx.send(Msg::Rebase(Box::new(start)));
    }

    /// Waits until everything sent so far is on the disk.
    pub fn flush(&self) -> Result<(), String> {
        let (ack, done) = mpsc::channel();
        self.tx
            .send(Msg::Flush(ack))
            .map_err(|_| "the journal's thread has stopped".to_string())?;
        done.recv()
            .map_err(|_| "the journal's thread has stopped".to_string())?
    }

    /// Ends the session: `remove` deletes the journal (a clean save or quit), else
    /// it is written out and left for recovery.
    pub fn close(mut self, remove: bool) {
        self.finish(remove);
    }

    fn finish(&mut self, remove: bool) {
        if let Some(t) = self.thread.take() {
            let (done, wait) = mpsc::channel();
            if self.tx.send(Msg::Close { remove, done }).is_ok() {
                let _ = wait.recv();
            }
            let _ = t.join();
        }
    }
}

impl Drop for Journal {
    /// A journal dropped without `close` is kept: the session did not end cleanly.
    fn drop(&mut self) {
        self.finish(false);
    }
}

/// Writes a new journal file (magic, header, base records, the pack's bytes when it
/// has no file) to a temporary beside `path`, locks it and renames it into place.
fn write_start(path: &Path, start: &Start) -> Result<(File, u64), String> {
    let named = |e: std::io::Error| format!("journal `{}`: {e}", path.display());
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut bytes = MAGIC.to_vec();
    bytes.extend(header_bytes(&start.header));
    if let (Some(slot), Some((_, m))) = (start.header.embedded_pack, &start.pack) {
        bytes.extend(record_bytes(&Record::Embedded {
            slot,
            bytes: pack::encode_pack(m, ResidualPrecision::F32),
        }));
    }
    for r in &start.base {
        bytes.extend(record_bytes(r));
    }
    let mut temp = tempfile::Builder::new()
        .prefix(".meso-journal-")
        .tempfile_in(dir)
        .map_err(named)?;
    temp.write_all(&bytes).map_err(named)?;
    temp.as_file().sync_all().map_err(named)?;
    temp.as_file()
        .try_lock()
        .map_err(|e| named(std::io::Error::other(e.to_string())))?;
    let mut file = temp.persist(path).map_err(|e| named(e.error))?;
    file.seek(SeekFrom::End(0)).map_err(named)?;
    Ok((file, bytes.len() as u64))
}

struct Writer {
    path: PathBuf,
    file: File,
    /// Bytes of whole records on the disk.
    good_len: u64,
    /// The edited pack as the journal has it.
    base: Option<(usize, Arc<SpmmMaterial>)>,
    /// Its newest state, not yet turned into a record.
    pending: Option<(usize, Arc<SpmmMaterial>)>,
    buffer: Vec<u8>,
    buffered_edits: usize,
    /// When the oldest unwritten edit came in.
    since: Option<Instant>,
    status: Arc<Mutex<JournalStatus>>,
}

impl Writer {
    fn run(&mut self, rx: &mpsc::Receiver<Msg>) {
        loop {
            let wait = self.since.map_or(Duration::from_secs(3600), |t| {
                (t + WRITE_WITHIN).saturating_duration_since(Instant::now())
            });
            match rx.recv_timeout(wait) {
                Ok(Msg::Pack { slot, material }) => {
                    if self.pending.as_ref().is_some_and(|(s, _)| *s != slot) {
                        self.materialize();
                    }
                    self.pending = Some((slot, material));
                    self.since.get_or_insert_with(Instant::now);
                }
                Ok(Msg::Record(r)) => {
                    self.materialize();
                    self.push(&r);
                }
                Ok(Msg::File(file, material)) => {
                    self.materialize();
                    let slot = file.slot;
                    self.push(&Record::File(file));
                    self.base = Some((slot, material));
                }
                Ok(Msg::Embed(slot, material)) => {
                    self.materialize();
                    self.push(&Record::Embedded {
                        slot,
                        bytes: pack::encode_pack(&material, ResidualPrecision::F32),
                    });
                    self.base = Some((slot, material));
                }
                Ok(Msg::Seal) => self.materialize(),
                Ok(Msg::Flush(ack)) => {
                    self.materialize();
                    let _ = ack.send(self.write());
                }
                Ok(Msg::Rebase(start)) => self.rebase(*start),
                Ok(Msg::Close { remove, done }) => {
                    if remove {
                        let _ = std::fs::remove_file(&self.path);
                    } else {
                        self.materialize();
                        let _ = self.write();
                    }
                    let _ = self.file.unlock();
                    let _ = done.send(());
                    return;
                }
                Err(RecvTimeoutError::Timeout) => {
                    self.materialize();
                    let _ = self.write();
                }
                Err(RecvTimeoutError::Disconnected) => {
                    self.materialize();
                    let _ = self.write();
                    return;
                }
            }
        }
    }

    fn push(&mut self, r: &Record) {
        self.buffer.extend(record_bytes(r));
        self.buffered_edits += usize::from(r.is_edit());
        self.since.get_or_insert_with(Instant::now);
    }

    /// The pending pack state as a delta from the journal's (or whole, if it is not
    /// the same pack).
    fn materialize(&mut self) {
        let Some((slot, m)) = self.pending.take() else {
            return;
        };
        let record = match &self.base {
            Some((s, base)) if *s == slot => match base.delta_to(&m) {
                Ok(d) if d.is_empty() => None,
                Ok(d) => Some(Record::Pack {
                    slot,
                    delta: d.encode(),
                }),
                Err(_) => Some(Record::Embedded {
                    slot,
                    bytes: pack::encode_pack(&m, ResidualPrecision::F32),
                }),
            },
            _ => Some(Record::Embedded {
                slot,
                bytes: pack::encode_pack(&m, ResidualPrecision::F32),
            }),
        };
        if let Some(r) = record {
            self.push(&r);
        }
        self.base = Some((slot, m));
    }

    fn write(&mut self) -> Result<(), String> {
        if self.buffer.is_empty() {
            self.since = None;
            return Ok(());
        }
        let result = self
            .file
            .write_all(&self.buffer)
            .and_then(|()| self.file.sync_data());
        let mut status = self.status.lock().expect("journal status");
        match result {
            Ok(()) => {
                self.good_len += self.buffer.len() as u64;
                self.buffer.clear();
                status.edits += self.buffered_edits;
                self.buffered_edits = 0;
                status.error = None;
                self.since = None;
                Ok(())
            }
            Err(e) => {
                // Cut back to the last whole record; the batch is tried again later.
                let _ = self.file.set_len(self.good_len);
                let _ = self.file.seek(SeekFrom::Start(self.good_len));
                let message = format!(
                    "the recovery journal `{}` cannot be written ({e}); edits are kept in memory",
                    self.path.display()
                );
                status.error = Some(message.clone());
                self.since = Some(Instant::now());
                Err(message)
            }
        }
    }

    fn rebase(&mut self, start: Start) {
        // Everything so far is written first: if the new file cannot be, the old
        // journal still holds every edit and goes on.
        self.materialize();
        let _ = self.write();
        match write_start(&self.path, &start) {
            Ok((file, len)) => {
                let _ = self.file.unlock();
                self.file = file;
                self.good_len = len;
                self.base = start.pack;
                self.buffer.clear();
                self.buffered_edits = 0;
                self.since = None;
                let mut status = self.status.lock().expect("journal status");
                status.edits = 0;
                status.error = None;
            }
            Err(e) => {
                // The old journal stays, with every edit: still a valid recovery.
                self.status.lock().expect("journal status").error = Some(e);
            }
        }
    }
}
