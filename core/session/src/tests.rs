//! The session's promises: a journal replayed equals the live document, a journal
//! cut at any byte restores everything before the cut, saves that fail or meet a
//! changed file lose nothing, undo stays within its budget, scripts edit as the
//! command line does.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::DVec3;
use meso_materials::spmm::pack::{self, ResidualPrecision};
use meso_materials::spmm::{SpmmMaterial, TexelMask, WeightTarget};
use meso_render::SceneEdit;
use meso_render::scene::test_scenes::edit_test_scene;
use meso_render::scene::{Ambient, Light, Material, Scene};

use crate::document::{Document, SaveError, read_pack_file};
use crate::journal::{self, Record};
use crate::recover;
use crate::script::{Runner, Script};

/// The edit test scene with its panel pack (material 1) read from a file in `dir`.
fn scene_with_pack(dir: &Path) -> (Scene, PathBuf) {
    let mut scene = edit_test_scene();
    let Material::Spmm { material, .. } = &scene.materials[1] else {
        unreachable!("material 1 is the panel pack")
    };
    let path = dir.join("panel.spmm");
    pack::write_pack(&path, material, ResidualPrecision::F16).expect("write");
    let (read, _) = read_pack_file(&path).expect("read");
    if let Material::Spmm { material, .. } = &mut scene.materials[1] {
        *material = read;
    }
    scene.material_files = vec![None, Some(path.clone())];
    (scene, path)
}

fn pack_of(doc: &Document) -> Arc<SpmmMaterial> {
    doc.material().expect("the document edits a pack")
}

/// A brush dab on cluster `c`, basis 0, around texel `t`.
fn stroke(doc: &Document, t: usize, gain: f64) -> SceneEdit {
    let m = pack_of(doc);
    let (w, h) = (m.width(), m.height());
    let mut s = vec![0.0f32; (w * h) as usize];
    let n = s.len();
    s[t % n] = 1.0;
    let mask = TexelMask::from_strengths(w, h, s).expect("mask");
    let c = m.texel_cluster()[t % m.texel_cluster().len()] as usize;
    let next = m
        .with_weight_scale(&WeightTarget::cluster(c).within(&mask), [gain; 3])
        .expect("stroke");
    on_pack(doc, next)
}

fn on_pack(doc: &Document, m: SpmmMaterial) -> SceneEdit {
    let slot = doc.pack.as_ref().expect("pack").material;
    let Material::Spmm {
        uv_scale,
        residual,
        npca,
        ..
    } = &doc.scene.materials[slot]
    else {
        unreachable!()
    };
    SceneEdit::Material {
        index: slot,
        material: Material::Spmm {
            material: Arc::new(m),
            uv_scale: *uv_scale,
            residual: *residual,
            npca: *npca,
        },
    }
}

fn step(doc: &mut Document, e: &SceneEdit) {
    doc.apply(e).expect("edit applies");
    doc.close_group();
}

/// The document states a user would call the same.
fn assert_same(a: &Document, b: &Document) {
    assert!(pack_of(a).stores_same(&pack_of(b)), "packs differ");
    assert_eq!(pack_of(a).view(), pack_of(b).view(), "views differ");
    assert_eq!(a.scene.lights, b.scene.lights);
    assert_eq!(a.scene.ambient, b.scene.ambient);
    assert_eq!(a.scene.camera, b.scene.camera);
    assert_eq!(a.scene.render.light_samples, b.scene.render.light_samples);
    for (x, y) in a.scene.materials.iter().zip(&b.scene.materials) {
        match (x, y) {
            (
                Material::Brdf { brdf, albedo },
                Material::Brdf {
                    brdf: b2,
                    albedo: a2,
                },
            ) => {
                assert_eq!((brdf, albedo), (b2, a2))
            }
            (
                Material::Spmm {
                    uv_scale,
                    residual,
                    npca,
                    ..
                },
                Material::Spmm {
                    uv_scale: u,
                    residual: r,
                    npca: n,
                    ..
                },
            ) => {
                assert_eq!((uv_scale, residual, npca), (u, r, n))
            }
            _ => panic!("material kinds differ"),
        }
    }
}

/// A session of every kind of edit, with undo and redo and a save in the middle.
fn edit_session(doc: &mut Document, pack_path: &Path) {
    for t in 0..6 {
        let e = stroke(doc, t * 3, 1.5);
        step(doc, &e);
    }
    let basis = pack_of(doc).clusters()[0].bases[1];
    let added = pack_of(doc).with_basis_added(1, basis).expect("add").0;
    step(doc, &on_pack(doc, added));
    let mut light = doc.scene.lights[1];
    if let Light::Point { position, .. } = &mut light {
        *position += DVec3::new(0.1, 0.2, -0.3);
    }
    step(doc, &SceneEdit::Light { index: 1, light });
    step(
        doc,
        &SceneEdit::Ambient(Some(Ambient {
            radiance: DVec3::splat(0.2),
            radius: f64::INFINITY,
        })),
    );
    step(doc, &SceneEdit::LightSamples(3));
    let mut floor = doc.scene.materials[0].clone();
    if let Material::Brdf { albedo, .. } = &mut floor {
        *albedo = DVec3::new(0.2, 0.4, 0.6);
    }
    step(
        doc,
        &SceneEdit::Material {
            index: 0,
            material: floor,
        },
    );
    doc.undo();
    doc.undo();
    doc.redo();
    doc.save_pack(pack_path).expect("save");
    // A drag: several edits in one group.
    for t in 0..3 {
        let e = stroke(doc, 7 + t, 0.75);
        doc.apply(&e).expect("drag");
    }
    doc.close_group();
    let mut camera = doc.scene.camera;
    camera.position.x += 0.5;
    doc.apply_view(&SceneEdit::Camera(camera)).expect("camera");
    let off = pack_of(doc).with_cluster_residual_off(0).expect("off");
    step(doc, &on_pack(doc, off));
    doc.undo();
    let e = stroke(doc, 11, 2.0);
    step(doc, &e);
}

fn only_journal(dir: &Path) -> PathBuf {
    let files = journal::journal_files(dir);
    assert_eq!(files.len(), 1, "one journal: {files:?}");
    files[0].clone()
}

#[test]
fn a_journal_replayed_gives_the_live_document() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, pack_path) = scene_with_pack(tmp.path());
    let state = tmp.path().join("state");
    let mut live = Document::new(scene.clone(), Some(tmp.path().join("scene.toml")));
    live.journal_to(&state);
    edit_session(&mut live, &pack_path);
    live.journal().expect("journal").flush().expect("flush");
    let path = only_journal(&state);
    assert!(journal::is_live(&path), "the session holds its journal");
    let contents = journal::read(&path).expect("read");
    assert!(contents.cut_at.is_none());
    assert!(contents.edits() > 0);

    // The studio's restore: the scene opened again, the journal replayed.
    let (fresh_scene, _) = (scene_from_disk(&scene, &pack_path), ());
    let mut restored = Document::new(fresh_scene, Some(tmp.path().join("scene.toml")));
    let replayed = restored.replay(&contents).expect("replay");
    assert!(replayed.lost.is_empty(), "{:?}", replayed.lost);
    assert_same(&restored, &live);
    // `meso recover apply`: the pack alone.
    let (m, precision) = recover::pack_of(&contents).expect("pack");
    assert!(m.stores_same(&pack_of(&live)));
    assert_eq!(precision, ResidualPrecision::F16);
    // A restore is one undo step back to the files.
    restored.undo();
    assert!(!restored.dirty());
    drop(live);
    assert!(
        !journal::is_live(&path),
        "a dropped session leaves its journal unlocked"
    );
    assert_eq!(journal::journal_files(&state).len(), 1, "and kept");
}

/// The scene as opening its file again gives it: the pack read from disk.
fn scene_from_disk(scene: &Scene, pack_path: &Path) -> Scene {
    let mut s = scene.clone();
    let (m, _) = read_pack_file(pack_path).expect("read");
    if let Material::Spmm { material, .. } = &mut s.materials[1] {
        *material = m;
    }
    s
}

#[test]
fn a_journal_cut_at_any_byte_restores_every_whole_record_before_the_cut() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, pack_path) = scene_with_pack(tmp.path());
    let state = tmp.path().join("state");
    let mut live = Document::new(scene.clone(), None);
    live.journal_to(&state);
    for t in 0..4 {
        let e = stroke(&live, t * 5, 1.25);
        step(&mut live, &e);
    }
    step(&mut live, &SceneEdit::LightSamples(2));
    live.journal().expect("journal").flush().expect("flush");
    let path = only_journal(&state);
    let bytes = std::fs::read(&path).expect("bytes");
    let full = journal::parse(&path, &bytes).expect("parse");
    assert!(
        recover::pack_of(&full)
            .expect("pack")
            .0
            .stores_same(&pack_of(&live))
    );
    // The states after each whole record, replayed from the full journal.
    let mut header_end = None;
    for cut in 0..bytes.len() {
        match journal::parse(&path, &bytes[..cut]) {
            Err(_) => assert!(
                header_end.is_none(),
                "a cut at {cut} after the header fails"
            ),
            Ok(c) => {
                header_end.get_or_insert(cut);
                let n = c.records.len();
                assert_eq!(c.records, full.records[..n], "cut at {cut}");
                let whole_prefix = c.cut_at.is_none();
                assert_eq!(
                    whole_prefix,
                    record_boundaries(&bytes).contains(&cut),
                    "cut at {cut}"
                );
                let mut doc = Document::new(scene_from_disk(&scene, &pack_path), None);
                doc.replay(&c).expect("a cut journal replays");
                let mut want = Document::new(scene_from_disk(&scene, &pack_path), None);
                want.replay(&journal::Contents {
                    records: full.records[..n].to_vec(),
                    cut_at: None,
                    header: full.header.clone(),
                })
                .expect("prefix");
                assert_same(&doc, &want);
            }
        }
    }
    assert!(header_end.is_some());
    drop(live);
}

/// Offsets where a whole record ends (the magic, then each frame).
fn record_boundaries(bytes: &[u8]) -> Vec<usize> {
    let mut at = journal::MAGIC.len();
    let mut out = vec![];
    while at + 12 <= bytes.len() {
        let len = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        at += 12 + len;
        out.push(at);
    }
    out
}

#[test]
fn a_full_disk_loses_neither_the_edits_nor_the_file() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, pack_path) = scene_with_pack(tmp.path());
    let on_disk = std::fs::read(&pack_path).expect("bytes");
    let state = tmp.path().join("state");
    let mut doc = Document::new(scene, None);
    doc.journal_to(&state);
    let e = stroke(&doc, 2, 3.0);
    step(&mut doc, &e);
    doc.set_pack_writer(Box::new(|_, _| {
        Err("No space left on device (os error 28)".into())
    }));
    let err = doc.save_pack(&pack_path).expect_err("the disk is full");
    assert!(
        matches!(err, SaveError::Write(ref m) if m.contains("No space")),
        "{err}"
    );
    assert!(doc.dirty(), "the edits stay");
    assert_eq!(
        std::fs::read(&pack_path).expect("bytes"),
        on_disk,
        "the file is intact"
    );
    doc.journal().expect("journal").flush().expect("flush");
    let path = only_journal(&state);
    assert!(
        journal::read(&path).expect("read").edits() > 0,
        "the journal keeps the edits"
    );
    // Space again: the save succeeds and, with no scene edit left, the journal goes.
    doc.set_pack_writer(Box::new(|p, b| {
        meso_materials::atomic::write_bytes_atomic(p, b).map_err(|e| e.to_string())
    }));
    doc.save_pack(&pack_path).expect("save");
    assert!(!doc.dirty());
    assert!(
        journal::journal_files(&state).is_empty(),
        "a clean save removes the journal"
    );
    let (m, _) = read_pack_file(&pack_path).expect("read");
    assert!(m.stores_same(&pack_of(&doc)));
}

#[test]
fn a_journal_that_cannot_be_written_keeps_the_edits_in_memory() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, _) = scene_with_pack(tmp.path());
    // A state folder that is a file: the journal cannot start; editing goes on.
    let blocked = tmp.path().join("blocked");
    std::fs::write(&blocked, b"").expect("file");
    let mut doc = Document::new(scene, None);
    doc.journal_to(&blocked.join("sessions"));
    let e = stroke(&doc, 2, 3.0);
    step(&mut doc, &e);
    assert!(doc.dirty());
    assert!(doc.journal_error().is_some_and(|e| e.contains("blocked")));
}

#[test]
fn a_pack_changed_on_disk_is_not_overwritten_unasked() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, pack_path) = scene_with_pack(tmp.path());
    let mut doc = Document::new(scene, None);
    let e = stroke(&doc, 4, 2.0);
    step(&mut doc, &e);
    assert_eq!(doc.pack_changed_on_disk(), None);
    // Another program (a `meso pack edit` script) writes the file.
    let (theirs, _) = read_pack_file(&pack_path).expect("read");
    let theirs = theirs
        .with_weight_scale(&WeightTarget::cluster(0), [0.5; 3])
        .expect("scale");
    pack::write_pack(&pack_path, &theirs, ResidualPrecision::F16).expect("write");
    let theirs_bytes = std::fs::read(&pack_path).expect("bytes");
    assert_eq!(doc.pack_changed_on_disk(), Some(pack_path.clone()));
    assert_eq!(
        doc.save_pack(&pack_path),
        Err(SaveError::ChangedOnDisk(pack_path.clone()))
    );
    assert_eq!(
        std::fs::read(&pack_path).expect("bytes"),
        theirs_bytes,
        "their file stays"
    );
    assert!(doc.dirty());
    // Reload theirs (one undo step: undo brings ours back).
    let mine = pack_of(&doc);
    doc.reload_pack().expect("reload");
    assert!(pack_of(&doc).stores_same(&read_pack_file(&pack_path).expect("read").0));
    assert_eq!(doc.pack_changed_on_disk(), None);
    doc.undo();
    assert!(pack_of(&doc).stores_same(&mine));
    // Or overwrite, as asked; or save as another file.
    doc.save_pack_over(&pack_path).expect("overwrite");
    assert!(
        read_pack_file(&pack_path)
            .expect("read")
            .0
            .stores_same(&mine)
    );
    let e = stroke(&doc, 5, 2.0);
    step(&mut doc, &e);
    std::fs::write(&pack_path, b"not a pack any more").expect("clobber");
    let other = tmp.path().join("mine.spmm");
    doc.save_pack(&other).expect("save as");
    assert_eq!(doc.pack.as_ref().and_then(|p| p.path.clone()), Some(other));
}

#[test]
fn undo_stays_within_its_budget_and_says_what_it_dropped() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, _) = scene_with_pack(tmp.path());
    let mut doc = Document::new(scene, None);
    let budget = 16 << 10;
    doc.set_undo_budget(budget);
    let mut states = vec![pack_of(&doc)];
    for t in 0..400 {
        let e = stroke(&doc, t, if t % 2 == 0 { 1.5 } else { 0.8 });
        step(&mut doc, &e);
        states.push(pack_of(&doc));
    }
    let stats = doc.undo_stats();
    assert!(stats.bytes <= budget, "{stats:?}");
    assert!(
        stats.dropped > 0 && stats.steps + stats.dropped == 400,
        "{stats:?}"
    );
    // Each kept step undoes to exactly the state it was taken at.
    for k in (0..stats.steps).rev() {
        doc.undo();
        assert!(
            pack_of(&doc).stores_same(&states[stats.dropped + k]),
            "undo to {k}"
        );
    }
    assert!(!doc.can_undo());
    for k in 0..stats.steps {
        doc.redo();
        assert!(
            pack_of(&doc).stores_same(&states[stats.dropped + k + 1]),
            "redo to {k}"
        );
    }
}

#[test]
fn a_stroke_step_holds_its_texels_not_a_copy_of_the_pack() {
    let tmp = tempfile::tempdir().expect("tmp");
    let mut scene = edit_test_scene();
    let big = meso_materials::spmm::testing::sample_material(128, 128, 4, Some(4));
    let path = tmp.path().join("big.spmm");
    pack::write_pack(&path, &big, ResidualPrecision::F32).expect("write");
    scene.materials[1] = Material::Spmm {
        material: read_pack_file(&path).expect("read").0,
        uv_scale: glam::DVec2::ONE,
        residual: true,
        npca: 4,
    };
    scene.material_files = vec![None, Some(path)];
    let mut doc = Document::new(scene, None);
    for t in 0..50 {
        let e = stroke(&doc, t * 31, 1.1);
        step(&mut doc, &e);
    }
    let per_step = doc.undo_stats().bytes / 50;
    let whole = std::fs::metadata(tmp.path().join("big.spmm"))
        .expect("meta")
        .len() as usize;
    assert!(
        per_step * 100 < whole,
        "{per_step} bytes a stroke step, the pack is {whole}"
    );
}

#[test]
fn scripts_edit_as_the_command_line_does() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, _) = scene_with_pack(tmp.path());
    let script = Script::parse(
        &tmp.path().join("s.toml"),
        r#"
[[edit]]
pack = "--cluster 0 --basis 1 --scale 1.5,1.5,1.2"
[[edit]]
wait_ms = 0
[[edit]]
pack = "--cluster 1 --scale 0.5 --brush 1.5,1.5,1"
[[edit]]
scene = "light 1 position=0.5,1,0.25"
[[edit]]
scene = "material 0 albedo=0.3,0.3,0.3"
[[edit]]
scene = "ambient off"
"#,
    )
    .expect("script");
    let mut doc = Document::new(scene.clone(), None);
    let mut runner = Runner::new(script);
    let now = std::time::Instant::now();
    let mut applied = 0;
    while !runner.done() {
        for i in runner.due(now) {
            let e = runner
                .script
                .edit_on(i, &doc)
                .expect("edit")
                .expect("not a wait");
            step(&mut doc, &e);
            applied += 1;
        }
    }
    assert_eq!(applied, 5);
    let start = pack_of(&Document::new(scene, None));
    let mut dab = TexelMask::empty(start.width(), start.height());
    dab.stamp(
        glam::DVec2::new(1.5, 1.5),
        1.0,
        1.0,
        meso_materials::spmm::Falloff::Linear,
    );
    let want = start
        .with_weight_scale(&WeightTarget::basis(0, 1), [1.5, 1.5, 1.2])
        .and_then(|m| m.with_weight_scale(&WeightTarget::cluster(1).within(&dab), [0.5; 3]))
        .expect("edits");
    assert!(pack_of(&doc).stores_same(&want));
    assert_eq!(
        doc.scene.lights[1],
        Light::Point {
            position: DVec3::new(0.5, 1.0, 0.25),
            intensity: DVec3::new(1.0, 0.5, 0.2)
        }
    );
    assert_eq!(doc.scene.ambient, None);
    assert!(
        matches!(doc.scene.materials[0], Material::Brdf { albedo, .. } if albedo == DVec3::splat(0.3))
    );
    assert_eq!(
        doc.undo_stats().steps,
        5,
        "each scripted edit is one undo step"
    );
}

#[test]
fn bad_scripts_name_the_edit_and_key_at_fault() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, _) = scene_with_pack(tmp.path());
    let doc = Document::new(scene, None);
    let p = tmp.path().join("bad.toml");
    for (text, needle) in [
        ("[[edit]]\npack = 3", "edit 1: `pack` must be a string"),
        ("[[edit]]\nwait_ms = -1", "edit 1: `wait_ms`"),
        ("[[edit]]\nscene = \"x\"\npack = \"\"", "edit 1: has 2 keys"),
        (
            "[[edit]]\nwait_ms = 1\n[[edit]]\nscene = \"teleport 3\"",
            "edit 2: scene: unknown command `teleport`",
        ),
        ("[[edit]]\nfoo = 1", "unknown key `foo`"),
        ("[[edit]]\npack = \"--scale 2\"", "no --cluster"),
        ("[edits]", "bad.toml"),
    ] {
        let err = Script::parse(&p, text).expect_err(text);
        assert!(err.contains(needle), "{text}: {err}");
    }
    for (command, needle) in [
        ("light 7 position=1,2,3", "light 7 does not exist"),
        ("light 0 position=1,2,3", "is not a key of light 0"),
        ("material 0 roughness=3", "material 0"),
        ("environment strength=2", "no environment"),
        ("camera position=1,2", "three"),
    ] {
        let s = Script::parse(&p, &format!("[[edit]]\nscene = \"{command}\"")).expect("parses");
        let err = s.edit_on(0, &doc).expect_err(command);
        assert!(err.contains(needle), "{command}: {err}");
    }
}

#[test]
fn recover_lists_sessions_and_refuses_to_discard_a_live_one() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (scene, _) = scene_with_pack(tmp.path());
    let state = tmp.path().join("state");
    let mut doc = Document::new(scene, Some(tmp.path().join("scene.toml")));
    doc.journal_to(&state);
    assert!(
        recover::list(&state).0.is_empty(),
        "no journal before the first edit"
    );
    let e = stroke(&doc, 1, 2.0);
    step(&mut doc, &e);
    step(&mut doc, &SceneEdit::LightSamples(4));
    doc.journal().expect("journal").flush().expect("flush");
    let (sessions, unreadable) = recover::list(&state);
    assert!(unreadable.is_empty());
    assert_eq!(sessions.len(), 1);
    let s = &sessions[0];
    assert!(s.live);
    assert_eq!(s.edits, 2);
    assert_eq!(
        s.packs,
        vec![std::path::absolute(tmp.path().join("panel.spmm")).unwrap()]
    );
    assert!(
        recover::restorable(&state).is_empty(),
        "a live session is not offered"
    );
    assert!(
        recover::discard(&s.journal)
            .expect_err("live")
            .contains("running session")
    );
    doc.close_journal(false);
    assert_eq!(recover::restorable(&state).len(), 1);
    recover::discard(&s.journal).expect("discard");
    assert!(recover::list(&state).0.is_empty());
    let _ = Record::Unrecorded(String::new()).is_edit();
}
