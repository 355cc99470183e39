//! `--mode` and `--device`, shared by the subcommands that render (docs/cli.md): they
//! override the scene's `[render] mode` and `device`; a mode that cannot render the
//! scene, or is not built, is bad input (exit 2) naming why, never a fallback.

use anyhow::anyhow;
use clap::Args;
use meso_render::scene::Scene;
use meso_render::{Device, ModeError, ModeKind};

use crate::failure::CliError;

#[derive(Args, Debug, Clone)]
pub struct ModeArgs {
    /// Render mode: spmm | biscale | adaptive (default: the scene's `[render] mode`).
    #[arg(long, value_parser = parse_mode)]
    pub mode: Option<ModeKind>,
    /// Where the mode runs: cpu | gpu (default: the scene's `[render] device`).
    #[arg(long, value_parser = parse_device)]
    pub device: Option<Device>,
}

fn parse_mode(s: &str) -> Result<ModeKind, String> {
    ModeKind::from_name(s).ok_or_else(|| format!("`{s}`: modes are spmm, biscale, adaptive"))
}

fn parse_device(s: &str) -> Result<Device, String> {
    Device::from_name(s).ok_or_else(|| format!("`{s}`: devices are cpu, gpu"))
}

impl ModeArgs {
    /// The mode and device for `scene`, checked: exit 2 if it cannot render it.
    pub fn resolve(&self, scene: &Scene) -> Result<(ModeKind, Device), CliError> {
        let kind = self.mode.unwrap_or(scene.render.mode);
        let device = self.device.unwrap_or(scene.render.device);
        meso_modes::supports(kind, device, scene).map_err(mode_error)?;
        Ok((kind, device))
    }
}

/// A mode that cannot be made is the input's fault (exit 2), except a cancelled one.
pub fn mode_error(e: ModeError) -> CliError {
    match e {
        ModeError::Cancelled(_) | ModeError::DeviceFailed(_) => CliError::failure(anyhow!(e)),
        _ => CliError::bad_input(anyhow!(e)),
    }
}
