//! The `meso` command-line contract (docs/cli.md), tested on the real binary: exit
//! codes 0/2/1, one `error:` line naming the place at fault, `--json` output that
//! parses, and outputs that are written whole or not at all.

use std::io::Write;
use std::process::{Command, Output, Stdio};

mod bench;
mod brdf;
mod btf_fit;
mod btf_formats;
mod compare;
mod merl;
mod pack;
mod recover;
mod regress;
mod render;
mod reports;

fn meso(args: &[&str], stdin: &str) -> Output {
    // Precomputations are cached in the test target's folder, not the user's.
    let mut child = Command::new(env!("CARGO_BIN_EXE_meso"))
        .args(args)
        .env(
            "MESO_CACHE_DIR",
            concat!(env!("CARGO_TARGET_TMPDIR"), "/meso-cache"),
        )
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the meso binary was built by cargo for this test");
    let written = child
        .stdin
        .take()
        .expect("stdin is piped")
        .write_all(stdin.as_bytes());
    // A command that rejects its arguments exits without reading stdin.
    if let Err(e) = written {
        assert_eq!(e.kind(), std::io::ErrorKind::BrokenPipe, "write stdin: {e}");
    }
    child.wait_with_output().expect("meso runs to completion")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Asserts a bad-input failure: exit 2, exactly one stderr line, starting `error:`
/// and containing every `needle`, nothing on stdout.
fn assert_bad_input(o: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "stderr: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "one error line expected, got: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    for needle in needles {
        assert!(lines[0].contains(needle), "`{needle}` missing from: {err}");
    }
    assert!(
        o.stdout.is_empty(),
        "stdout must stay empty on error: {}",
        stdout(o)
    );
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn usage_errors_are_one_line_and_exit_2() {
    assert_bad_input(
        &meso(&["brdf", "eval", "--modle", "ward"], ""),
        &["--modle"],
    );
    assert_bad_input(&meso(&["render-everything"], ""), &["render-everything"]);
    let help = meso(&["--help"], "");
    assert_ok(&help);
    assert!(stdout(&help).contains("compare"));
}

#[test]
fn a_closed_output_pipe_ends_the_command_quietly() {
    use std::io::{BufRead, BufReader};
    // Far more output than a pipe buffers; the reader stops after one line.
    let input: String = (0..200_000).map(|_| "0,0,1,0,0,1\n").collect();
    let mut child = Command::new(env!("CARGO_BIN_EXE_meso"))
        .args(["brdf", "eval", "--model", "lambertian"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("meso starts");
    let mut stdin = child.stdin.take().expect("stdin");
    let writer = std::thread::spawn(move || {
        let _ = stdin.write_all(input.as_bytes());
    });
    let mut first = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut first)
        .expect("one line");
    assert!(first.starts_with("3.18309886e-1"), "{first}");
    let out = child.wait_with_output().expect("meso ends");
    let _ = writer.join();
    let err = String::from_utf8_lossy(&out.stderr);
    // Ended by SIGPIPE like any Unix filter: no panic, no error line.
    assert!(err.is_empty(), "{err}");
    assert_ne!(out.status.code(), Some(101), "not a panic");
}

fn assert_ok(o: &Output) {
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `meso render` with `env` added to its environment.
fn meso_with_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_meso"))
        .args(args)
        .envs(env.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .expect("meso runs to completion")
}
