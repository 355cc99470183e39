//! `meso recover`: the studio's recovery journals from the command line. `list`
//! shows the sessions in the state folder (`MESO_STATE_DIR` or the platform's),
//! `apply` writes the edited pack a journal ends with (atomically), `discard` removes
//! a journal. A journal cut mid-record gives everything before the cut.

use std::path::PathBuf;

use anyhow::anyhow;
use clap::Subcommand;
use meso_session::journal;
use meso_session::recover;
use serde_json::json;

use crate::failure::CliError;

#[derive(Subcommand, Debug)]
pub enum RecoverCommand {
    /// Sessions with a journal: their scene and packs, edit counts, times, whether live.
    List {
        /// The folder holding `sessions/` (default: MESO_STATE_DIR, else
        /// $XDG_STATE_HOME/meso, else ~/.local/state/meso).
        #[arg(long)]
        state_dir: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Write the edited pack as the journal ends with it.
    Apply {
        journal: PathBuf,
        #[arg(short = 'o', long)]
        output: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Remove a journal (refused while its session runs).
    Discard { journal: PathBuf },
}

pub fn run(command: RecoverCommand) -> Result<(), CliError> {
    match command {
        RecoverCommand::List { state_dir, json } => {
            let dir = state_dir.map_or_else(journal::sessions_dir, |d| d.join("sessions"));
            let (sessions, unreadable) = recover::list(&dir);
            for u in &unreadable {
                eprintln!("warning: {u}");
            }
            if json {
                return crate::print_json(&json!({ "sessions": sessions }));
            }
            if sessions.is_empty() {
                println!("no sessions in {}", dir.display());
            }
            for s in &sessions {
                println!(
                    "{}\n  scene {}\n  packs {}\n  {} edits, {} to {}{}",
                    s.journal.display(),
                    s.scene
                        .as_ref()
                        .map_or("(built in)".into(), |p| p.display().to_string()),
                    s.packs
                        .iter()
                        .map(|p| p.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", "),
                    s.edits,
                    s.started,
                    s.last_edit,
                    if s.live { " (live)" } else { "" }
                );
            }
            Ok(())
        }
        RecoverCommand::Apply {
            journal: path,
            output,
            json,
        } => {
            let contents = journal::read(&path).map_err(|e| CliError::bad_input(anyhow!(e)))?;
            let (material, precision) = recover::pack_of(&contents)
                .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", path.display())))?;
            meso_materials::spmm::pack::write_pack(&output, &material, precision)
                .map_err(CliError::failure)?;
            let cut = contents.cut_at;
            if let Some(at) = cut {
                eprintln!(
                    "warning: `{}` ends in a cut record at byte {at}: the edits before it were applied",
                    path.display()
                );
            }
            if json {
                return crate::print_json(&json!({
                    "journal": path.display().to_string(),
                    "output": output.display().to_string(),
                    "edits": contents.edits(),
                    "cut_at": cut,
                }));
            }
            println!(
                "wrote {} ({} journaled edits applied)",
                output.display(),
                contents.edits()
            );
            Ok(())
        }
        RecoverCommand::Discard { journal: path } => {
            recover::discard(&path).map_err(|e| CliError::bad_input(anyhow!(e)))?;
            println!("removed {}", path.display());
            Ok(())
        }
    }
}
