//! The viewport denoiser on the device: its guides against the CPU mode's, its filter
//! against `Denoiser::apply_reference` (the textbook form), and the GPU mode's
//! filtered first frame, made without a read-back.

use meso_materials::image::Image;
use meso_render::{Denoiser, Guides, Pass, RenderMode, denoise, run_frames};

use super::super::denoise::{DeviceDenoiser, GUIDE_FLOATS};
use super::super::display::DeviceImage;
use super::super::kernel;
use super::{context, gpu_mode, test_scene};
use crate::GpuContext;

/// An image on the device, as `DeviceImage` holds one.
fn upload_image(ctx: &GpuContext, img: &Image) -> DeviceImage {
    let texels: Vec<[f32; 4]> = img
        .pixels()
        .iter()
        .map(|p| [p[0], p[1], p[2], 1.0])
        .collect();
    let buffer = kernel::storage(ctx, "test image", bytemuck::cast_slice(&texels));
    DeviceImage::new(ctx.clone(), buffer, img.width(), img.height())
}

/// Guides on the device, as `shaders/guides.wgsl` writes them.
fn upload_guides(ctx: &GpuContext, g: &Guides) -> wgpu::Buffer {
    let floats: Vec<f32> = (0..g.normal.len())
        .flat_map(|p| {
            let (n, a) = (g.normal[p], g.albedo[p]);
            [n[0], n[1], n[2], g.depth[p], a[0], a[1], a[2], 0.0]
        })
        .collect();
    assert_eq!(floats.len() as u64, g.normal.len() as u64 * GUIDE_FLOATS);
    kernel::storage(ctx, "test guides", bytemuck::cast_slice(&floats))
}

/// A noisy image over guides with every kind of edge the filter stops at: background
/// (infinite distance) beside surfaces, a step in distance, a crease in the normal, a
/// change of albedo, and bright highlights.
fn edges(width: u32, height: u32) -> (Image, Guides) {
    let mut img = Image::new(width, height);
    let n = (width * height) as usize;
    let mut g = Guides {
        width,
        height,
        normal: vec![[0.0; 3]; n],
        depth: vec![f32::INFINITY; n],
        albedo: vec![[0.0; 3]; n],
    };
    let mut state = 0x2545_f491_u32;
    let mut noise = || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state as f32 / u32::MAX as f32
    };
    for y in 0..height {
        for x in 0..width {
            let p = (y * width + x) as usize;
            let base = if x < width / 5 {
                // Background: a sky with noise of its own.
                [0.3, 0.4, 0.9]
            } else {
                let (normal, depth, albedo) = match (x < width / 2, y < height / 2) {
                    (true, true) => ([0.0, 0.0, 1.0], 2.0, [0.8, 0.2, 0.2]),
                    (true, false) => ([0.0, 0.0, 1.0], 2.0 + 0.5, [0.8, 0.2, 0.2]),
                    (false, true) => ([0.0, 0.6, 0.8], 2.2, [0.8, 0.2, 0.2]),
                    (false, false) => ([0.0, 0.6, 0.8], 2.2, [0.1, 0.7, 0.3]),
                };
                (g.normal[p], g.depth[p], g.albedo[p]) = (normal, depth, albedo);
                albedo
            };
            let spike = if noise() > 0.97 { 20.0 } else { 1.0 };
            img.pixels_mut()[p] = base.map(|c| c * spike * (0.2 + 1.6 * noise()));
        }
    }
    (img, g)
}

/// The largest difference of two images, relative to each pixel's size (at least 1).
fn max_relative(a: &Image, b: &Image) -> f32 {
    a.pixels()
        .iter()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs() / q[c].abs().max(1.0)))
        .fold(0.0, f32::max)
}

#[test]
fn the_device_filter_is_the_reference_filter() {
    let ctx = context();
    let (img, guides) = edges(53, 37);
    let (image, guide_buffer) = (upload_image(ctx, &img), upload_guides(ctx, &guides));
    let mut filter = DeviceDenoiser::new(ctx);
    for (samples, strength) in [(1, 1.0), (4, 0.6), (16, 0.0)] {
        let denoiser = Denoiser::for_samples(samples);
        let expected = denoise::blend(
            &img,
            &denoiser
                .apply_reference(&img, &guides)
                .expect("matching guides"),
            strength,
        );
        let got = filter
            .apply(&image, &guide_buffer, &denoiser, strength)
            .expect("the device takes the default filter")
            .read()
            .expect("read back");
        let error = max_relative(&got, &expected);
        eprintln!("{samples} samples, strength {strength}: largest relative error {error:e}");
        assert!(
            error <= 1e-4,
            "{samples} samples, strength {strength}: the device's filter differs from the reference by {error}"
        );
    }
    // It smooths: the filtered surface is far less noisy than the estimate.
    let filtered = filter
        .apply(&image, &guide_buffer, &Denoiser::for_samples(1), 1.0)
        .expect("filtered")
        .read()
        .expect("read back");
    let roughness = |img: &Image| {
        let w = img.width() as usize;
        let row = &img.pixels()[w * 5 + w / 5 + 1..w * 5 + w / 2 - 1];
        row.windows(2)
            .map(|p| (p[0][0] - p[1][0]).abs())
            .sum::<f32>()
    };
    assert!(roughness(&filtered) < 0.3 * roughness(&img));
}

#[test]
fn a_negative_normal_power_is_left_to_the_host() {
    let ctx = context();
    let (img, guides) = edges(8, 8);
    let denoiser = Denoiser {
        normal_power: -2,
        ..Denoiser::default()
    };
    let got = DeviceDenoiser::new(ctx).apply(
        &upload_image(ctx, &img),
        &upload_guides(ctx, &guides),
        &denoiser,
        1.0,
    );
    assert!(got.is_none());
}

/// The fraction of pixels where `agree` holds.
fn share(n: usize, agree: impl Fn(usize) -> bool) -> f64 {
    (0..n).filter(|&p| agree(p)).count() as f64 / n as f64
}

#[test]
fn the_device_guides_are_the_cpu_modes() {
    // A pack and an analytic floor; a mirror box and area light; a MERL bunny; an
    // environment seen past the object.
    for (file, size) in [
        ("default.toml", 40),
        ("cornell.toml", 40),
        ("merl_bunny.toml", 40),
        ("env.toml", 40),
    ] {
        let scene = test_scene(file);
        let cpu = meso_modes::trace::SpmmMode::new(scene.clone(), size, size)
            .expect("CPU mode")
            .guides(Pass::Frame)
            .expect("CPU guides");
        let gpu = gpu_mode(scene, size)
            .guides(Pass::Frame)
            .expect("GPU guides");
        assert_eq!((gpu.width, gpu.height), (size, size));
        let n = (size * size) as usize;
        let hits_agree = share(n, |p| cpu.depth[p].is_finite() == gpu.depth[p].is_finite());
        let both = |p: usize| cpu.depth[p].is_finite() && gpu.depth[p].is_finite();
        let depth = share(n, |p| {
            !both(p) || (cpu.depth[p] - gpu.depth[p]).abs() <= 1e-3 * cpu.depth[p]
        });
        let normal = share(n, |p| {
            let (a, b) = (cpu.normal[p], gpu.normal[p]);
            !both(p) || a[0] * b[0] + a[1] * b[1] + a[2] * b[2] >= 0.999
        });
        let albedo = share(n, |p| {
            let (a, b) = (cpu.albedo[p], gpu.albedo[p]);
            (0..3).all(|c| (a[c] - b[c]).abs() <= 1e-3 + 1e-3 * a[c].abs())
        });
        let mean = |g: &Guides| {
            g.albedo
                .iter()
                .flatten()
                .map(|&v| f64::from(v))
                .sum::<f64>()
        };
        eprintln!(
            "{file}: hits {hits_agree:.4}, depth {depth:.4}, normal {normal:.4}, albedo {albedo:.4}, albedo sums {:.4} / {:.4}",
            mean(&gpu),
            mean(&cpu)
        );
        for (what, s) in [
            ("hit or miss", hits_agree),
            ("distance", depth),
            ("normal", normal),
            ("albedo", albedo),
        ] {
            assert!(
                s >= 0.98,
                "{file}: the {what} agrees at only {s} of the pixels"
            );
        }
        assert!(
            (mean(&gpu) - mean(&cpu)).abs() <= 0.005 * mean(&cpu),
            "{file}: albedo sums {} against the CPU's {}",
            mean(&gpu),
            mean(&cpu)
        );
    }
}

#[test]
fn the_gpu_mode_filters_its_frame_on_the_device_without_a_read_back() {
    // A device of its own, so no other test's read-backs are counted.
    let ctx = GpuContext::new().expect("a wgpu adapter");
    let size = 40;
    let mut gpu = super::super::GpuSpmmMode::prepare(
        ctx.clone(),
        test_scene("cornell.toml"),
        size,
        size,
        meso_render::Prepare::quietly(),
    )
    .expect("the GPU mode");
    run_frames(&mut gpu, 1, |_, _| {});
    let denoiser = Denoiser::for_samples(1);
    let estimate = gpu.image_on_device().expect("the image on the device");
    let before = ctx.bytes_read_back();
    let picture = gpu
        .denoised_on_device(estimate.as_ref(), &denoiser, 0.75)
        .expect("filtered on the device");
    assert_eq!(
        ctx.bytes_read_back(),
        before,
        "filtering read something back"
    );
    let got = picture.read().expect("read back");
    let image = estimate.read().expect("read back");
    let guides = gpu.guides(Pass::Frame).expect("guides");
    let expected = denoise::blend(
        &image,
        &denoiser.apply_reference(&image, &guides).expect("guides"),
        0.75,
    );
    let error = max_relative(&got, &expected);
    assert!(error <= 1e-4, "largest relative error {error}");
    // Guides are kept until an edit: after a camera move they are the new view's.
    let mut camera = gpu.scene().camera;
    camera.position += glam::DVec3::new(0.3, 0.1, 0.0);
    gpu.apply(meso_render::SceneEdit::Camera(camera))
        .expect("a camera edit");
    let mut moved = test_scene("cornell.toml");
    moved.camera = camera;
    let fresh = super::gpu_mode(moved, size)
        .guides(Pass::Frame)
        .expect("guides");
    assert_eq!(gpu.guides(Pass::Frame).expect("guides"), fresh);
}

#[test]
fn the_denoiser_kernels_are_made_ahead_when_asked() {
    let mut gpu = gpu_mode(test_scene("default.toml"), 8);
    assert!(!gpu.denoiser_kernels_made(), "made before anyone asked");
    gpu.prepare_denoiser();
    assert!(gpu.denoiser_kernels_made());
    run_frames(&mut gpu, 1, |_, _| {});
    let image = gpu.image_on_device().expect("on the device");
    assert!(
        gpu.denoised_on_device(image.as_ref(), &Denoiser::for_samples(1), 1.0)
            .is_some()
    );
}
