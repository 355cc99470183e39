//! Whole images against the CPU mode's (the image rule in `tests.rs`): the default
//! scene, the Cornell box, and the residual panel with the moving flag.

use super::{gpu_mode, image_agrees_with_the_cpu, image_of_scene_agrees_with_the_cpu, rmse};

#[test]
fn the_default_scene_on_the_gpu_agrees_with_the_cpu() {
    image_agrees_with_the_cpu("default.toml", 40, 16);
}

#[test]
fn the_cornell_box_on_the_gpu_agrees_with_the_cpu() {
    image_agrees_with_the_cpu("cornell.toml", 40, 16);
}

/// The code-built edit scene: an SPMM panel with a PCA residual under an area and a
/// point light with AO; while moving, the pixels that shaded the residual restart
/// and render without it, as on the CPU.
#[test]
fn the_residual_panel_and_the_moving_flag_agree_with_the_cpu() {
    use meso_render::{Invalidation, RenderMode, SceneEdit, run_frames};
    let scene = meso_render::scene::test_scenes::edit_test_scene();
    image_of_scene_agrees_with_the_cpu("edit_test_scene", scene.clone(), 24, 16);
    let mut gpu = gpu_mode(scene, 24);
    run_frames(&mut gpu, 2, |_, _| {});
    let still = gpu.image();
    let Invalidation::Pixels(n) = gpu.apply(SceneEdit::Moving(true)).expect("edit") else {
        panic!("moving restarts pixels")
    };
    assert!(n > 0 && n < 24 * 24, "{n} pixels shaded the residual");
    run_frames(&mut gpu, 2, |_, _| {});
    let moving = gpu.image();
    assert_ne!(rmse(&still, &moving), 0.0, "the residual changes the image");
    assert_eq!(
        gpu.apply(SceneEdit::Moving(true)).expect("edit"),
        Invalidation::Nothing
    );
}
