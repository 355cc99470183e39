//! `meso-studio SCENE --run SCRIPT.toml --headless`: a scripted session without a
//! window, for continuous integration and bug reports on machines with no display.
//! The script's edits go through the document as the panels' do (one undo step each,
//! journaled in the session's recovery journal); no renderer runs. At the end the
//! journal is written out and kept, as after a session that ended without saving:
//! `meso recover` reads it.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use meso_session::Document;
use meso_session::script::{Runner, Script};
use meso_studio::studio::{Settings, default_scene_path};

pub fn run(scene: Option<PathBuf>, script: Script) -> ExitCode {
    let path = scene.unwrap_or_else(default_scene_path);
    let loaded = match meso_render::scene::load_scene(&path) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("meso-studio: `{}`: {e}", path.display());
            return ExitCode::from(2);
        }
    };
    let settings = Settings::default();
    let mut doc = Document::new(loaded, Some(path));
    doc.set_undo_budget(settings.undo_budget_mb << 20);
    doc.journal_to(&settings.sessions_dir());
    let mut runner = Runner::new(script);
    let total = runner.script.edits.len();
    loop {
        let now = Instant::now();
        for i in runner.due(now) {
            let edit = match runner.script.edit_on(i, &doc) {
                Ok(Some(e)) => e,
                Ok(None) => continue,
                Err(e) => {
                    eprintln!("meso-studio: {e}");
                    doc.close_journal(false);
                    return ExitCode::from(2);
                }
            };
            if let Err(e) = doc.apply(&edit) {
                eprintln!("meso-studio: edit {}: {e}", i + 1);
                doc.close_journal(false);
                return ExitCode::from(2);
            }
            doc.close_group();
            if let Some(e) = doc.journal_error() {
                eprintln!("meso-studio: {e}");
            }
            println!("edit {} of {total} applied", i + 1);
        }
        match runner.wait(Instant::now()) {
            Some(d) => std::thread::sleep(d),
            None => break,
        }
    }
    let undo = doc.undo_stats();
    println!(
        "undo: {} steps in {:.1} KiB (budget {} MiB, {} oldest dropped)",
        undo.steps,
        undo.bytes as f64 / 1024.0,
        undo.budget >> 20,
        undo.dropped
    );
    if let Some(j) = doc.journal() {
        if let Err(e) = j.flush() {
            eprintln!("meso-studio: {e}");
        }
        println!("journal: {}", j.path().display());
    }
    doc.close_journal(false);
    ExitCode::SUCCESS
}
