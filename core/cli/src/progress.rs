//! Progress on stderr for long commands (only when stderr is a terminal, docs/cli.md)
//! and the Ctrl-C flag they poll: the first Ctrl-C sets it, the work stops between
//! items, and no output file is written.

use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::sync::OnceLock;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

static CANCEL: AtomicBool = AtomicBool::new(false);
static HANDLER: OnceLock<()> = OnceLock::new();

/// The process's cancel flag, with the Ctrl-C handler installed on first use.
pub fn cancel_flag() -> &'static AtomicBool {
    HANDLER.get_or_init(|| {
        // Without a handler Ctrl-C kills the process, which the atomic writes make
        // safe as well; so a failure to install one is not an error.
        let _ = ctrlc::set_handler(|| CANCEL.store(true, std::sync::atomic::Ordering::SeqCst));
    });
    &CANCEL
}

/// A one-line progress display, redrawn at most ten times a second.
pub struct ProgressLine {
    enabled: bool,
    last: Mutex<Option<Instant>>,
}

impl ProgressLine {
    pub fn new() -> Self {
        Self {
            enabled: std::io::stderr().is_terminal(),
            last: Mutex::new(None),
        }
    }

    pub fn update(&self, label: &str, done: usize, total: usize) {
        if !self.enabled {
            return;
        }
        let Ok(mut last) = self.last.lock() else {
            return;
        };
        let now = Instant::now();
        if done < total && last.is_some_and(|t| now - t < Duration::from_millis(100)) {
            return;
        }
        *last = Some(now);
        let width = 30;
        let filled = (done * width).checked_div(total).unwrap_or(width);
        let bar: String = (0..width)
            .map(|i| if i < filled { '#' } else { '.' })
            .collect();
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r{label:<14} [{bar}] {done}/{total}   ");
        let _ = err.flush();
    }

    pub fn finish(&self) {
        if self.enabled {
            eprintln!();
        }
    }
}
