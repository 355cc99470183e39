//! The device itself: hardware and software adapters, a device lost while rendering,
//! and a device shared with the studio's window (or refused for too low limits).

use meso_render::RenderModeExt;

use crate::GpuContext;

use super::{context, gpu_mode, mean, test_scene};

/// Only GPUs count as hardware for the studio's default device: the adapter CI has
/// (lavapipe, a CPU adapter) does not, so there the studio stays on the CPU.
#[test]
fn software_adapters_are_not_hardware() {
    use wgpu::DeviceType;
    assert!(crate::is_hardware(DeviceType::DiscreteGpu));
    assert!(crate::is_hardware(DeviceType::IntegratedGpu));
    assert!(!crate::is_hardware(DeviceType::Cpu));
    assert!(!crate::is_hardware(DeviceType::Other));
    assert_eq!(
        context().is_software(),
        !crate::is_hardware(context().info_type())
    );
    if context().is_software() {
        assert_eq!(
            crate::hardware_adapter(),
            None,
            "{}",
            context().adapter_name()
        );
    }
}

/// A device lost while the mode renders (here destroyed on purpose, as a driver reset
/// would) is an error the mode reports, not a panic: the frame adds nothing, the
/// progress stays as it was, later frames add nothing either, and the image (its film
/// was on the device, gone with it) is black, not a panic or a read of freed memory.
#[test]
fn a_lost_device_is_reported_and_renders_nothing_more() {
    use meso_render::{ModeError, RenderMode, run_frames};
    // A device of its own: the other tests share `context()`.
    let ctx = GpuContext::new().expect("an adapter");
    let mut gpu = crate::GpuSpmmMode::prepare(
        ctx.clone(),
        test_scene("cornell.toml"),
        16,
        16,
        meso_render::Prepare::quietly(),
    )
    .expect("prepares");
    run_frames(&mut gpu, 2, |_, _| {});
    assert!(gpu.failure().is_none());
    assert!(mean(&gpu.image()) > 0.0);
    assert_eq!(gpu.progress().min_samples, 2);
    ctx.device.destroy();
    let run = run_frames(&mut gpu, 3, |_, _| {});
    assert_eq!(run.frames, 1, "stops at the failed frame");
    assert_eq!(run.counters.samples, 0);
    let Some(ModeError::DeviceFailed(message)) = gpu.failure() else {
        panic!("a device failure, got {:?}", gpu.failure())
    };
    assert!(message.contains(&ctx.adapter_name()), "{message}");
    assert_eq!(gpu.progress().min_samples, 2, "the progress stays");
    assert!(gpu.image_on_device().is_none());
    assert_eq!(mean(&gpu.image()), 0.0);
    assert_eq!(gpu.render_frame().counters.samples, 0);
}

/// The adapter `GpuContext::new` picks, with a device made the way the studio's window
/// makes it (`needed_limits`, its own label): what `from_device` is given there.
fn window_device(
    limits: impl Fn(&wgpu::Adapter) -> wgpu::Limits,
) -> (wgpu::Adapter, wgpu::Device, wgpu::Queue) {
    let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    let instance = wgpu::Instance::new(desc);
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        ..Default::default()
    }))
    .expect("an adapter (CI: lavapipe, WGPU_BACKEND=vulkan)");
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("window"),
        required_limits: limits(&adapter),
        ..Default::default()
    }))
    .expect("a device");
    (adapter, device, queue)
}

/// A context on a device made elsewhere (the studio's window's) renders what a
/// context of its own renders, bit for bit: the same adapter, shader and samples, and
/// the device's limits only bound sizes. The shared device is the one given.
#[test]
fn a_shared_device_renders_what_an_own_device_renders() {
    use meso_render::{RenderMode, run_frames};
    let (adapter, device, queue) = window_device(GpuContext::needed_limits);
    let shared = GpuContext::from_device(&adapter, device.clone(), queue).expect("shareable");
    assert!(shared.is_shared() && !context().is_shared());
    assert_eq!(shared.sharing(), &crate::Sharing::Shared);
    assert_eq!(shared.adapter_name(), context().adapter_name());
    assert!(
        shared.device == device,
        "the context renders on the device it was given"
    );
    let scene = test_scene("default.toml");
    let mut on_shared = crate::GpuSpmmMode::prepare(
        shared,
        scene.clone(),
        24,
        24,
        meso_render::Prepare::quietly(),
    )
    .expect("prepares on the shared device");
    let mut on_own = gpu_mode(scene, 24);
    run_frames(&mut on_shared, 3, |_, _| {});
    run_frames(&mut on_own, 3, |_, _| {});
    assert!(on_shared.failure().is_none());
    assert!(
        on_shared
            .diagnostics()
            .summary()
            .is_some_and(|s| s.contains("shared with the window")),
        "{:?}",
        on_shared.diagnostics().summary()
    );
    let (a, b) = (on_shared.image(), on_own.image());
    assert!(a.pixels().iter().flatten().any(|v| *v > 0.0), "not black");
    assert_eq!(a.pixels(), b.pixels(), "bit for bit");
}

/// A device made with fewer storage buffers per stage than the integrator binds is
/// refused by name, whatever the adapter (so the studio makes a device of its own).
#[test]
fn a_device_with_too_low_limits_is_not_shared() {
    let (adapter, device, queue) = window_device(|_| wgpu::Limits::downlevel_defaults());
    let err = GpuContext::from_device(&adapter, device, queue).expect_err("too low");
    let message = err.to_string();
    assert!(
        message.contains("max_storage_buffers_per_shader_stage is 4"),
        "{message}"
    );
    assert!(message.contains("cannot be shared"), "{message}");
}
