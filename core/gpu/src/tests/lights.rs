//! Lights on the GPU: colour edits that keep the samples, more than 16 lights, several
//! light samples per frame, and light edits that invalidate as on the CPU.

use glam::DVec3;

use super::{
    gpu_mode, image_of_scene_agrees_with_the_cpu, mean, mode_agrees_with_the_cpu, test_scene,
};

/// A light-colour edit keeps every sample, as on the CPU: with the light alone
/// lighting the scene, doubling its radiance doubles the image exactly and the
/// sample count stays.
#[test]
fn a_light_colour_edit_keeps_the_gpus_samples() {
    use meso_render::{Invalidation, RenderMode, SceneEdit, run_frames};
    let mut scene = test_scene("cornell.toml");
    scene.ambient = None;
    scene.background = meso_render::scene::Background::Color(DVec3::ZERO);
    let mut gpu = gpu_mode(scene.clone(), 24);
    run_frames(&mut gpu, 3, |_, _| {});
    let before = gpu.image();
    let samples = gpu.progress().min_samples;
    let light = scene.lights[0].with_emission(scene.lights[0].emission() * 2.0);
    assert_eq!(
        gpu.apply(SceneEdit::Light { index: 0, light })
            .expect("edit"),
        Invalidation::Nothing
    );
    assert_eq!(gpu.progress().min_samples, samples);
    let after = gpu.image();
    assert!(mean(&before) > 0.0);
    for (a, b) in after.pixels().iter().zip(before.pixels()) {
        for c in 0..3 {
            assert!(
                (a[c] - 2.0 * b[c]).abs() <= 1e-6 * b[c].abs().max(1e-6),
                "{a:?} {b:?}"
            );
        }
    }
    // Moving the light restarts its layer only: the samples of the frame after it.
    let mut moved = light;
    if let meso_render::scene::Light::Area { corner, .. } = &mut moved {
        corner.y -= 0.1;
    }
    assert_eq!(
        gpu.apply(SceneEdit::Light {
            index: 0,
            light: moved
        })
        .expect("edit"),
        Invalidation::Layer(meso_render::layers::FIRST_LIGHT)
    );
    run_frames(&mut gpu, 1, |_, _| {});
    assert_eq!(gpu.progress().min_samples, 1);
}

/// More than 16 lights (40: point lights, one-sided area lights facing both ways, a
/// black one): the CPU's bounded film (two own layers and a shared one) and its
/// stochastic selection, on the GPU; the image rule above.
#[test]
fn forty_lights_on_the_gpu_agree_with_the_cpu() {
    let scene = meso_render::scene::test_scenes::many_lights_scene(40);
    image_of_scene_agrees_with_the_cpu("40 lights", scene, 24, 16);
}

/// Several light samples per frame on the GPU's two light paths: three per area light
/// at MERL surfaces (each with its MIS material sample; the environment off, so the
/// area light is the image) and two selections among 40 lights; the image rule above
/// against the CPU with the same setting.
#[test]
fn light_samples_on_the_gpu_agree_with_the_cpu() {
    let mut merl = test_scene("merl_bunny.toml");
    merl.environment = None;
    merl.render.light_samples = 3;
    image_of_scene_agrees_with_the_cpu("merl_bunny.toml, 3 light samples", merl, 32, 16);
    let mut many = meso_render::scene::test_scenes::many_lights_scene(40);
    many.render.light_samples = 2;
    image_of_scene_agrees_with_the_cpu("40 lights, 2 light samples", many, 24, 16);
}

/// Light edits among 40 lights invalidate on the GPU exactly as on the CPU (a shared
/// light's colour promotes it to an own layer, a colour edit of an own light keeps
/// everything, a move restarts its layer, added and removed lights, back to 16 lights
/// and one layer each), the sample counts follow, and the edited mode's image then
/// agrees with the CPU's for the edited scene.
#[test]
fn light_edits_among_many_lights_invalidate_as_on_the_cpu() {
    use meso_render::{RenderMode, SceneEdit, run_frames};
    let mut scene = meso_render::scene::test_scenes::many_lights_scene(40);
    scene.render.sampler = meso_materials::rng::Sampler::Independent;
    let size = 24;
    let mut cpu = meso_modes::trace::SpmmMode::new(scene.clone(), size, size).expect("CPU mode");
    let mut gpu = gpu_mode(scene.clone(), size);
    run_frames(&mut cpu, 2, |_, _| {});
    run_frames(&mut gpu, 2, |_, _| {});
    let own = |m: &meso_modes::trace::SpmmMode| m.light_layers().light_targets(m.scene());
    let targets = own(&cpu);
    let shared = (0..40)
        .find(|&k| targets[k].layer == meso_render::layers::SHARED_LIGHTS)
        .expect("a shared light");
    let mut brighter = scene.lights[shared];
    brighter = brighter.with_emission(brighter.emission() * 3.0);
    let moved = match brighter {
        meso_render::scene::Light::Point {
            position,
            intensity,
        } => meso_render::scene::Light::Point {
            position: position + DVec3::new(0.1, 0.0, 0.0),
            intensity,
        },
        l => l,
    };
    let mut edits = vec![
        SceneEdit::Light {
            index: shared,
            light: brighter,
        },
        SceneEdit::Light {
            index: shared,
            light: brighter.with_emission(brighter.emission() * 0.5),
        },
        SceneEdit::Light {
            index: shared,
            light: moved,
        },
        SceneEdit::AddLight(scene.lights[9]),
        SceneEdit::RemoveLight(3),
    ];
    // Down to 16 lights: the film lays its light layers out again, one per light.
    edits.extend((0..24).map(|_| SceneEdit::RemoveLight(0)));
    for edit in edits {
        let what = format!("{edit:?}");
        let a = cpu.apply(edit.clone()).expect("CPU edit");
        let b = gpu.apply(edit).expect("GPU edit");
        assert_eq!(a, b, "{what}");
        run_frames(&mut cpu, 1, |_, _| {});
        run_frames(&mut gpu, 1, |_, _| {});
        assert_eq!(cpu.film().layers(), gpu.film_layers(), "{what}");
        assert_eq!(
            cpu.progress().min_samples,
            gpu.progress().min_samples,
            "{what}"
        );
    }
    assert_eq!(gpu.scene().lights.len(), 16);
    // Back above 16, then the image of the edited scene.
    let extra = gpu.scene().lights[0];
    gpu.apply(SceneEdit::AddLight(extra)).expect("a 17th light");
    let edited = gpu.scene().clone();
    mode_agrees_with_the_cpu("40 lights, edited", edited, size, 16, Some(gpu));
}
