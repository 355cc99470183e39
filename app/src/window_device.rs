//! The window's wgpu device, made so the GPU mode can render on it too: eframe is asked
//! for a device with the limits the mode needs (`wgpu_configuration`), and the studio's
//! registry is given that device (`modes_for`), or, when it cannot be shared, told why
//! so each GPU mode makes its own and the status bar says so. On a shared device a
//! frame reaches the window without leaving it (the viewport's `DisplayTexture`,
//! docs/gpu.md "No round trip").

use std::sync::Arc;

use eframe::egui_wgpu::{RenderState, WgpuConfiguration, WgpuSetup};
use eframe::wgpu;
use meso_gpu::GpuContext;

use meso_viewport::maker::CoreModes;

/// eframe's wgpu set-up with the window's device asked for with the GPU mode's limits
/// (`GpuContext::needed_limits`) on top of what egui asks (8192-texel textures for 4k
/// surfaces). A GL adapter keeps egui's WebGL2 limits: its device is not shared.
pub fn wgpu_configuration() -> WgpuConfiguration {
    let mut config = WgpuConfiguration::default();
    if let WgpuSetup::CreateNew(create) = &mut config.wgpu_setup {
        create.device_descriptor = Arc::new(device_descriptor);
    }
    config
}

/// The window's device request on `adapter` (`wgpu_configuration`).
pub fn device_descriptor(adapter: &wgpu::Adapter) -> wgpu::DeviceDescriptor<'static> {
    let base = if adapter.get_info().backend == wgpu::Backend::Gl {
        wgpu::Limits::downlevel_webgl2_defaults()
    } else {
        GpuContext::needed_limits(adapter)
    };
    wgpu::DeviceDescriptor {
        label: Some("meso window and gpu mode"),
        required_limits: wgpu::Limits {
            max_texture_dimension_2d: base.max_texture_dimension_2d.max(8192),
            ..base
        },
        ..Default::default()
    }
}

/// The studio's registry for a window drawn by `render_state` (`None`: not drawn by
/// wgpu, or headless): GPU modes on the window's device when it can be shared.
pub fn modes_for(render_state: Option<&RenderState>) -> CoreModes {
    let Some(rs) = render_state else {
        return CoreModes::default();
    };
    match GpuContext::from_device(&rs.adapter, rs.device.clone(), rs.queue.clone()) {
        Ok(ctx) => CoreModes::on_device(ctx),
        Err(e) => CoreModes::unshared(e.to_string()),
    }
}
