//! How the `meso` binary fails: one `error:` line on stderr and an exit code that
//! tells bad input (2) from other failures (1), as docs/cli.md requires.

use std::process::ExitCode;

/// Exit code for bad input or usage: an unreadable or invalid file, an unknown
/// model, an out-of-range parameter, a malformed row.
pub const EXIT_BAD_INPUT: u8 = 2;
/// Exit code for every other failure (an output that cannot be written, ...).
pub const EXIT_FAILURE: u8 = 1;

#[derive(Debug)]
pub struct CliError {
    pub bad_input: bool,
    pub error: anyhow::Error,
}

impl CliError {
    pub fn bad_input(error: impl Into<anyhow::Error>) -> Self {
        Self {
            bad_input: true,
            error: error.into(),
        }
    }
    pub fn failure(error: impl Into<anyhow::Error>) -> Self {
        Self {
            bad_input: false,
            error: error.into(),
        }
    }
}

/// Classifies a library error with a context that names the place at fault.
pub trait ResultExt<T> {
    fn bad_input_ctx(self, context: impl FnOnce() -> String) -> Result<T, CliError>;
    fn failure_ctx(self, context: impl FnOnce() -> String) -> Result<T, CliError>;
}

impl<T, E: Into<anyhow::Error>> ResultExt<T> for Result<T, E> {
    fn bad_input_ctx(self, context: impl FnOnce() -> String) -> Result<T, CliError> {
        self.map_err(|e| CliError::bad_input(e.into().context(context())))
    }
    fn failure_ctx(self, context: impl FnOnce() -> String) -> Result<T, CliError> {
        self.map_err(|e| CliError::failure(e.into().context(context())))
    }
}

/// The error and its causes joined by ": " on one line, leaving out a cause whose
/// text the line already holds (library errors often quote their source: printing it
/// again said the cause twice).
pub fn one_line(error: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in error.chain() {
        let text = cause.to_string().replace('\n', " ");
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

/// Prints the error chain on one line and returns the matching exit code.
pub fn report(err: &CliError) -> ExitCode {
    let line = one_line(&err.error);
    eprintln!("error: {line}");
    ExitCode::from(if err.bad_input {
        EXIT_BAD_INPUT
    } else {
        EXIT_FAILURE
    })
}

/// Help and version go to stdout with exit 0; a usage error becomes one `error:`
/// line (clap's first line, without its multi-line usage block) and exit 2.
pub fn report_clap_error(err: clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    match err.kind() {
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => {
            print!("{err}");
            ExitCode::SUCCESS
        }
        _ => {
            let message = usage_message(&err.to_string());
            eprintln!("error: {message} (see `meso --help`)");
            ExitCode::from(EXIT_BAD_INPUT)
        }
    }
}

/// Clap's first paragraph on one line: its first line alone would drop what follows
/// it, such as the names of missing required arguments.
fn usage_message(rendered: &str) -> String {
    let paragraph: Vec<&str> = rendered
        .lines()
        .skip_while(|l| l.trim().is_empty())
        .take_while(|l| !l.trim().is_empty())
        .map(str::trim)
        .collect();
    let line = paragraph.join(" ");
    let line = line.strip_prefix("error:").unwrap_or(&line).trim();
    if line.is_empty() {
        "invalid usage".to_string()
    } else {
        line.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_argument_is_named_on_the_one_line() {
        let rendered = "error: the following required arguments were not provided:\n  --mode <MODE>\n\nUsage: meso precompute --mode <MODE> <SCENE>\n\nFor more information, try '--help'.\n";
        assert_eq!(
            usage_message(rendered),
            "the following required arguments were not provided: --mode <MODE>"
        );
        assert_eq!(usage_message("\n\n"), "invalid usage");
    }

    #[test]
    fn a_cause_the_message_already_quotes_is_said_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file (os error 2)");
        let lib = meso_materials::atomic::AtomicWriteError::CreateTemp {
            path: "/missing/x.png".into(),
            dir: "/missing".into(),
            source: io,
        };
        let e = anyhow::Error::new(lib).context("writing `/missing/x.png`");
        let line = one_line(&e);
        assert_eq!(line.matches("No such file").count(), 1, "{line}");
        assert!(line.starts_with("writing `/missing/x.png`: cannot create a temporary file"));
        // A cause that adds something is kept.
        let e = anyhow::anyhow!("inner detail").context("outer");
        assert_eq!(one_line(&e), "outer: inner detail");
    }
}
