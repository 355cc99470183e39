//! The golden store: one EXR per case in the manifest's goldens folder, and the log of
//! every `--update` beside them (`LOG.md`: date, reason, command, Meso version, cases).
//! The log entry is written first, then each golden atomically: an interrupted update
//! leaves every golden whole (old or new) and is never silent.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use meso_materials::atomic::write_bytes_atomic;
use meso_materials::image::{Image, write_exr};

/// The log's file name in the goldens folder.
pub const LOG_FILE: &str = "LOG.md";

/// Why and by what the goldens are rewritten.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UpdateRequest {
    pub reason: String,
    /// The command line, as the user typed it (for the log).
    pub command: String,
}

#[derive(Debug, thiserror::Error)]
pub enum GoldenError {
    #[error("cannot create the goldens folder `{}`: {source}", path.display())]
    Folder {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot read the update log `{}`: {source}", path.display())]
    ReadLog {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("writing the update log: {0}")]
    WriteLog(#[from] meso_materials::atomic::AtomicWriteError),
    #[error("writing golden `{}`: {source}", path.display())]
    Write {
        path: PathBuf,
        source: meso_materials::image::ImageError,
    },
}

/// One entry of the log, in Markdown.
pub fn log_entry(request: &UpdateRequest, cases: &[&str], when: SystemTime) -> String {
    let mut text = format!(
        "## {} ({} golden{})\n\n- reason: {}\n- command: `{}`\n- meso: {}\n- cases:",
        utc_timestamp(when),
        cases.len(),
        if cases.len() == 1 { "" } else { "s" },
        request.reason.replace('\n', " "),
        request.command.replace('`', "'"),
        env!("CARGO_PKG_VERSION"),
    );
    for c in cases {
        text.push_str(&format!(" `{c}`"));
    }
    text.push_str("\n\n");
    text
}

/// Appends the log entry (atomically: the whole log is rewritten), then writes every
/// golden atomically, in order. Stops at the first failure, naming the file.
pub fn write_goldens(
    goldens: &Path,
    request: &UpdateRequest,
    images: &[(PathBuf, &str, &Image)],
) -> Result<(), GoldenError> {
    std::fs::create_dir_all(goldens).map_err(|source| GoldenError::Folder {
        path: goldens.to_path_buf(),
        source,
    })?;
    let log = goldens.join(LOG_FILE);
    let mut text = match std::fs::read_to_string(&log) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            "# Golden image updates\n\nWritten by `meso regress --update`, newest last.\n\n"
                .to_string()
        }
        Err(source) => return Err(GoldenError::ReadLog { path: log, source }),
    };
    let names: Vec<&str> = images.iter().map(|(_, n, _)| *n).collect();
    text.push_str(&log_entry(request, &names, SystemTime::now()));
    write_bytes_atomic(&log, text.as_bytes())?;
    for (path, _, image) in images {
        write_exr(path, image).map_err(|source| GoldenError::Write {
            path: path.clone(),
            source,
        })?;
    }
    Ok(())
}

/// `YYYY-MM-DDTHH:MM:SSZ` of a time (UTC).
pub fn utc_timestamp(when: SystemTime) -> String {
    meso_materials::utc::timestamp(when)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_update_logs_first_then_writes_each_golden_and_a_failure_names_the_file() {
        let dir = tempfile::tempdir().expect("temp dir");
        let goldens = dir.path().join("goldens");
        let img = Image::new(4, 4);
        let request = UpdateRequest {
            reason: "first goldens".into(),
            command: "meso regress m.toml --update".into(),
        };
        let a = goldens.join("a.exr");
        write_goldens(&goldens, &request, &[(a.clone(), "a", &img)]).expect("written");
        assert_eq!(meso_materials::image::read_exr(&a).expect("golden"), img);
        let log = std::fs::read_to_string(goldens.join(LOG_FILE)).expect("log");
        assert!(log.contains("reason: first goldens"), "{log}");
        assert!(log.contains("- meso: "), "{log}");
        assert!(log.contains("`meso regress m.toml --update`"), "{log}");
        assert!(log.contains("cases: `a`"), "{log}");

        // The second golden's path is a folder: the write fails naming it, the first
        // golden of this update is written, the old `a` stays whole, and the log holds
        // both entries (the failed update is not silent).
        let before = std::fs::read(&a).expect("a");
        let b = goldens.join("b.exr");
        std::fs::create_dir_all(&b).expect("folder in the way");
        let c = goldens.join("c.exr");
        let mut other = Image::new(4, 4);
        other.set(1, 1, [1.0, 2.0, 3.0]);
        let second = UpdateRequest {
            reason: "second".into(),
            command: "x".into(),
        };
        let err = write_goldens(
            &goldens,
            &second,
            &[(c.clone(), "c", &other), (b.clone(), "b", &other)],
        )
        .expect_err("b is a folder");
        assert!(err.to_string().contains("b.exr"), "{err}");
        assert_eq!(
            meso_materials::image::read_exr(&c).expect("c written"),
            other
        );
        assert_eq!(std::fs::read(&a).expect("a"), before);
        let log = std::fs::read_to_string(goldens.join(LOG_FILE)).expect("log");
        assert_eq!(log.matches("## ").count(), 2, "{log}");
        assert!(
            log.contains("reason: second") && log.contains("`c` `b`"),
            "{log}"
        );
    }
}
