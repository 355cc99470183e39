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
