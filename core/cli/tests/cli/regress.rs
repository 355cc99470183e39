//! `meso regress`: exit codes, reports, goldens and their update log.

use std::path::Path;
use std::process::Command;
use std::process::Stdio;

use crate::*;

/// A regression manifest in `dir` over the repository's default scene: its own
/// material and the shipped woven wool substituted, `extra` appended.
fn regress_manifest(dir: &Path, size: u32, frames: u32, extra: &str) -> std::path::PathBuf {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = format!(
        "version = 1\ngoldens = \"goldens\"\n\n[defaults]\nwidth = {size}\nheight = {size}\nframes = {frames}\nmax_relative_rmse = 0.001\n\n[scenes.default]\npath = \"{}\"\nreplace = \"leather\"\n\n[materials.wool]\nkind = \"spmm\"\npack = \"{}\"\n\n[[matrix]]\nscenes = [\"default\"]\nmaterials = [\"scene\", \"wool\"]\nmodes = [\"spmm\"]\n{extra}",
        repo.join("tests/scenes/default.toml").display(),
        repo.join("materials/woven_wool.spmm").display(),
    );
    let path = dir.join("manifest.toml");
    std::fs::write(&path, text).expect("manifest");
    path
}

#[test]
fn regress_exit_codes_json_update_log_and_junit() {
    let dir = tempfile::tempdir().expect("temp dir");
    let m = regress_manifest(dir.path(), 24, 2, "");
    let ms = m.to_str().expect("utf-8 path");
    // No goldens yet: exit 1, each case says how to create its golden.
    let o = meso(&["regress", ms], "");
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("error: 2 of 2 cases failed: "), "{err}");
    assert!(stdout(&o).contains("--update --reason"), "{}", stdout(&o));
    // --update needs a reason, and a reason needs --update.
    assert_bad_input(&meso(&["regress", ms, "--update"], ""), &["--reason"]);
    assert_bad_input(&meso(&["regress", ms, "--reason", "x"], ""), &["--update"]);
    let o = meso(
        &["regress", ms, "--update", "--reason", "first goldens"],
        "",
    );
    assert_ok(&o);
    let log = std::fs::read_to_string(dir.path().join("goldens/LOG.md")).expect("log");
    assert!(log.contains("- reason: first goldens"), "{log}");
    assert!(log.contains("--update --reason 'first goldens'"), "{log}");
    assert!(
        log.contains("cases: `default.scene.spmm-cpu` `default.wool.spmm-cpu`"),
        "{log}"
    );
    assert!(
        log.contains(&format!("- meso: {}", env!("CARGO_PKG_VERSION"))),
        "{log}"
    );
    for case in ["default.scene.spmm-cpu", "default.wool.spmm-cpu"] {
        assert!(dir.path().join(format!("goldens/{case}.exr")).is_file());
    }
    // All pass: exit 0, one JSON object, a report folder and a JUnit file.
    let report = dir.path().join("report");
    let junit = dir.path().join("junit.xml");
    let o = meso(
        &[
            "regress",
            ms,
            "--json",
            "--jobs",
            "2",
            "-o",
            report.to_str().expect("utf-8"),
            "--junit",
            junit.to_str().expect("utf-8"),
        ],
        "",
    );
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert_eq!(
        (v["total"].as_u64(), v["passed"].as_u64()),
        (Some(2), Some(2)),
        "{v}"
    );
    assert_eq!(
        v["cases"][0]["metrics"]["identical"],
        serde_json::json!(true)
    );
    for f in ["index.html", "summary.md", "report.json"] {
        assert!(report.join(f).is_file(), "{f}");
    }
    let x = std::fs::read_to_string(&junit).expect("junit");
    assert!(x.contains("tests=\"2\" failures=\"0\""), "{x}");
    // Another seed changes every render: exit 1 naming both cases; the JUnit file
    // says so too.
    let m = regress_manifest(dir.path(), 24, 2, "seed = 9\n");
    let ms = m.to_str().expect("utf-8 path");
    let o = meso(
        &["regress", ms, "--junit", junit.to_str().expect("utf-8")],
        "",
    );
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("default.scene.spmm-cpu") && err.contains("default.wool.spmm-cpu"),
        "{err}"
    );
    let x = std::fs::read_to_string(&junit).expect("junit");
    assert!(x.contains("tests=\"2\" failures=\"2\""), "{x}");
    // Shards: every case in one of the two; merged, one report and one JUnit file
    // with both failures, and exit 1.
    let mut total = 0;
    let mut dirs = Vec::new();
    for (i, k) in ["1/2", "2/2"].into_iter().enumerate() {
        let d = dir.path().join(format!("shard{i}"));
        let o = meso(
            &[
                "regress",
                ms,
                "--shard",
                k,
                "--json",
                "-o",
                d.to_str().expect("utf-8"),
            ],
            "",
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
        total += v["total"].as_u64().expect("total");
        dirs.push(d.to_str().expect("utf-8").to_string());
    }
    assert_eq!(total, 2);
    let merged = dir.path().join("merged");
    let merged_junit = dir.path().join("merged.xml");
    let o = meso(
        &[
            "regress",
            "merge",
            &dirs[0],
            &dirs[1],
            "-o",
            merged.to_str().expect("utf-8"),
            "--junit",
            merged_junit.to_str().expect("utf-8"),
        ],
        "",
    );
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(merged.join("index.html").is_file());
    let x = std::fs::read_to_string(&merged_junit).expect("merged junit");
    assert!(x.contains("tests=\"2\" failures=\"2\""), "{x}");
    assert_bad_input(
        &meso(
            &[
                "regress",
                "merge",
                &dirs[0],
                "-o",
                merged.to_str().expect("utf-8"),
            ],
            "",
        ),
        &["shard(s) 2/2 missing"],
    );
}

#[test]
fn regress_bad_input_exits_2_naming_the_place() {
    let dir = tempfile::tempdir().expect("temp dir");
    let m = regress_manifest(dir.path(), 24, 2, "colour = 3\n");
    let ms = m.to_str().expect("utf-8 path");
    assert_bad_input(
        &meso(&["regress", ms], ""),
        &["manifest.toml` line 22", "colour"],
    );
    let m = regress_manifest(
        dir.path(),
        24,
        2,
        "\n[materials.velvet]\nkind = \"btf\"\npath = \"velvet.btf\"\n\n[[case]]\nscene = \"default\"\nmaterial = \"velvet\"\nmode = \"spmm\"\n",
    );
    let ms = m.to_str().expect("utf-8 path");
    assert_bad_input(
        &meso(&["regress", ms], ""),
        &[
            "case `default.velvet.spmm-cpu`",
            "line 25, `materials.velvet.path`",
            "velvet.btf",
        ],
    );
    let m = regress_manifest(dir.path(), 24, 2, "");
    let ms = m.to_str().expect("utf-8 path");
    assert_bad_input(
        &meso(&["regress", ms, "--only", "nothing*"], ""),
        &["matches no case"],
    );
    assert_bad_input(
        &meso(&["regress", ms, "--shard", "3/2"], ""),
        &["--shard", "K/N"],
    );
    assert_bad_input(&meso(&["regress", ms, "--jobs", "0"], ""), &["--jobs"]);
    assert_bad_input(
        &meso(&["regress", "/no/such.toml"], ""),
        &["/no/such.toml", "cannot read"],
    );
    // A replaced material the scene does not have names the manifest line and the case.
    let text = std::fs::read_to_string(&m)
        .expect("text")
        .replace("replace = \"leather\"", "replace = \"suede\"");
    std::fs::write(&m, text).expect("edit");
    assert_bad_input(
        &meso(&["regress", ms], ""),
        &[
            "case `default.wool.spmm-cpu`",
            "line 12",
            "no material `suede`",
            "leather",
        ],
    );
    // merge: not a report folder.
    assert_bad_input(
        &meso(
            &[
                "regress",
                "merge",
                dir.path().to_str().expect("utf-8"),
                "-o",
                "x",
            ],
            "",
        ),
        &["report.json"],
    );
}

/// `--update` renders every case before it writes: killed while rendering, every old
/// golden and the log stay as they were.
#[test]
fn regress_update_killed_midway_keeps_the_old_goldens() {
    let dir = tempfile::tempdir().expect("temp dir");
    let m = regress_manifest(dir.path(), 16, 1, "");
    let ms = m.to_str().expect("utf-8 path");
    assert_ok(&meso(&["regress", ms, "--update", "--reason", "old"], ""));
    let goldens = dir.path().join("goldens");
    let snapshot = || -> Vec<(std::ffi::OsString, Vec<u8>)> {
        let mut files: Vec<_> = std::fs::read_dir(&goldens)
            .expect("goldens")
            .map(|e| {
                let e = e.expect("entry");
                (e.file_name(), std::fs::read(e.path()).expect("readable"))
            })
            .collect();
        files.sort();
        files
    };
    let before = snapshot();
    assert_eq!(before.len(), 3, "two goldens and the log");
    // Larger and longer on another seed, on one thread: seconds of rendering on any
    // machine to kill into.
    regress_manifest(dir.path(), 256, 64, "seed = 3\n");
    let mut child = Command::new(env!("CARGO_BIN_EXE_meso"))
        .args([
            "regress",
            ms,
            "--update",
            "--reason",
            "new",
            "--threads",
            "1",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("meso starts");
    std::thread::sleep(std::time::Duration::from_millis(700));
    let still_running = child.try_wait().expect("wait").is_none();
    child.kill().expect("kill");
    let status = child.wait().expect("reaped");
    assert!(
        still_running && !status.success(),
        "the update finished before it could be killed ({status}); the test needs a longer render"
    );
    assert_eq!(
        snapshot(),
        before,
        "goldens or log changed by a killed update"
    );
}
