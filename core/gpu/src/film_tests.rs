//! The film on the device against the host's `Film` (the reference for its rules),
//! the f32 sums' error after 10,000 samples, the display texture against
//! `image::to_srgb8`, and a frame that reads back no image. They need a wgpu adapter
//! (CI: lavapipe), as `tests.rs`.

use glam::DVec3;

use super::GpuContext;
use super::display::{DeviceImage, DisplayTexture};
use super::film::{AUX_WORDS, DeviceFilm};
use super::kernel::{encoder, storage};
use super::tests::context;
use meso_materials::image::{Image, to_srgb8};
use meso_materials::rng::SampleStream;
use meso_render::film::{EMPTY_UV_BOX, Film, LayeredFilm, UvBox, material_bit};

/// One sample of every pixel: per pixel and layer RGB, per pixel a material mask and
/// a texture-coordinate box.
struct Sample {
    rgb: Vec<[f32; 3]>,
    masks: Vec<u64>,
    boxes: Vec<UvBox>,
}

fn random_sample(s: &mut SampleStream, pixels: usize, layers: usize) -> Sample {
    let rgb = (0..pixels * layers)
        .map(|_| {
            let r = s.next();
            // One value in 50 is NaN or infinite: dropped and counted.
            if r < 0.01 {
                [f32::NAN, 0.5, 0.5]
            } else if r < 0.02 {
                [0.5, f32::INFINITY, 0.5]
            } else {
                [0, 1, 2].map(|_| (-s.next().max(1e-12).ln() * 3.0) as f32)
            }
        })
        .collect();
    let masks = (0..pixels)
        .map(|_| material_bit((s.next() * 4.0) as usize) | material_bit(40))
        .collect();
    // Pixel p shades texture coordinates near u = p / pixels.
    let boxes = (0..pixels)
        .map(|p| {
            if s.next() < 0.2 {
                EMPTY_UV_BOX
            } else {
                let u = (p as f64 / pixels as f64 + 0.02 * s.next()) as f32;
                let v = s.next() as f32;
                [u, v, u + 0.01, v + 0.05]
            }
        })
        .collect();
    Sample { rgb, masks, boxes }
}

/// Adds `sample` to both films (the device's through its accumulation pass).
fn add(host: &mut Film, device: &DeviceFilm, sample: &Sample, active: &[usize]) {
    let layers = host.layers();
    for p in 0..sample.masks.len() {
        let out: Vec<DVec3> = (0..layers)
            .map(|l| DVec3::from_array(sample.rgb[p * layers + l].map(f64::from)))
            .collect();
        host.add_pixel_sample(p as u32, active, &out, sample.masks[p], &sample.boxes[p]);
    }
    let ctx = context();
    let aux: Vec<u32> = sample
        .masks
        .iter()
        .zip(&sample.boxes)
        .flat_map(|(m, b)| {
            let words = [*m as u32, (*m >> 32) as u32];
            // One sample each.
            words.into_iter().chain(b.map(f32::to_bits)).chain([1])
        })
        .collect();
    assert_eq!(aux.len(), sample.masks.len() * AUX_WORDS);
    ctx.queue
        .write_buffer(&device.frame, 0, bytemuck::cast_slice(&sample.rgb));
    ctx.queue
        .write_buffer(&device.aux, 0, bytemuck::cast_slice(&aux));
    device.set_params(active, false, &[]);
    let mut enc = encoder(ctx);
    device.record_accumulate(&mut enc);
    ctx.queue.submit([enc.finish()]);
}

/// Both films agree: the resolved images within f32 rounding, the fewest samples and
/// the dropped count exactly.
fn agree(host: &Film, device: &mut DeviceFilm, active: &[usize], what: &str) {
    let weights: Vec<DVec3> = (0..host.layers())
        .map(|l| DVec3::new(1.0 + l as f64, 0.5, 2.0 - 0.25 * l as f64))
        .collect();
    let want = host.resolve(&weights);
    let got = device.resolve(active, &weights).read().expect("reads back");
    for (i, (a, b)) in got.pixels().iter().zip(want.pixels()).enumerate() {
        for c in 0..3 {
            let tol = 1e-5 * f64::from(b[c].abs()).max(1.0);
            assert!(
                (f64::from(a[c]) - f64::from(b[c])).abs() <= tol,
                "{what}: pixel {i} channel {c}: device {} host {}",
                a[c],
                b[c]
            );
        }
    }
    device.recount(active).expect("counts");
    assert_eq!(device.min_samples(), host.min_samples(active), "{what}");
    assert_eq!(device.dropped(), host.dropped(), "{what}");
    assert_eq!(device.layers(), host.layers(), "{what}");
}

/// Every rule of the host film holds on the device through a history of samples and
/// edits: NaN and infinite samples dropped and counted, inactive layers untouched,
/// a layer restarted, added, removed and laid out again, the pixels a texel edit
/// reaches (by material mask and box) restarted, the same pixels as on the host, and
/// a new size.
#[test]
fn the_film_on_the_device_keeps_the_host_films_rules() {
    let (w, h) = (7, 5);
    let pixels = (w * h) as usize;
    let mut host = Film::new(w, h, 4);
    let mut device = DeviceFilm::new(context(), w, h, 4);
    let mut s = SampleStream::new(&[17]);
    let mut active = vec![0, 1, 3];
    for step in 0..40 {
        let sample = random_sample(&mut s, pixels, host.layers());
        add(&mut host, &device, &sample, &active);
        match step {
            8 => {
                agree(&host, &mut device, &active, "after 9 samples");
                host.reset_layer(1);
                LayeredFilm::reset_layer(&mut device, 1);
                agree(&host, &mut device, &active, "a layer restarted");
            }
            14 => {
                host.push_layer();
                device.push_layer();
                active = vec![0, 1, 3, 4];
                agree(&host, &mut device, &active, "a layer added");
            }
            20 => {
                // A texel edit of material 2 at u in [0, 0.3]: the host's pixels.
                let reaches = |b: &UvBox| b[0] <= 0.3 && b[2] >= 0.0;
                let want = host.reset_reaching_pixels(material_bit(2), reaches);
                let got = device
                    .reset_where(|m, b| m & material_bit(2) != 0 && reaches(b))
                    .expect("reads the marks");
                assert!(!want.is_empty() && want.len() < pixels, "{want:?}");
                assert_eq!(got, want);
                agree(&host, &mut device, &active, "pixels restarted");
            }
            26 => {
                host.remove_layer(0);
                device.remove_layer(0);
                active = vec![0, 2, 3];
                agree(&host, &mut device, &active, "a layer removed");
            }
            32 => {
                host.keep_layers(5, 2);
                device.keep_layers(5, 2);
                active = vec![0, 1, 2, 4];
                agree(&host, &mut device, &active, "layers laid out again");
            }
            _ => {}
        }
    }
    agree(&host, &mut device, &active, "at the end");
    assert!(host.dropped() > 0, "the history had non-finite samples");
    host.reset();
    device.reset();
    agree(&host, &mut device, &active, "all restarted");
    assert_eq!(device.min_samples(), 0);
    // A new size: every sample forgotten, the dropped count kept.
    host.resize(4, 6);
    device.resize(4, 6);
    for _ in 0..3 {
        let sample = random_sample(&mut s, 24, host.layers());
        add(&mut host, &device, &sample, &active);
    }
    assert_eq!((device.width(), device.height()), (4, 6));
    agree(&host, &mut device, &active, "resized");
}

/// f32 sums after 10,000 samples: the mean of exponentially distributed samples
/// (mean 1 to 4 by pixel and channel) against the f64 sum of the same f32 values.
/// The largest relative error is printed and bounded by 1e-4 (docs/gpu.md); a
/// 7-digit format would show it, an 8-bit display never.
#[test]
fn f32_sums_stay_within_1e_4_of_f64_after_10000_samples() {
    let (w, h) = (8, 8);
    let pixels = (w * h) as usize;
    let mut device = DeviceFilm::new(context(), w, h, 1);
    let mut sums = vec![[0f64; 3]; pixels];
    let mut s = SampleStream::new(&[5]);
    // No marks, one sample each.
    let one_sample: Vec<u32> = (0..pixels * AUX_WORDS)
        .map(|i| u32::from(i % AUX_WORDS == AUX_WORDS - 1))
        .collect();
    context()
        .queue
        .write_buffer(&device.aux, 0, bytemuck::cast_slice(&one_sample));
    for _ in 0..10_000 {
        let rgb: Vec<[f32; 3]> = (0..pixels)
            .map(|p| {
                let scale = 1.0 + (p % 4) as f64;
                [0, 1, 2].map(|_| (-s.next().max(1e-12).ln() * scale) as f32)
            })
            .collect();
        for (sum, v) in sums.iter_mut().zip(&rgb) {
            for c in 0..3 {
                sum[c] += f64::from(v[c]);
            }
        }
        context()
            .queue
            .write_buffer(&device.frame, 0, bytemuck::cast_slice(&rgb));
        device.set_params(&[0], false, &[]);
        let mut enc = encoder(context());
        device.record_accumulate(&mut enc);
        context().queue.submit([enc.finish()]);
    }
    let got = device
        .resolve(&[0], &[DVec3::ONE])
        .read()
        .expect("reads back");
    let mut worst = 0f64;
    for (a, sum) in got.pixels().iter().zip(&sums) {
        for c in 0..3 {
            let mean = sum[c] / 10_000.0;
            worst = worst.max((f64::from(a[c]) - mean).abs() / mean);
        }
    }
    device.recount(&[0]).expect("counts");
    assert_eq!(device.min_samples(), 10_000);
    eprintln!("f32 film after 10,000 samples: largest relative error of a mean {worst:.2e}");
    assert!(worst < 1e-4, "{worst}");
}

/// A device image: read back as it was written; shown in a display texture, the
/// codes `to_srgb8` gives (within one code: the device's pow is f32) at several
/// exposures, NaN, negative and over-range values included; a new size makes a new
/// texture.
#[test]
fn the_display_texture_holds_what_to_srgb8_encodes() {
    let ctx: &GpuContext = context();
    let (w, h) = (13, 6);
    let mut img = Image::new(w, h);
    let mut s = SampleStream::new(&[3]);
    for (i, p) in img.pixels_mut().iter_mut().enumerate() {
        *p = match i {
            0 => [f32::NAN, -1.0, 1e30],
            1 => [0.0, 0.0031308, 1.0],
            2 => [1e-7, 0.5, f32::INFINITY],
            _ => [0, 1, 2].map(|_| (s.next() * 1.5) as f32),
        };
    }
    let texels: Vec<[f32; 4]> = img
        .pixels()
        .iter()
        .map(|p| [p[0], p[1], p[2], 1.0])
        .collect();
    let buffer = storage(ctx, "image", bytemuck::cast_slice(&texels));
    let device_image = DeviceImage::new(ctx.clone(), buffer, w, h);
    let back = device_image.read().expect("reads back");
    for (a, b) in back.pixels().iter().zip(img.pixels()) {
        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
    }
    let mut target = DisplayTexture::new(ctx);
    let first = target.generation();
    for exposure in [0.0, -1.5, 2.0] {
        device_image.show_in(&mut target, exposure);
        let got = target.read_codes().expect("reads the texture");
        let want = to_srgb8(&img, exposure);
        assert_eq!(got.len(), want.len());
        for (i, (a, b)) in got.iter().zip(&want).enumerate() {
            for c in 0..3 {
                assert!(
                    a[c].abs_diff(b[c]) <= 1,
                    "exposure {exposure}, pixel {i}, channel {c}: {} against {}",
                    a[c],
                    b[c]
                );
            }
        }
    }
    assert_eq!(target.size(), (w, h));
    assert_ne!(target.generation(), first, "made at the image's size");
    let same = target.generation();
    device_image.show_in(&mut target, 0.0);
    assert_eq!(target.generation(), same, "the same size keeps the texture");
}

/// A frame of the GPU mode reads back its counters only, never the image: the bytes
/// read back from the device stay under 100 per frame; showing the frame in a
/// display texture reads nothing back; only `image()` does (16 bytes a pixel). The
/// device image is the film's image, and later frames leave it as it was.
#[test]
fn a_frame_reads_back_its_counters_and_no_image() {
    use meso_render::{Prepare, RenderMode, run_frames};
    // A device of its own: the count is per device, and other tests share theirs.
    let ctx = GpuContext::new().expect("an adapter");
    let scene = super::tests::test_scene("cornell.toml");
    let mut gpu = super::GpuSpmmMode::prepare(ctx.clone(), scene, 24, 16, Prepare::quietly())
        .expect("prepares");
    let before = ctx.bytes_read_back();
    run_frames(&mut gpu, 4, |_, _| {});
    let per_frame = (ctx.bytes_read_back() - before) / 4;
    assert!(per_frame < 100, "{per_frame} bytes read back per frame");
    let shown = gpu.image_on_device().expect("the image is on the device");
    let mut target = DisplayTexture::new(&ctx);
    let before = ctx.bytes_read_back();
    assert!(
        target.show(shown.as_ref(), 0.0),
        "an image of the texture's device"
    );
    assert_eq!(ctx.bytes_read_back(), before, "showing reads nothing back");
    let mut other = DisplayTexture::new(context());
    assert!(
        !other.show(shown.as_ref(), 0.0),
        "an image of another device is not shown"
    );
    let image = gpu.image();
    assert_eq!(ctx.bytes_read_back() - before, 24 * 16 * 16);
    run_frames(&mut gpu, 2, |_, _| {});
    let kept = shown.read().expect("reads back");
    assert_eq!(
        *kept, image,
        "a device image is one frame's, not the film's"
    );
    assert_ne!(gpu.image(), image, "the film went on");
    assert_eq!(gpu.progress().min_samples, 6);
}

/// Read-backs from two threads on one device (the studio's window thread and render
/// thread share it) all complete: a poll that returns while the other thread is still
/// running this thread's map callback must not be taken for a lost device (it was,
/// now and then, in parallel tests: a GPU mode failed with "a read-back never
/// completed"). 1,500 each: the unfixed code failed about one in 600.
#[test]
fn read_backs_from_two_threads_on_one_device_all_complete() {
    use super::kernel::submit_and_read;
    let ctx = GpuContext::new().expect("an adapter");
    let failures = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..2u32)
            .map(|t| {
                let ctx = &ctx;
                scope.spawn(move || {
                    let buffer = storage(ctx, "read-back test", bytemuck::cast_slice(&[t; 4]));
                    (0..1500)
                        .filter(|_| {
                            submit_and_read(ctx, encoder(ctx), &[(&buffer, 16)])
                                .map(|b| b[0] != bytemuck::cast_slice::<u32, u8>(&[t; 4]))
                                .unwrap_or(true)
                        })
                        .count()
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| w.join().expect("no panic"))
            .sum::<usize>()
    });
    assert_eq!(failures, 0, "read-backs that failed or read wrong bytes");
    assert!(ctx.failure().is_none(), "{:?}", ctx.failure());
}
