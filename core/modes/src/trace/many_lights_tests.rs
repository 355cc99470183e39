//! Many lights: stochastic selection converges to tracing every light, the bounded
//! film stays within its memory bound, an edit among thousands of lights restarts only
//! the promoted light's slot and the shared layer, and a film that cannot fit is
//! refused naming its bytes.

use glam::DVec3;
use rayon::prelude::*;

use super::SpmmMode;
use meso_materials::image::Image;
use meso_render::RenderModeExt;
use meso_render::layers::{FIRST_LIGHT, MANY_LIGHTS, OWN_LIGHT_LAYERS, SHARED_LIGHTS};
use meso_render::light_selection::LightSampling;
use meso_render::scene::test_scenes::many_lights_scene;
use meso_render::scene::{Light, Scene};
use meso_render::{Film, Invalidation, ModeError, RenderMode, SceneEdit};

/// Per sample index, the mean over the image of the weighted sample, per pixel too.
fn samples(m: &SpmmMode, size: u32, indices: std::ops::Range<u64>) -> Vec<Vec<f64>> {
    let w = m.layer_weights();
    indices
        .into_par_iter()
        .map(|i| {
            (0..size * size)
                .map(|p| {
                    let (out, _, _) = m.sample(p % size, p / size, i);
                    out.iter()
                        .zip(&w)
                        .map(|(o, w)| (*o * *w).element_sum() / 3.0)
                        .sum()
                })
                .collect()
        })
        .collect()
}

fn mean_sd(v: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = v.clone().count() as f64;
    let mean = v.clone().sum::<f64>() / n;
    let var = v.map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

#[test]
fn stochastic_selection_of_a_thousand_lights_converges_to_tracing_every_light() {
    const SIZE: u32 = 10;
    const N: u64 = 64;
    let scene = many_lights_scene(1000);
    let mut exact = SpmmMode::new(scene.clone(), SIZE, SIZE).expect("size");
    exact.set_light_sampling(LightSampling::Exact);
    let e = samples(&exact, SIZE, 0..N);
    // One selection per shading point, and three (each weighted a third) against the
    // same exact reference of one point per light.
    for light_samples in [1, 3] {
        let mut scene = scene.clone();
        scene.render.light_samples = light_samples;
        let stochastic = SpmmMode::new(scene, SIZE, SIZE).expect("size");
        assert_eq!(stochastic.layer_weights(), exact.layer_weights());
        let s = samples(&stochastic, SIZE, 0..N);
        // Both draw the same jittered pixel positions (the first two dimensions), so
        // the difference carries only the light sampling's noise.
        let image_diff = (0..N as usize)
            .map(|i| (s[i].iter().sum::<f64>() - e[i].iter().sum::<f64>()) / (SIZE * SIZE) as f64);
        let (d, sd) = mean_sd(image_diff);
        let (level, _) = mean_sd((0..N as usize).map(|i| e[i].iter().sum::<f64>()));
        let level = level / (SIZE * SIZE) as f64;
        // Monte Carlo tolerance: 4 standard errors of the mean difference.
        let tolerance = 4.0 * sd / (N as f64).sqrt();
        eprintln!(
            "{light_samples} selections: image mean difference {d:.3e}, 4 sigma {tolerance:.3e}, level {level:.4}"
        );
        assert!(
            d.abs() < tolerance,
            "{light_samples} selections: image mean off by {d} (level {level}, 4 sigma {tolerance})"
        );
        assert!(
            tolerance < 0.05 * level,
            "the test is sharp: {tolerance} vs {level}"
        );
        // Per pixel: at most 2 of 100 beyond 4.5 standard errors (t with 63 dof:
        // expect about 0.003 beyond 4.5 per pixel if unbiased).
        let outliers = (0..(SIZE * SIZE) as usize)
            .filter(|&p| {
                let (d, sd) = mean_sd((0..N as usize).map(|i| s[i][p] - e[i][p]));
                sd > 0.0 && d.abs() > 4.5 * sd / (N as f64).sqrt()
            })
            .count();
        assert!(
            outliers <= 2,
            "{light_samples} selections: {outliers} pixels off"
        );
    }
}

#[test]
fn stochastic_frames_trace_a_fixed_number_of_shadow_rays_and_are_thread_independent() {
    const SIZE: u32 = 12;
    let scene = many_lights_scene(2000);
    let mut m = SpmmMode::new(scene.clone(), SIZE, SIZE).expect("size");
    let stats = m.render_frame();
    let points = stats.counters.shading_points;
    assert!(points > 0);
    assert!(
        stats.counters.rays.shadow <= points * meso_render::light_selection::LIGHT_SAMPLES as u64,
        "{} shadow rays for {points} points",
        stats.counters.rays.shadow
    );
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let mut single = SpmmMode::new(scene, SIZE, SIZE).expect("size");
    one.install(|| single.render_frame());
    assert_eq!(m.image().pixels(), single.image().pixels());
}

#[test]
fn film_memory_stays_within_one_and_a_half_times_one_light() {
    const SIZE: u32 = 1024;
    let bytes = |n: usize| {
        let m = SpmmMode::new(many_lights_scene(n), SIZE, SIZE).expect("fits");
        let b = m.film().bytes();
        assert_eq!(m.progress().film_bytes, b);
        assert_eq!(b, Film::bytes_for(SIZE, SIZE, m.film().layers()));
        b
    };
    let one = bytes(1);
    for n in [100, 10_000] {
        let b = bytes(n);
        assert!(
            b as f64 <= 1.5 * one as f64,
            "{n} lights: {b} bytes against {one} for one light"
        );
    }
    assert_eq!(
        Film::bytes_for(SIZE, SIZE, SHARED_LIGHTS + 1),
        bytes(10_000),
        "own layers and one shared layer"
    );
}

/// `film` resolved with the mode's weights except `zero` set to zero.
fn resolve_without(m: &SpmmMode, zero: &[usize]) -> Image {
    let mut w = m.layer_weights();
    for &l in zero {
        w[l] = DVec3::ZERO;
    }
    m.film().resolve(&w)
}

fn assert_close(a: &Image, b: &Image) {
    for (p, q) in a.pixels().iter().zip(b.pixels()) {
        for c in 0..3 {
            assert!(
                (p[c] - q[c]).abs() <= 1e-5 * p[c].abs().max(q[c].abs()).max(1e-3),
                "{p:?} vs {q:?}"
            );
        }
    }
}

/// The two brightest lights (they own the layers of a fresh bounded film) and one
/// point light in the shared layer.
fn brightest_two_and_a_shared_point(scene: &Scene) -> (usize, usize, usize) {
    let mut order: Vec<usize> = (0..scene.lights.len()).collect();
    order.sort_by(|&a, &b| {
        meso_render::layers::light_power(&scene.lights[b])
            .total_cmp(&meso_render::layers::light_power(&scene.lights[a]))
    });
    let shared = order[OWN_LIGHT_LAYERS..]
        .iter()
        .copied()
        .find(|&k| matches!(scene.lights[k], Light::Point { .. }))
        .expect("point lights");
    (order[0], order[1], shared)
}

#[test]
fn an_edit_among_thousands_restarts_only_the_promoted_slot_and_the_shared_layer() {
    // The exact path on a bounded film: its samples of one light do not depend on the
    // others, so what the rule keeps can be compared with a fresh render bit for bit
    // (to rounding). The stochastic path keeps the same layers (tested below) but its
    // samples of one light depend on the others through the resampling.
    const SIZE: u32 = 8;
    let scene = many_lights_scene(2000);
    let (a, _b, c) = brightest_two_and_a_shared_point(&scene);
    let exact = |scene: Scene, frames: u32| {
        let mut m = SpmmMode::new(scene, SIZE, SIZE).expect("size");
        m.set_light_sampling(LightSampling::Exact);
        for _ in 0..frames {
            m.render_frame();
        }
        m
    };
    let mut m = exact(scene.clone(), 4);
    assert_eq!(m.film().layers(), SHARED_LIGHTS + 1);
    let slot_of = |m: &SpmmMode, k: usize| {
        (0..OWN_LIGHT_LAYERS).find(|&s| m.light_targets[k].layer == FIRST_LIGHT + s)
    };
    assert_eq!(slot_of(&m, a), Some(0), "the brightest owns slot 0");
    let before = m.progress();
    // An emission edit of an own light re-weights.
    let mut brighter = scene.lights[a];
    brighter = brighter.with_emission(brighter.emission() * 2.0);
    assert_eq!(
        m.apply(SceneEdit::Light {
            index: a,
            light: brighter
        }),
        Ok(Invalidation::Nothing)
    );
    assert_eq!(m.progress(), before);
    // Moving a light of the shared layer promotes it to the slot of the dimmer own
    // light (used least recently), restarting that slot and the shared layer.
    let mut moved = scene.lights[c];
    if let Light::Point { position, .. } = &mut moved {
        position.x += 0.3;
    }
    assert_eq!(
        m.apply(SceneEdit::Light {
            index: c,
            light: moved
        }),
        Ok(Invalidation::Layers(vec![FIRST_LIGHT + 1, SHARED_LIGHTS]))
    );
    assert_eq!(slot_of(&m, c), Some(1));
    assert_eq!(slot_of(&m, a), Some(0), "the other slot kept its light");
    for _ in 0..4 {
        m.render_frame();
    }
    // m: light a and the background over frames 0..8, every other light over
    // frames 4..8. A fresh render of the edited scene over 8 and 4 frames gives both:
    // frames 4..8 of the rest are 2 * mean(0..8) - mean(0..4).
    let mut edited = scene.clone();
    edited.lights[a] = brighter;
    edited.lights[c] = moved;
    let (f8, f4) = (exact(edited.clone(), 8), exact(edited, 4));
    // Kept: light a's layer and the background (0..8); restarted: the other lights.
    let a_layer = f8.light_targets[a].layer;
    let restarted: Vec<usize> = (FIRST_LIGHT..=SHARED_LIGHTS)
        .filter(|&l| l != a_layer)
        .collect();
    let kept: Vec<usize> = (0..=SHARED_LIGHTS)
        .filter(|l| !restarted.contains(l))
        .collect();
    let only_a = resolve_without(&f8, &restarted);
    let (rest8, rest4) = (resolve_without(&f8, &kept), resolve_without(&f4, &kept));
    let mut expected = only_a.clone();
    for (e, (r8, r4)) in expected
        .pixels_mut()
        .iter_mut()
        .zip(rest8.pixels().iter().zip(rest4.pixels()))
    {
        for ((e, r8), r4) in e.iter_mut().zip(r8).zip(r4) {
            *e += 2.0 * r8 - r4;
        }
    }
    assert_close(&m.image(), &expected);
}

#[test]
fn a_stochastic_edit_among_thousands_keeps_the_same_layers_and_converges_to_the_edit() {
    const SIZE: u32 = 8;
    const N: u64 = 48;
    let scene = many_lights_scene(1000);
    let (a, _, c) = brightest_two_and_a_shared_point(&scene);
    let mut m = SpmmMode::new(scene.clone(), SIZE, SIZE).expect("size");
    m.render_frame();
    let dim = scene.lights[a].with_emission(DVec3::ZERO);
    assert_eq!(
        m.apply(SceneEdit::Light {
            index: a,
            light: dim
        }),
        Ok(Invalidation::Nothing)
    );
    let bright = scene.lights[c].with_emission(DVec3::new(0.5, 0.2, 0.1));
    assert_eq!(
        m.apply(SceneEdit::Light {
            index: c,
            light: bright
        }),
        Ok(Invalidation::Layers(vec![FIRST_LIGHT + 1, SHARED_LIGHTS]))
    );
    assert_eq!(m.progress().min_samples, 0);
    // Its own layer now re-weights: editing it again costs nothing.
    let brighter = bright.with_emission(DVec3::new(1.0, 0.4, 0.2));
    assert_eq!(
        m.apply(SceneEdit::Light {
            index: c,
            light: brighter
        }),
        Ok(Invalidation::Nothing)
    );
    // From here, every sample estimates the edited scene without bias: compare with
    // tracing every light of the edited scene, sample by sample.
    let mut edited = scene;
    edited.lights[a] = dim;
    edited.lights[c] = brighter;
    let mut exact = SpmmMode::new(edited, SIZE, SIZE).expect("size");
    exact.set_light_sampling(LightSampling::Exact);
    let (s, e) = (samples(&m, SIZE, 0..N), samples(&exact, SIZE, 0..N));
    let diff = (0..N as usize)
        .map(|i| (s[i].iter().sum::<f64>() - e[i].iter().sum::<f64>()) / (SIZE * SIZE) as f64);
    let (d, sd) = mean_sd(diff);
    assert!(
        d.abs() < 4.0 * sd / (N as f64).sqrt(),
        "off by {d} (sd {sd})"
    );
}

#[test]
fn crossing_the_threshold_lays_the_light_layers_out_again() {
    let mut scene = many_lights_scene(MANY_LIGHTS);
    let extra = scene.lights.pop().expect("lights");
    let mut m = SpmmMode::new(scene, 6, 6).expect("size");
    m.render_frame();
    assert_eq!(m.film().layers(), FIRST_LIGHT + MANY_LIGHTS - 1);
    assert_eq!(
        m.apply(SceneEdit::AddLight(extra)),
        Ok(Invalidation::Layer(FIRST_LIGHT + MANY_LIGHTS - 1))
    );
    assert_eq!(
        m.apply(SceneEdit::AddLight(extra)),
        Ok(Invalidation::Layers(
            (FIRST_LIGHT..=SHARED_LIGHTS).collect()
        ))
    );
    assert!(m.light_layers().bounded());
    assert_eq!(m.film().layers(), SHARED_LIGHTS + 1);
    m.render_frame();
    assert_eq!(m.progress().min_samples, 1);
    assert_eq!(
        m.apply(SceneEdit::RemoveLight(0)),
        Ok(Invalidation::Layers(
            (FIRST_LIGHT..FIRST_LIGHT + MANY_LIGHTS).collect()
        ))
    );
    assert!(!m.light_layers().bounded());
    assert_eq!(m.film().layers(), FIRST_LIGHT + MANY_LIGHTS);
}

#[test]
fn a_film_that_cannot_fit_is_refused_naming_its_bytes() {
    let err = Film::check(16384, 16384, 19, 1 << 30).expect_err("145 GB");
    let bytes = Film::bytes_for(16384, 16384, 19);
    assert_eq!(bytes, 16384 * 16384 * (19 * 28 + 8 + 16));
    let msg = err.to_string();
    assert!(msg.contains(&bytes.to_string()), "{msg}");
    assert!(!msg.contains('\n'));
    // 16 lights: 19 layers, 145 GB at the largest size, more than this machine has.
    let scene = many_lights_scene(MANY_LIGHTS);
    match SpmmMode::new(scene, 16384, 16384) {
        Err(ModeError::TooLarge(e)) => {
            assert_eq!(e.bytes, bytes);
            assert!(e.to_string().contains("bytes"), "{e}");
        }
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("a 145 GB film was allocated"),
    }
    // A resize is refused the same way and changes nothing.
    let mut m = SpmmMode::new(many_lights_scene(MANY_LIGHTS), 4, 4).expect("small");
    let err = m
        .apply(SceneEdit::Resize {
            width: 16384,
            height: 16384,
        })
        .expect_err("too large");
    assert!(err.to_string().contains(&bytes.to_string()), "{err}");
    assert_eq!(m.film().width(), 4);
}
