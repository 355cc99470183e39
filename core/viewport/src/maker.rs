//! Where the studio gets its render modes: `supports` (can this mode render this
//! scene, and if not, which parts stop it) and `create` (prepare the mode, with
//! progress and cancel). The studio and its render thread ask a `ModeMaker`, never a
//! mode's type; the default is core's registry (`meso_modes`), and tests inject
//! slow or refusing makers to drive the mode switch through the real window. Given the
//! window's wgpu device (`CoreModes::on_device`), the GPU mode renders on it.

use std::sync::Arc;

#[cfg(feature = "gpu")]
use meso_gpu::GpuContext;
use meso_modes::GpuDevice;
use meso_render::scene::Scene;
use meso_render::{Device, ModeError, ModeKind, Prepare, RenderMode};

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

/// Core's registry: the modes this build has; the GPU mode on `gpu` when set (the
/// window's device, shared), else on a device of its own made per mode, which says
/// why the window's was not shared when `unshared` holds a reason.
#[derive(Clone, Debug, Default)]
pub struct CoreModes {
    #[cfg(feature = "gpu")]
    gpu: Option<GpuContext>,
    unshared: Option<String>,
}

impl CoreModes {
    /// The registry with every GPU mode on `gpu` (cloned: one device for all).
    #[cfg(feature = "gpu")]
    pub fn on_device(gpu: GpuContext) -> Self {
        Self {
            gpu: Some(gpu),
            unshared: None,
        }
    }

    /// The registry with GPU modes on devices of their own, because the window's
    /// device could not be shared (`why`, shown in the status bar).
    pub fn unshared(why: impl Into<String>) -> Self {
        Self {
            #[cfg(feature = "gpu")]
            gpu: None,
            unshared: Some(why.into()),
        }
    }

    /// The device GPU modes are made on, if one was given.
    #[cfg(feature = "gpu")]
    pub fn gpu(&self) -> Option<&GpuContext> {
        self.gpu.as_ref()
    }
}

impl ModeMaker for CoreModes {
    fn supports(&self, kind: ModeKind, device: Device, scene: &Scene) -> Result<(), ModeError> {
        meso_modes::supports(kind, device, scene)
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
        let gpu = match self.unshared.as_deref() {
            Some(why) => GpuDevice::OwnBecause(why),
            None => GpuDevice::Own,
        };
        #[cfg(feature = "gpu")]
        let gpu = self.gpu.as_ref().map_or(gpu, GpuDevice::Shared);
        let mode = meso_modes::create_on(gpu, kind, device, scene, width, height, prepare)?;
        // The viewport filters the first frames: a GPU mode's filter kernels are made
        // here, while the mode is prepared off the UI's and the render's path.
        mode.prepare_denoiser();
        Ok(mode)
    }
}

/// The maker the studio uses unless told otherwise.
pub fn core_modes() -> Arc<dyn ModeMaker> {
    Arc::new(CoreModes::default())
}

/// A mode and device as the UI names them: "spmm (cpu)".
pub fn mode_name(kind: ModeKind, device: Device) -> String {
    format!("{} ({})", kind.name(), device.name())
}
