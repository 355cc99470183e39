//! Unit tests of the pass's guards, the allocation's correction and the mip-maps.

use super::pass::{mip, radiance_edge, visibility_edge};
use super::*;
use meso_render::RenderModeExt;

#[test]
fn a_visibility_step_between_neighbours_marks_both_sides_and_noise_below_it_does_not() {
    // A shadow edge between columns 1 and 2 of a 4 x 2 map; a 0.05 wobble elsewhere.
    let visible = [1.0, 0.95, 0.2, 0.25, 1.0, 0.95, 0.2, 0.25];
    let edge: Vec<bool> = (0..8)
        .map(|i| visibility_edge(&visible, 4, 2, i % 4, i / 4))
        .collect();
    assert_eq!(edge, [false, true, true, false, false, true, true, false]);
}

#[test]
fn a_radiance_step_marks_both_sides_and_a_smooth_ramp_or_dark_noise_does_not() {
    // A highlight edge between columns 1 and 2 (1 -> 3); a 10% ramp elsewhere.
    let mean = [1.0, 1.1, 3.0, 3.3];
    let edge: Vec<bool> = (0..4)
        .map(|x| radiance_edge(&mean, 4, 1, x, 0, 0.0))
        .collect();
    assert_eq!(edge, [false, true, true, false]);
    // Steps of 1e-4 between near-black pixels stay below a floor of 1e-3.
    let dark = [0.0, 1e-4, 0.0];
    assert!((0..3).all(|x| !radiance_edge(&dark, 3, 1, x, 0, 1e-3)));
}

#[test]
fn a_pixel_whose_samples_vary_more_than_predicted_takes_more_samples() {
    let scene = super::super::tests::merl_test_scene();
    let mut mode = AdaptiveMode::prepare(scene, 32, 32, Prepare::quietly()).expect("adaptive");
    // Past the last refinement every pixel is a site of level 0.
    for _ in 0..2 * (mode.top_level() + 1) {
        mode.render_frame();
    }
    assert!(mode.moments.iter().all(|m| m.count() > 0));
    let frames = mode.core.frames..mode.core.frames + 16;
    let taken = |mode: &AdaptiveMode, i: usize| -> u32 {
        let b = mode.buffers.as_ref().expect("pass done");
        frames
            .clone()
            .map(|f| mode.plan_frame(b, f).samples[i])
            .sum()
    };
    // The pixel predicted quietest among those the mode gives more than the floor.
    let b = mode.buffers.as_ref().expect("pass done");
    let i = (0..b.sigma.len())
        .filter(|&i| b.sigma[i] > 0.0)
        .min_by(|&a, &c| b.sigma[a].total_cmp(&b.sigma[c]))
        .expect("a lit pixel");
    let predicted = b.sigma[i];
    let before = taken(&mode, i);
    // Its samples turn out to vary with ten times the predicted deviation.
    let mut noisy = Moments::default();
    for k in 0..64 {
        noisy.add(if k % 2 == 0 { 0.0 } else { 20.0 * predicted });
    }
    mode.moments[i] = noisy;
    let after = taken(&mode, i);
    assert!(after > 3 * before.max(1), "{before} -> {after} samples");
    // A restart forgets what the samples measured, as it forgets the samples.
    let camera = mode.scene().camera;
    mode.apply(SceneEdit::Camera(camera)).expect("camera edit");
    assert!(mode.moments.iter().all(|m| m.count() == 0));
}

/// The last column and row are sites of every frame's plan, from the first frame on
/// (the parents of the pixels next to them, `upsample::far_parent`), and each takes
/// at least a sample in the first frame.
#[test]
fn the_last_row_and_column_are_shaded_in_every_frame() {
    let scene = super::super::tests::merl_test_scene();
    let (w, h) = (30, 21);
    let mut mode = AdaptiveMode::prepare(scene, w, h, Prepare::quietly()).expect("adaptive");
    mode.render_frame();
    let b = mode.buffers.as_ref().expect("pass done");
    for f in [0, 1, 5] {
        let plan = mode.plan_frame(b, f);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                if upsample::is_edge(x, y, w, h) {
                    assert!(plan.site_level[i].is_some(), "frame {f}: ({x}, {y})");
                }
            }
        }
    }
    assert!(
        (0..w * h)
            .filter(|&i| upsample::is_edge(i % w, i / w, w, h))
            .all(|i| mode.own[i as usize] > 0)
    );
}

#[test]
fn mip_reduces_blocks_of_odd_images_by_min_and_max() {
    let v = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0, 5.0];
    let min = mip(&v, 3, 3, 1, f64::min);
    assert_eq!(min[1], vec![1.0, 4.0, 2.0, 5.0]);
    let max = mip(&v, 3, 3, 1, f64::max);
    assert_eq!(max[1], vec![5.0, 9.0, 6.0, 5.0]);
}

/// A material edit restarts the samples but keeps the bandwidth pass: the next frame
/// shades at once with the pass's buffers while the edited material's lobes are
/// analysed on a thread of their own; the analysis is taken up by a frame when done,
/// and after the next pass the mode renders exactly as one made with the edited
/// scene.
#[test]
fn a_material_edit_keeps_the_pass_and_analyses_the_material_beside_the_frames() {
    let scene = meso_render::scene::test_scenes::edit_test_scene();
    let (index, pack) = (scene.materials.iter().enumerate())
        .find_map(|(i, m)| match m {
            Material::Spmm { material, .. } => Some((i, material.clone())),
            _ => None,
        })
        .expect("the edit scene has a pack");
    let mut mode = AdaptiveMode::prepare(scene.clone(), 24, 24, Prepare::quietly()).expect("mode");
    mode.render_frame();
    let sigma = |m: &AdaptiveMode| m.buffers.as_ref().map(|b| b.sigma.clone());
    let before = sigma(&mode).expect("the pass ran");
    let mut edited = scene.materials[index].clone();
    if let Material::Spmm { material, .. } = &mut edited {
        *material = Arc::new(
            pack.with_weight_scale(&meso_materials::spmm::WeightTarget::basis(0, 0), [2.0; 3])
                .expect("a weight edit"),
        );
    }
    let edit = SceneEdit::Material {
        index,
        material: edited,
    };
    assert_eq!(mode.apply(edit.clone()), Ok(Invalidation::All));
    assert_eq!(mode.progress().min_samples, 0, "the samples restart");
    assert_eq!(mode.analysing.len(), 1, "analysed beside the frames");
    // A second edit while it runs marks it stale: still one analysis, of the latest.
    assert_eq!(mode.apply(edit.clone()), Ok(Invalidation::All));
    assert_eq!(
        mode.analysing.len(),
        1,
        "one analysis per material at a time"
    );
    assert_eq!(sigma(&mode), Some(before), "the pass is kept");
    mode.render_frame();
    assert_eq!(mode.progress().frames, 1, "a frame");
    // The analysis is taken up by a frame once done; the next pass uses it.
    for _ in 0..1000 {
        if mode.analysing.is_empty() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
        mode.render_frame();
    }
    assert!(mode.analysing.is_empty(), "the analysis was not taken up");
    let camera = mode.scene().camera;
    mode.apply(SceneEdit::Camera(camera)).expect("camera edit");
    mode.render_frame();
    let mut fresh =
        AdaptiveMode::prepare(mode.scene().clone(), 24, 24, Prepare::quietly()).expect("mode");
    fresh.render_frame();
    assert_eq!(mode.materials[index], fresh.materials[index]);
    assert!(mode.image().pixels() == fresh.image().pixels());
}
