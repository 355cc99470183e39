//! Where the studio gets its render modes: `supports` (can this mode render this
//! scene, and if not, which parts stop it) and `create` (prepare the mode, with
//! progress and cancel). The studio and its render thread ask a `ModeMaker`, never a
//! mode's type; the default is core's registry (`meso_core::modes`), and tests inject
//! slow or refusing makers to drive the mode switch through the real window.

use std::sync::Arc;

use meso_core::modes;
use meso_core::render::{Device, ModeError, ModeKind, Prepare, RenderMode};
use meso_core::scene::Scene;

/// Makes render modes by kind and device.
pub trait ModeMaker: Send + Sync {
    /// `Ok` if the mode exists and can render everything in `scene`.
    fn supports(&self, kind: ModeKind, device: Device, scene: &Scene) -> Result<(), ModeError>;

    /// Prepares the mode for `scene` at `width` x `height`, reporting progress and
    /// stopping when `prepare`'s cancel flag is set.
    fn create(
        &self,
        kind: ModeKind,
        device: Device,
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Box<dyn RenderMode>, ModeError>;
}

/// Core's registry: the modes this build has.
#[derive(Clone, Copy, Debug, Default)]
pub struct CoreModes;

impl ModeMaker for CoreModes {
    fn supports(&self, kind: ModeKind, device: Device, scene: &Scene) -> Result<(), ModeError> {
        modes::supports(kind, device, scene)
    }

    fn create(
        &self,
        kind: ModeKind,
        device: Device,
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Box<dyn RenderMode>, ModeError> {
        modes::create(kind, device, scene, width, height, prepare)
    }
}

/// The maker the studio uses unless told otherwise.
pub fn core_modes() -> Arc<dyn ModeMaker> {
    Arc::new(CoreModes)
}

/// A mode and device as the UI names them: "spmm (cpu)".
pub fn mode_name(kind: ModeKind, device: Device) -> String {
    format!("{} ({})", kind.name(), device.name())
}
