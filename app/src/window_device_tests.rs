//! The GPU mode on the window's own wgpu device, as main.rs wires it (built with the
//! `gpu` feature): the mode renders on the window's device, its frames reach the window
//! without a read-back, and a window device too small to share is named in the GPU
//! mode's summary. Needs a wgpu adapter (CI: lavapipe, WGPU_BACKEND=vulkan).

use std::sync::Arc;

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use meso_render::{Device, ModeKind, Prepare};

use super::mode_tests::{next_frame_mode, small, step_until};
use super::tests::loaded;
use super::*;
use meso_viewport::maker::ModeMaker;

/// The studio drawn by a wgpu render state made as eframe makes it with main.rs's
/// configuration (`window_device::wgpu_configuration`), its registry sharing that
/// device (`window_device::modes_for`) and its viewport drawing frames there
/// (`Studio::drawn_by`), as main.rs wires them; loaded. With the render state and the
/// shared context.
fn studio_on_the_windows_device(
    settings: Settings,
) -> (
    Harness<'static, Studio>,
    eframe::egui_wgpu::RenderState,
    meso_gpu::GpuContext,
) {
    use crate::window_device;
    let rs = egui_kittest::wgpu::create_render_state(
        window_device::wgpu_configuration().wgpu_setup,
        eframe::egui_wgpu::RendererOptions::PREDICTABLE,
    );
    let modes = window_device::modes_for(Some(&rs));
    let ctx = modes.gpu().expect("the window's device is shared").clone();
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .renderer(egui_kittest::wgpu::WgpuTestRenderer::from_render_state(
            rs.clone(),
        ))
        .build_ui_state(
            |ui, s: &mut Studio| s.show(ui),
            Studio::with_maker(None, None, settings, Arc::new(modes))
                .drawn_by(Some((rs.clone(), ctx.clone()))),
        );
    loaded(&mut h);
    (h, rs, ctx)
}

/// The GPU mode on the window's own wgpu device: the window's render state is made as
/// eframe makes it with main.rs's configuration (`window_device::wgpu_configuration`),
/// the studio's registry is given that device, and a switch to the GPU renders frames
/// on it (the status bar's summary says so) while the window draws with it too. Needs
/// a wgpu adapter (CI: lavapipe, WGPU_BACKEND=vulkan).
#[test]
fn the_gpu_mode_renders_on_the_windows_own_device() {
    let (mut h, rs, ctx) = studio_on_the_windows_device(small());
    assert!(ctx.is_shared());
    assert!(ctx.device == rs.device, "the window's device itself");
    let info = rs.adapter.get_info();
    let adapter = format!("{} ({})", info.name, info.backend);
    assert_eq!(ctx.adapter_name(), adapter);
    h.state_mut().request_mode(ModeKind::Spmm, Device::Gpu);
    step_until(&mut h, "a frame of the GPU mode", |h| {
        h.state().frame().is_some_and(|f| f.device == Device::Gpu)
    });
    let frame = h.state().frame().expect("a frame").clone();
    let summary = frame.summary.clone().unwrap_or_default();
    assert!(summary.starts_with(&adapter), "{summary}");
    assert!(summary.contains("shared with the window"), "{summary}");
    assert!(
        frame.image().pixels().iter().flatten().any(|v| *v > 0.0),
        "the GPU frame is not black"
    );
    // The window draws with the device the mode renders on, and the mode keeps going.
    h.render().expect("the window draws");
    next_frame_mode(&mut h);
    let now = h.state().frame().expect("a frame");
    assert_eq!(now.device, Device::Gpu, "no fallback to the CPU");
}

/// On the window's own device, a GPU frame reaches the screen without leaving the
/// device: the render thread publishes the estimate on the device (the denoiser off),
/// the viewport encodes it there into the texture the window samples, and while
/// frames go on only their counters are read back (four frames or more read back less
/// than a quarter of one image), and the status bar says so. What the window draws in the viewport is the
/// frame's image as `to_srgb8` encodes it: the mean code within 1.5 and the same
/// contrast (the texture is stretched over the viewport, so pixels are compared in
/// bulk). Needs a wgpu adapter (CI: lavapipe).
#[test]
fn a_gpu_frame_reaches_the_window_without_a_read_back() {
    gpu_frames_reach_the_window_without_a_read_back(false);
}

/// The same with the denoiser on: the first frames are filtered on the device
/// (`RenderMode::denoised_on_device`), so the picture shown stays there too and what
/// the window draws is that picture.
#[test]
fn a_denoised_gpu_frame_reaches_the_window_without_a_read_back() {
    gpu_frames_reach_the_window_without_a_read_back(true);
}

fn gpu_frames_reach_the_window_without_a_read_back(denoise: bool) {
    let settings = Settings {
        denoise,
        exposure: 0.5,
        ..small()
    };
    let (mut h, _, ctx) = studio_on_the_windows_device(settings);
    h.state_mut().request_mode(ModeKind::Spmm, Device::Gpu);
    step_until(&mut h, "a frame of the GPU mode", |h| {
        h.state()
            .frame()
            .is_some_and(|f| f.device == Device::Gpu && f.progress.min_samples >= 2)
    });
    let (before, samples) = (
        ctx.bytes_read_back(),
        h.state().frame().expect("a frame").progress.min_samples,
    );
    step_until(&mut h, "four more samples", |h| {
        h.state()
            .frame()
            .is_some_and(|f| f.progress.min_samples >= samples + 4)
    });
    // Four frames or more (a restart in between, a resize under load, means more);
    // their counters are 40 bytes each and an edit's count 8, while one image is 16
    // bytes a pixel: all of them together stay under a quarter of one image.
    let p = h.state().frame().expect("a frame").progress;
    let image_bytes = 16 * u64::from(p.width) * u64::from(p.height);
    let read = ctx.bytes_read_back() - before;
    assert!(
        read < image_bytes / 4,
        "{read} bytes read back over four frames or more; an image is {image_bytes}"
    );
    h.state_mut().set_max_samples(1);
    next_frame_mode(&mut h);
    h.step();
    let frame = h.state().frame().expect("a frame").clone();
    assert!(
        frame.estimate.on_device().is_some(),
        "the estimate stays on the device"
    );
    if denoise {
        assert!(frame.progress.min_samples < meso_render::denoise::FADE_SAMPLES);
        assert!(
            frame
                .shown
                .as_ref()
                .is_some_and(|s| s.on_device().is_some()),
            "the denoised picture is made and kept on the device"
        );
    }
    assert!(
        h.state().shows_frames_from_device(),
        "shown from the device"
    );
    h.step();
    assert!(
        h.query_by_label_contains("shown from the device").is_some(),
        "the status bar says so"
    );
    let screen = h.render().expect("the window draws");
    let rect = h.state().viewport.rect.expect("the viewport was shown");
    let ppp = h.ctx.pixels_per_point();
    let (x0, y0) = (
        (rect.min.x * ppp).ceil() as u32 + 1,
        (rect.min.y * ppp).ceil() as u32 + 1,
    );
    let (x1, y1) = (
        (rect.max.x * ppp).floor() as u32 - 1,
        (rect.max.y * ppp).floor() as u32 - 1,
    );
    let drawn: Vec<f64> = (y0..y1)
        .flat_map(|y| (x0..x1).map(move |x| (x, y)))
        .flat_map(|(x, y)| screen.get_pixel(x, y).0[..3].to_vec())
        .map(f64::from)
        .collect();
    let want: Vec<f64> = meso_materials::image::to_srgb8(&frame.shown_image(), 0.5)
        .into_iter()
        .flatten()
        .map(f64::from)
        .collect();
    let stats = |v: &[f64]| {
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        (mean, sd)
    };
    let ((m_drawn, sd_drawn), (m_want, sd_want)) = (stats(&drawn), stats(&want));
    assert!(sd_want > 5.0, "the image has structure: {sd_want}");
    assert!(
        (m_drawn - m_want).abs() < 1.5,
        "mean code on screen {m_drawn:.2}, of the image {m_want:.2}"
    );
    assert!(
        (sd_drawn - sd_want).abs() < 0.1 * sd_want,
        "contrast on screen {sd_drawn:.2}, of the image {sd_want:.2}"
    );
}

/// A window device made with less than the GPU mode needs is not shared: each GPU
/// mode makes a device of its own and its summary says why.
#[test]
fn a_window_device_too_small_to_share_is_named_in_the_summary() {
    use eframe::egui_wgpu::WgpuSetup;
    let mut config = crate::window_device::wgpu_configuration();
    if let WgpuSetup::CreateNew(create) = &mut config.wgpu_setup {
        create.device_descriptor = Arc::new(|_| eframe::wgpu::DeviceDescriptor {
            required_limits: eframe::wgpu::Limits::downlevel_defaults(),
            ..Default::default()
        });
    }
    let rs = egui_kittest::wgpu::create_render_state(
        config.wgpu_setup,
        eframe::egui_wgpu::RendererOptions::PREDICTABLE,
    );
    let modes = crate::window_device::modes_for(Some(&rs));
    assert!(modes.gpu().is_none());
    let scene = crate::studio::default_scene_path();
    let scene = meso_render::scene::load_scene(&scene).expect("the default scene");
    let mode = modes
        .create(
            ModeKind::Spmm,
            Device::Gpu,
            scene,
            16,
            16,
            Prepare::quietly(),
        )
        .expect("a GPU mode on its own device");
    let summary = mode.diagnostics().summary().unwrap_or_default();
    assert!(
        summary.contains("own device (the device on")
            && summary.contains("max_storage_buffers_per_shader_stage is 4"),
        "{summary}"
    );
}
