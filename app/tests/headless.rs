//! The goal, on the real binary: a scripted session killed with SIGKILL one
//! second after its last edit loses none of its edits — the journal's pack equals the
//! same edits made by `meso pack edit`'s code (`meso_session::pack_edits`; the CLI
//! test `recover_lists_applies_and_discards_a_sessions_journal` checks the command
//! gives the same bytes).

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use meso_materials::spmm::pack;
use meso_session::pack_edits::PackEdits;
use meso_session::{journal, recover};

const EDITS: [&str; 4] = [
    "--cluster 0 --basis 0 --scale 1.5,1.5,1.2",
    "--cluster 0 --scale 0.5 --brush 4,4,3",
    "--mute 0:1",
    "--cluster 0 --scale 1.25 --brush 20,9,5",
];

fn write_scene(dir: &Path) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    std::fs::copy(
        root.join("materials/brushed_metal.spmm"),
        dir.join("metal.spmm"),
    )
    .expect("copy the pack");
    let scene = dir.join("panel.toml");
    std::fs::write(
        &scene,
        "version = 1\n[render]\nwidth = 16\nheight = 16\n\
         [camera]\nposition = [0.0, 1.0, 1.5]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov_y_deg = 40.0\n\
         [materials.metal]\nkind = \"spmm\"\npack = \"metal.spmm\"\nuv_scale = [2.0, 2.0]\n\
         [[quad]]\ncorner = [-0.5, 0.0, 0.5]\nedge_u = [1.0, 0.0, 0.0]\nedge_v = [0.0, 0.0, -1.0]\nmaterial = \"metal\"\n",
    )
    .expect("write the scene");
    scene
}

#[test]
fn a_session_killed_a_second_after_its_last_edit_loses_none_of_them() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = write_scene(dir.path());
    let script = dir.path().join("session.toml");
    let mut text: String = EDITS
        .iter()
        .map(|e| format!("[[edit]]\npack = \"{e}\"\n[[edit]]\nwait_ms = 20\n"))
        .collect();
    text += "[[edit]]\nwait_ms = 600000\n";
    std::fs::write(&script, text).expect("write the script");
    let state = dir.path().join("state");
    let mut child = Command::new(env!("CARGO_BIN_EXE_meso-studio"))
        .arg(&scene)
        .args(["--run", script.to_str().expect("utf-8"), "--headless"])
        .env("MESO_STATE_DIR", &state)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("the studio binary was built for this test");
    let lines = BufReader::new(child.stdout.take().expect("stdout"));
    let last = format!("edit {} of", 2 * EDITS.len() - 1);
    for line in lines.lines() {
        if line.expect("a line").starts_with(&last) {
            break;
        }
    }
    std::thread::sleep(Duration::from_secs(1));
    child.kill().expect("SIGKILL");
    child.wait().expect("reaped");

    let (sessions, unreadable) = recover::list(&state.join("sessions"));
    assert!(unreadable.is_empty(), "{unreadable:?}");
    assert_eq!(sessions.len(), 1);
    assert!(!sessions[0].live, "a killed session holds no lock");
    assert_eq!(sessions[0].edits, EDITS.len());
    let contents = journal::read(&sessions[0].journal).expect("read");
    assert!(contents.cut_at.is_none());
    let (recovered, precision) = recover::pack_of(&contents).expect("replays");

    let mut reference = pack::read_pack(&dir.path().join("metal.spmm")).expect("the pack");
    for e in EDITS {
        reference = PackEdits::parse(e)
            .and_then(|p| p.apply(&reference, dir.path()))
            .expect("edit")
            .material;
    }
    let file = std::fs::read(dir.path().join("metal.spmm")).expect("the pack");
    assert_eq!(
        precision,
        pack::residual_precision(&file),
        "saved as the file was"
    );
    assert_eq!(
        pack::encode_pack(&recovered, precision),
        pack::encode_pack(&reference, precision),
        "the journal's pack is the edited pack, tensor for tensor"
    );
}
