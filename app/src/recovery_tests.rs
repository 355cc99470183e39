//! Never losing work, through the studio's real UI: a scripted session's edits go
//! through the panels' path (one undo step each, journaled); a studio that ends
//! without closing leaves its journal, the next one offers it and "Restore" brings
//! the document back; a pack changed on disk by another program is noticed, and
//! "Reload theirs" loads it with ours one undo away.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use meso_materials::spmm::pack::{self, ResidualPrecision};
use meso_materials::spmm::{SpmmMaterial, WeightTarget};
use meso_session::recover;
use meso_session::script::Script;

use super::tests::loaded;
use super::*;

/// A one-quad scene in `dir` wearing a copy of the brushed-metal pack (ours to
/// change on disk).
fn scene_with_own_pack(dir: &Path) -> (PathBuf, PathBuf) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let pack = dir.join("metal.spmm");
    std::fs::copy(root.join("materials/brushed_metal.spmm"), &pack).expect("copy the pack");
    let scene = dir.join("panel.toml");
    std::fs::write(
        &scene,
        r#"version = 1
[render]
width = 32
height = 32
[camera]
position = [0.0, 1.0, 1.5]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y_deg = 40.0
[materials.metal]
kind = "spmm"
pack = "metal.spmm"
uv_scale = [2.0, 2.0]
[[quad]]
corner = [-0.5, 0.0, 0.5]
edge_u = [1.0, 0.0, 0.0]
edge_v = [0.0, 0.0, -1.0]
material = "metal"
[[light]]
kind = "point"
position = [0.0, 1.0, 0.0]
intensity = [1.0, 1.0, 1.0]
"#,
    )
    .expect("write the scene");
    (scene, pack)
}

fn studio(scene: &Path, state: &Path) -> Harness<'static, Studio> {
    let settings = Settings {
        journal: true,
        state_dir: Some(state.to_path_buf()),
        max_samples: 1,
        ..Settings::for_tests()
    };
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .build_ui_state(
            |ui, s: &mut Studio| s.show(ui),
            Studio::new(None, Some(scene.to_path_buf()), settings),
        );
    loaded(&mut h);
    h
}

fn pack_now(h: &Harness<'_, Studio>) -> std::sync::Arc<SpmmMaterial> {
    h.state()
        .doc
        .as_ref()
        .and_then(|d| d.material())
        .expect("a pack")
}

fn step_until(
    h: &mut Harness<'_, Studio>,
    what: &str,
    done: impl Fn(&Harness<'_, Studio>) -> bool,
) {
    let deadline = Instant::now() + Duration::from_secs(30);
    while !done(h) {
        assert!(Instant::now() < deadline, "{what} within 30 s");
        h.step();
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_scripted_session_is_journaled_and_restored_after_the_studio_dies() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (scene, _) = scene_with_own_pack(dir.path());
    let state = dir.path().join("state");
    let script = Script::parse(
        &dir.path().join("s.toml"),
        r#"
[[edit]]
pack = "--cluster 0 --scale 1.5,1.2,1.0"
[[edit]]
wait_ms = 50
[[edit]]
scene = "light 0 position=0.2,1.5,0.1"
[[edit]]
pack = "--cluster 0 --scale 0.5 --brush 4,4,3"
"#,
    )
    .expect("script");
    let mut h = studio(&scene, &state);
    h.state_mut().run_script(script);
    step_until(&mut h, "the script to end", |h| !h.state().script_running());
    let doc = h.state().doc.as_ref().expect("doc");
    assert_eq!(doc.undo_stats().steps, 3, "one undo step per scripted edit");
    let (edited, lights) = (pack_now(&h), doc.scene.lights.clone());
    doc.journal().expect("journaling").flush().expect("written");
    let sessions = recover::list(&state.join("sessions")).0;
    assert_eq!(sessions.len(), 1);
    assert!(
        sessions[0].live && sessions[0].edits == 3,
        "{:?}",
        sessions[0]
    );
    // The studio dies without closing (no on_exit): its journal stays.
    drop(h);

    let mut h = studio(&scene, &state);
    assert_eq!(
        h.state().restore_offer().len(),
        1,
        "the next start offers it"
    );
    h.run_steps(2);
    h.get_by_label("Restore").click();
    h.run_steps(2);
    loaded(&mut h);
    assert!(
        pack_now(&h).stores_same(&edited),
        "the restored pack is the edited one"
    );
    assert_eq!(h.state().doc.as_ref().expect("doc").scene.lights, lights);
    assert!(h.state().doc.as_ref().expect("doc").dirty());
    let sessions = recover::list(&state.join("sessions")).0;
    assert_eq!(
        sessions.len(),
        1,
        "the old journal went once the new one held its edits"
    );
    assert!(sessions[0].live);
    // A clean exit removes the journal.
    h.state_mut().on_exit();
    assert!(recover::list(&state.join("sessions")).0.is_empty());
}

#[test]
fn a_pack_changed_on_disk_is_offered_back_and_ours_is_one_undo_away() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (scene, pack_path) = scene_with_own_pack(dir.path());
    let state = dir.path().join("state");
    let mut h = studio(&scene, &state);
    let script = Script::parse(
        &dir.path().join("s.toml"),
        "[[edit]]\npack = \"--cluster 0 --scale 2\"\n",
    )
    .expect("script");
    h.state_mut().run_script(script);
    step_until(&mut h, "the script", |h| !h.state().script_running());
    let ours = pack_now(&h);
    // Another program rewrites the pack.
    let theirs = pack::read_pack(&pack_path)
        .expect("read")
        .with_weight_scale(&WeightTarget::cluster(0), [0.25; 3])
        .expect("scale");
    pack::write_pack(&pack_path, &theirs, ResidualPrecision::F16).expect("write");
    step_until(&mut h, "the question", |h| {
        h.query_by_label("Reload theirs").is_some()
    });
    // Saving over it is refused until the user chooses.
    h.get_by_label("Keep editing").click();
    h.run_steps(2);
    assert!(!h.state_mut().save_pack_as(&pack_path));
    h.run_steps(2);
    h.get_by_label("Reload theirs").click();
    h.run_steps(2);
    assert!(pack_now(&h).stores_same(&pack::read_pack(&pack_path).expect("read")));
    h.state_mut().undo();
    assert!(pack_now(&h).stores_same(&ours));
}
