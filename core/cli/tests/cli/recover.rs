//! `meso recover`: a studio session's journal (written here through the same
//! `meso_session` document and script path the studio uses) listed, applied and
//! discarded; the pack it gives equals what `meso pack edit` gives for the same edits.

use std::path::Path;

use meso_session::Document;
use meso_session::script::{Runner, Script};

use crate::pack::write_small_pack;
use crate::*;

const EDITS: [&str; 2] = [
    "--cluster 0 --basis 1 --scale 1.5,1.5,1.2",
    "--cluster 1 --scale 0.5 --brush 0.5,1.5,1",
];

/// A one-quad scene in `dir` wearing the pack at `pack`.
fn write_scene(dir: &Path, pack: &Path) -> std::path::PathBuf {
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        format!(
            r#"version = 1
[render]
width = 8
height = 8
[camera]
position = [0.0, 0.5, 2.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y_deg = 40.0
[materials.panel]
kind = "spmm"
pack = "{}"
uv_scale = [1.0, 1.0]
[[quad]]
corner = [-0.5, 0.0, 0.5]
edge_u = [1.0, 0.0, 0.0]
edge_v = [0.0, 0.0, -1.0]
material = "panel"
[[light]]
kind = "point"
position = [0.0, 1.0, 0.0]
intensity = [1.0, 1.0, 1.0]
"#,
            pack.display()
        ),
    )
    .expect("write scene");
    scene
}

/// Runs the edits as a studio script would and leaves the journal as a crash does.
fn journaled_session(dir: &Path, scene: &Path, state: &Path) {
    let script_text: String = EDITS
        .iter()
        .map(|e| format!("[[edit]]\npack = \"{e}\"\n"))
        .chain(["[[edit]]\nscene = \"light 0 position=0,2,0\"\n".to_string()])
        .collect();
    let script = Script::parse(&dir.join("s.toml"), &script_text).expect("script");
    let loaded = meso_render::scene::load_scene(scene).expect("scene");
    let mut doc = Document::new(loaded, Some(scene.to_path_buf()));
    doc.journal_to(&state.join("sessions"));
    let mut runner = Runner::new(script);
    for i in runner.due(std::time::Instant::now()) {
        let e = runner
            .script
            .edit_on(i, &doc)
            .expect("edit")
            .expect("an edit");
        doc.apply(&e).expect("applies");
        doc.close_group();
    }
    doc.journal().expect("journal").flush().expect("written");
    // Dropped without closing: the session did not end cleanly.
}

#[test]
fn recover_lists_applies_and_discards_a_sessions_journal() {
    let dir = tempfile::tempdir().expect("temp dir");
    let pack = dir.path().join("small.spmm");
    write_small_pack(&pack);
    let scene = write_scene(dir.path(), &pack);
    let state = dir.path().join("state");
    journaled_session(dir.path(), &scene, &state);
    let s = state.to_str().expect("utf-8");

    let o = meso(&["recover", "list", "--state-dir", s, "--json"], "");
    assert_ok(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
    let sessions = v["sessions"].as_array().expect("sessions");
    assert_eq!(sessions.len(), 1, "{v}");
    let session = &sessions[0];
    for key in [
        "journal",
        "scene",
        "packs",
        "edits",
        "started",
        "last_edit",
        "live",
    ] {
        assert!(session.get(key).is_some(), "`{key}` missing: {session}");
    }
    assert_eq!(session["edits"], 3, "two pack edits and a light: {session}");
    assert_eq!(session["live"], false);
    assert!(
        session["scene"]
            .as_str()
            .expect("scene")
            .ends_with("scene.toml")
    );
    assert!(
        session["packs"][0]
            .as_str()
            .expect("pack")
            .ends_with("small.spmm")
    );
    assert!(session["started"].as_str().expect("time").ends_with('Z'));
    let journal = session["journal"].as_str().expect("path").to_string();

    // The journal's pack equals `meso pack edit`'s for the same edits, byte for byte.
    let recovered = dir.path().join("recovered.spmm");
    let r = recovered.to_str().expect("utf-8");
    assert_ok(&meso(&["recover", "apply", &journal, "-o", r], ""));
    let mut reference = pack.to_str().expect("utf-8").to_string();
    for (i, e) in EDITS.iter().enumerate() {
        let out = dir.path().join(format!("ref{i}.spmm"));
        let mut args = vec![
            "pack",
            "edit",
            &reference,
            "-o",
            out.to_str().expect("utf-8"),
        ];
        args.extend(e.split_whitespace());
        assert_ok(&meso(&args, ""));
        reference = out.to_str().expect("utf-8").to_string();
    }
    assert_eq!(
        std::fs::read(&recovered).expect("recovered"),
        std::fs::read(&reference).expect("reference"),
        "recover apply and pack edit disagree"
    );

    // A journal cut mid-record applies what came before, and says so.
    let bytes = std::fs::read(&journal).expect("journal");
    let cut = dir.path().join("cut.journal");
    std::fs::write(&cut, &bytes[..bytes.len() - 3]).expect("write");
    let o = meso(
        &[
            "recover",
            "apply",
            cut.to_str().expect("utf-8"),
            "-o",
            r,
            "--json",
        ],
        "",
    );
    assert_ok(&o);
    assert!(String::from_utf8_lossy(&o.stderr).contains("cut record"));

    // Bad input names the file.
    let not = dir.path().join("not.journal");
    std::fs::write(&not, b"hello").expect("write");
    assert_bad_input(
        &meso(
            &["recover", "apply", not.to_str().expect("utf-8"), "-o", r],
            "",
        ),
        &["not.journal", "not a Meso journal"],
    );
    // A pack changed since the session refuses to be patched.
    std::fs::write(&pack, b"changed").expect("clobber");
    assert_bad_input(
        &meso(&["recover", "apply", &journal, "-o", r], ""),
        &["small.spmm", "changed since the session journaled it"],
    );

    assert_ok(&meso(&["recover", "discard", &journal], ""));
    let o = meso(&["recover", "list", "--state-dir", s, "--json"], "");
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
    assert_eq!(v["sessions"].as_array().map(Vec::len), Some(0));
    assert_bad_input(
        &meso(&["recover", "discard", &journal], ""),
        &[journal.as_str()],
    );
}
