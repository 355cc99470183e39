//! An editing session below any window: the document the editor edits with undo
//! under a memory budget (`document.rs`, `undo.rs`), the recovery journal that keeps
//! every edit on disk as it happens (`journal/`), reading journals back (`recover.rs`:
//! `meso recover` and the studio's restore), scripted sessions (`script.rs`:
//! `meso-studio --run`), and the pack-edit language scripts share with `meso pack
//! edit` (`pack_edits.rs`).

pub mod document;
pub mod journal;
pub mod pack_edits;
pub mod recover;
pub mod script;
mod undo;

pub use document::{Document, SaveError, UndoStats};
pub use undo::DEFAULT_BUDGET as DEFAULT_UNDO_BUDGET;

#[cfg(test)]
mod tests;
