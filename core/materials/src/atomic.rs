//! Atomic file writes: every file Meso writes goes through `write_atomic`, which
//! writes a temporary file in the destination's folder, syncs it, then renames it
//! over the destination. An interrupted or failed write leaves the old file intact.

use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum AtomicWriteError {
    #[error("cannot create a temporary file in `{dir}` to write `{path}`: {source}")]
    CreateTemp {
        path: PathBuf,
        dir: PathBuf,
        source: io::Error,
    },
    #[error("cannot write `{path}`: {source}")]
    Write { path: PathBuf, source: io::Error },
    #[error("cannot replace `{path}` with the new version: {source}")]
    Persist { path: PathBuf, source: io::Error },
}

/// Writes `path` whole or not at all. `fill` writes the content into a buffered
/// temporary file; if it fails, nothing at `path` changes and the temporary is removed.
pub fn write_atomic<F>(path: &Path, fill: F) -> Result<(), AtomicWriteError>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let temp = tempfile::Builder::new()
        .prefix(".meso-")
        .suffix(".tmp")
        .tempfile_in(&dir)
        .map_err(|source| AtomicWriteError::CreateTemp {
            path: path.to_path_buf(),
            dir: dir.clone(),
            source,
        })?;
    let write_err = |source| AtomicWriteError::Write {
        path: path.to_path_buf(),
        source,
    };
    {
        let mut out = BufWriter::new(temp.as_file());
        fill(&mut out).map_err(write_err)?;
        out.flush().map_err(write_err)?;
    }
    // The temporary is created private (0600); give the result the permissions of the
    // file it replaces, or the usual 0644 for a new file.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(path)
            .map(|m| m.permissions().mode() & 0o7777)
            .unwrap_or(0o644);
        temp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(mode))
            .map_err(write_err)?;
    }
    temp.as_file().sync_all().map_err(write_err)?;
    temp.persist(path).map_err(|e| AtomicWriteError::Persist {
        path: path.to_path_buf(),
        source: e.error,
    })?;
    Ok(())
}

/// Writes a byte buffer atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), AtomicWriteError> {
    write_atomic(path, |w| w.write_all(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_whole_file() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("out.txt");
        write_bytes_atomic(&path, b"first version").expect("write");
        write_bytes_atomic(&path, b"second").expect("rewrite");
        assert_eq!(std::fs::read(&path).expect("read"), b"second");
    }

    #[test]
    fn failed_write_keeps_old_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("out.txt");
        write_bytes_atomic(&path, b"precious").expect("write");
        let err = write_atomic(&path, |w| {
            w.write_all(b"half a fi")?;
            Err(io::Error::other("disk on fire"))
        })
        .expect_err("the fill failed");
        assert!(err.to_string().contains("out.txt"), "{err}");
        assert_eq!(std::fs::read(&path).expect("read"), b"precious");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names.len(), 1, "left behind: {names:?}");
    }

    #[cfg(unix)]
    #[test]
    fn new_files_are_readable_and_replaced_files_keep_their_mode() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("out.txt");
        write_bytes_atomic(&path, b"new").expect("write");
        let mode = |p: &Path| std::fs::metadata(p).expect("stat").permissions().mode() & 0o777;
        assert_eq!(mode(&path), 0o644);
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).expect("chmod");
        write_bytes_atomic(&path, b"again").expect("rewrite");
        assert_eq!(mode(&path), 0o600);
    }

    #[test]
    fn missing_folder_is_a_named_error() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("no/such/folder/out.txt");
        let err = write_bytes_atomic(&path, b"x").expect_err("no folder");
        assert!(err.to_string().contains("no/such/folder"), "{err}");
    }
}
