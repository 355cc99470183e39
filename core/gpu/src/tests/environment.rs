//! Environment lighting on the GPU against the CPU: the studio map with MIS, and a
//! background image with map sampling alone.

use glam::DVec3;

use super::{image_agrees_with_the_cpu, image_of_scene_agrees_with_the_cpu, test_scene};

/// The environment scene (the studio map with MIS, a fitted pack with its residual
/// on the bunny, a Ward floor; rays that leave see the map): the map's and the
/// BRDFs' samples on the device, weighted as on the CPU.
#[test]
fn the_environment_scene_on_the_gpu_agrees_with_the_cpu() {
    image_agrees_with_the_cpu("env.toml", 32, 16);
}

/// The environment lighting alone (no MIS), a lat-long background image seen by
/// primary rays and by a mirror floor, rotated: what `layers::escaped` adds.
#[test]
fn a_background_image_and_map_sampling_alone_agree_with_the_cpu() {
    let mut scene = test_scene("env.toml");
    let env = scene.environment.as_mut().expect("an environment");
    env.mis = false;
    env.rotate_y_deg = -75.0;
    let (w, h) = (24, 12);
    let pixels = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
            [0.2 + x, 0.5 * (1.0 - y), 0.1 + 0.8 * x * y]
        })
        .collect();
    let image = meso_materials::image::Image::from_pixels(w, h, pixels).expect("an image");
    scene.background = meso_render::scene::Background::Environment(std::sync::Arc::new(image));
    let floor = scene
        .material_names
        .iter()
        .position(|n| n == "floor")
        .expect("the floor");
    scene.materials[floor] = meso_render::scene::Material::Mirror {
        reflectance: DVec3::new(0.8, 0.7, 0.6),
    };
    image_of_scene_agrees_with_the_cpu("env.toml with a background image", scene, 32, 16);
}

/// The `env` words of a map drawn in two parts (the adaptive mode's frames): the
/// header's offsets point at each part's tables and radiance, the parts' radiance adds
/// up to the map's, and `word_count` (checked against the device's limits before
/// anything is built) is what `words` makes.
#[test]
fn a_map_drawn_in_two_parts_lays_out_both_parts_tables_within_the_counted_words() {
    use crate::environment::{MapSampling, word_count, words};
    let scene = test_scene("env.toml");
    let env = scene.environment.as_ref().expect("an environment");
    let (w, h) = (env.map.width() as usize, env.map.height() as usize);
    for split in [false, true] {
        let sampling = MapSampling::new(Some(env), split);
        assert_eq!(sampling.parts.is_some(), split, "the studio map has peaks");
        let words = words(&scene, &sampling);
        assert_eq!(
            words.len(),
            word_count(Some(env), &scene.background, split),
            "split {split}"
        );
        let f = |at: u32| f32::from_bits(words[at as usize]);
        assert_eq!(words[13], if split { 2 } else { 0 });
        // Each part's row CDF ends at 1, its pdfs are its sampler's.
        let parts: Vec<[u32; 4]> = if split {
            vec![
                [words[6], words[7], words[8], words[14]],
                [words[16], words[17], words[18], words[19]],
            ]
        } else {
            vec![[words[6], words[7], words[8], words[9]]]
        };
        for (j, &[rows, _cols, pdfs, _rgb]) in parts.iter().enumerate() {
            assert_eq!(f(rows + h as u32), 1.0, "part {j}");
            let sampler = match &sampling.parts {
                Some(p) => &p[j].0,
                None => sampling.whole.as_ref().expect("a sampler"),
            };
            let (_, _, pdf) = sampler.tables();
            for (i, p) in pdf.enumerate() {
                assert_eq!(f(pdfs + i as u32), p as f32, "part {j} pixel {i}");
            }
        }
        if split {
            let (peaks, rest, map) = (words[14], words[19], words[9]);
            for i in 0..(w * h * 3) as u32 {
                assert_eq!(f(peaks + i) + f(rest + i), f(map + i), "word {i}");
            }
        }
    }
}
