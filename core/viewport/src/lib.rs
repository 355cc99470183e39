//! The interactive render loop, below any window: the render thread (`worker`) that
//! applies versioned edits and renders progressive frames with a mode from a
//! `ModeMaker` (`maker`), and the viewport denoiser that filters the newest frame
//! beside it (`filter`), never in the frame's path. The studio shows its
//! frames; `meso bench edits` times them without a window.

mod filter;
pub mod maker;
pub mod worker;

pub use maker::{CoreModes, ModeMaker, core_modes, mode_name};
pub use worker::{Command, Frame, Notice, Picture, Rejected, RenderWorker, Wake};
