//! The wgpu instance, adapter and device the GPU mode runs on. The backends come from
//! `WGPU_BACKEND` (wgpu's own variable; CI sets `vulkan` for Mesa's lavapipe), so a
//! backend that does not exist on this system yields no adapter and a one-line error.
//! A context is either the mode's own device or one made elsewhere (the studio's
//! window) and shared, if its limits are what the mode needs (`from_device`).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Why there is no device to render on.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum GpuError {
    #[error("no GPU adapter found for the backends {backends} (WGPU_BACKEND={env})")]
    NoAdapter { backends: String, env: String },
    #[error("the GPU adapter `{adapter}` refused a device: {reason}")]
    NoDevice { adapter: String, reason: String },
    /// The device stopped working (lost, destroyed, or an error on it): nothing it
    /// returns from here on can be trusted.
    #[error("the GPU `{adapter}` failed: {reason}")]
    Lost { adapter: String, reason: String },
    /// A device made elsewhere lacks what the mode needs (`GpuContext::from_device`).
    #[error("the device on `{adapter}` cannot be shared: {reason}")]
    NotShareable { adapter: String, reason: String },
}

/// Whose device a context renders on, for status lines.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Sharing {
    /// A device of its own (`new`, `from_adapter`).
    Own,
    /// A device made elsewhere, the studio's window's (`from_device`).
    Shared,
    /// A device of its own because the one made elsewhere could not be shared: why.
    OwnBecause(String),
}

/// True for an adapter that is a GPU (discrete, integrated or virtual), false for a
/// software rasteriser (lavapipe/llvmpipe, WARP) or an unknown kind.
pub fn is_hardware(device_type: wgpu::DeviceType) -> bool {
    matches!(
        device_type,
        wgpu::DeviceType::DiscreteGpu
            | wgpu::DeviceType::IntegratedGpu
            | wgpu::DeviceType::VirtualGpu
    )
}

/// The name of the first hardware adapter of the backends `WGPU_BACKEND` names
/// (`None`: only software adapters, or none), found once per process: the studio
/// renders on the GPU by default when there is one.
pub fn hardware_adapter() -> Option<String> {
    static FOUND: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    FOUND
        .get_or_init(|| {
            let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
            let backends = desc.backends;
            let instance = wgpu::Instance::new(desc);
            pollster::block_on(instance.enumerate_adapters(backends))
                .iter()
                .map(|a| a.get_info())
                .find(|i| is_hardware(i.device_type))
                .map(|i| format!("{} ({})", i.name, i.backend))
        })
        .clone()
}

/// One adapter's device and queue, shareable between modes (cloning shares them).
#[derive(Clone)]
pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    info: Arc<wgpu::AdapterInfo>,
    limits: wgpu::Limits,
    sharing: Sharing,
    /// The first failure the device reported (lost, or an error no one caught), kept
    /// here instead of wgpu's default of panicking on the thread that noticed it.
    failure: Arc<Mutex<Option<String>>>,
    /// Bytes read back from the device since it was made (all clones together).
    read_back: Arc<AtomicU64>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.adapter_name())
            .finish()
    }
}

impl GpuContext {
    /// The first adapter of the backends `WGPU_BACKEND` names (all by default),
    /// preferring a high-performance one, with a device of the limits the mode needs
    /// (`needed_limits`).
    pub fn new() -> Result<Self, GpuError> {
        let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        let backends = desc.backends;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|_| GpuError::NoAdapter {
            backends: format!("{backends:?}"),
            env: std::env::var("WGPU_BACKEND").unwrap_or_else(|_| "unset".into()),
        })?;
        Self::from_adapter(&adapter)
    }

    /// A device on `adapter` (the studio passes the one its window uses).
    pub fn from_adapter(adapter: &wgpu::Adapter) -> Result<Self, GpuError> {
        let info = adapter.get_info();
        // The limits the studio's shared device has (`needed_limits`), not the
        // adapter's own: a kernel that needs more (a ninth storage buffer) fails here,
        // in every test, as it would in the studio.
        let limits = Self::needed_limits(adapter);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("meso gpu"),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoDevice {
            adapter: info.name.clone(),
            reason: e.to_string(),
        })?;
        Ok(Self::watching(device, queue, info, limits, Sharing::Own))
    }

    /// The limits the mode needs of a device on `adapter`: WebGPU's defaults (eight
    /// storage buffers per stage, 64-invocation workgroups) with the adapter's largest
    /// buffers, since one sample's film and the scene's data each sit in one buffer.
    /// The studio asks for these when it makes its window's device, so it can share it.
    pub fn needed_limits(adapter: &wgpu::Adapter) -> wgpu::Limits {
        let allowed = adapter.limits();
        wgpu::Limits {
            max_buffer_size: allowed.max_buffer_size,
            max_storage_buffer_binding_size: allowed.max_storage_buffer_binding_size,
            ..wgpu::Limits::default()
        }
    }

    /// A context on `device` and `queue`, made elsewhere on `adapter` (the studio's
    /// window's): the mode renders on them instead of a device of its own. Refused,
    /// naming each limit, when the device was made with less than `needed_limits` or
    /// the adapter has no compute shaders.
    ///
    /// wgpu keeps one uncaptured-error handler and one lost callback per device; this
    /// takes both (eframe 0.37 sets neither), so an error on the device, the window's
    /// drawing included, is recorded as the mode's failure (the studio goes on on the
    /// CPU) instead of wgpu's default panic, which would close the window.
    pub fn from_device(
        adapter: &wgpu::Adapter,
        device: wgpu::Device,
        queue: wgpu::Queue,
    ) -> Result<Self, GpuError> {
        let info = adapter.get_info();
        let limits = device.limits();
        let compute = adapter
            .get_downlevel_capabilities()
            .flags
            .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS);
        let problem = if compute {
            shortfall(&Self::needed_limits(adapter), &limits)
        } else {
            Some("the adapter runs no compute shaders".into())
        };
        if let Some(reason) = problem {
            return Err(GpuError::NotShareable {
                adapter: format!("{} ({})", info.name, info.backend),
                reason,
            });
        }
        Ok(Self::watching(device, queue, info, limits, Sharing::Shared))
    }

    /// `device` with its failures recorded in the context (`failure`).
    fn watching(
        device: wgpu::Device,
        queue: wgpu::Queue,
        info: wgpu::AdapterInfo,
        limits: wgpu::Limits,
        sharing: Sharing,
    ) -> Self {
        let failure = Arc::new(Mutex::new(None));
        let record = |failure: &Arc<Mutex<Option<String>>>, reason: String| {
            if let Ok(mut f) = failure.lock() {
                f.get_or_insert(reason);
            }
        };
        let lost = Arc::clone(&failure);
        device.set_device_lost_callback(move |why, message| {
            record(&lost, format!("device lost ({why:?}): {message}"));
        });
        let errors = Arc::clone(&failure);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            record(&errors, e.to_string());
        }));
        Self {
            device,
            queue,
            info: Arc::new(info),
            limits,
            sharing,
            failure,
            read_back: Arc::default(),
        }
    }

    /// This context, a device of its own, marked as made because a shared one could
    /// not be (`reason`), so status lines say why the window's device is not used.
    pub fn own_because(mut self, reason: impl Into<String>) -> Self {
        self.sharing = Sharing::OwnBecause(reason.into());
        self
    }

    /// Whose device this is.
    pub fn sharing(&self) -> &Sharing {
        &self.sharing
    }

    /// True when `other` is this context or a clone of it: the same device. (wgpu's
    /// own `Device` equality compares ids, which devices of different instances can
    /// share.)
    pub fn same_device(&self, other: &GpuContext) -> bool {
        Arc::ptr_eq(&self.failure, &other.failure)
    }

    /// True when the device was made elsewhere and is shared (`from_device`).
    pub fn is_shared(&self) -> bool {
        self.sharing == Sharing::Shared
    }

    /// The device's first failure, if it has failed: every later result is void.
    pub fn failure(&self) -> Option<GpuError> {
        let reason = self.failure.lock().ok()?.clone()?;
        Some(self.lost(reason))
    }

    /// Bytes read back from the device so far, by every user of this context (a frame
    /// of the GPU mode reads back only its counters; docs/gpu.md).
    pub fn bytes_read_back(&self) -> u64 {
        self.read_back.load(Ordering::Relaxed)
    }

    pub(super) fn count_read_back(&self, bytes: u64) {
        self.read_back.fetch_add(bytes, Ordering::Relaxed);
    }

    /// A failure of this device for `reason`.
    pub(super) fn lost(&self, reason: impl Into<String>) -> GpuError {
        GpuError::Lost {
            adapter: self.adapter_name(),
            reason: reason.into(),
        }
    }

    /// The adapter's name and backend, for status lines (`llvmpipe (vulkan)`).
    pub fn adapter_name(&self) -> String {
        format!("{} ({})", self.info.name, self.info.backend)
    }

    /// True for a software rasteriser (lavapipe/llvmpipe, WARP): correct, not fast.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The adapter's kind (discrete, integrated, CPU, ...).
    pub fn info_type(&self) -> wgpu::DeviceType {
        self.info.device_type
    }

    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// The same device, with buffers limited to `bytes` as far as the mode's checks
    /// go (tests meet the limit without allocating it).
    #[cfg(test)]
    pub(super) fn with_buffer_limit(&self, bytes: u64) -> Self {
        let mut limited = self.clone();
        limited.limits.max_buffer_size = bytes;
        limited.limits.max_storage_buffer_binding_size = bytes;
        limited
    }
}

/// Each limit in `needed` that `got` does not reach, named with both values (`None`:
/// all reached).
fn shortfall(needed: &wgpu::Limits, got: &wgpu::Limits) -> Option<String> {
    let mut short = Vec::new();
    needed.check_limits_with_fail_fn(got, false, |name, needed, got| {
        short.push(format!("{name} is {got}, the GPU mode needs {needed}"));
    });
    (!short.is_empty()).then(|| short.join("; "))
}

#[cfg(test)]
mod tests {
    use super::shortfall;

    #[test]
    fn a_device_with_smaller_buffers_than_needed_is_named_limit_by_limit() {
        let needed = wgpu::Limits {
            max_buffer_size: 1 << 32,
            max_storage_buffer_binding_size: 1 << 31,
            ..wgpu::Limits::default()
        };
        assert_eq!(shortfall(&needed, &needed), None);
        let bigger = wgpu::Limits {
            max_buffer_size: 1 << 33,
            ..needed.clone()
        };
        assert_eq!(shortfall(&needed, &bigger), None);
        let why = shortfall(&needed, &wgpu::Limits::default()).expect("too small");
        assert!(why.contains("max_buffer_size is 268435456"), "{why}");
        assert!(
            why.contains(
                "max_storage_buffer_binding_size is 134217728, the GPU mode needs 2147483648"
            ),
            "{why}"
        );
        let fewer = wgpu::Limits {
            max_storage_buffers_per_shader_stage: 4,
            ..needed.clone()
        };
        let why = shortfall(&needed, &fewer).expect("too few");
        assert!(
            why.contains("max_storage_buffers_per_shader_stage is 4"),
            "{why}"
        );
    }
}
