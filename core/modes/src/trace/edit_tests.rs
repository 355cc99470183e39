//! Edits restart only what they invalidate, and what they keep is exactly right: the
//! image after an edit equals (to float rounding) a render that had the edit from the
//! start, wherever the edit claims to keep samples.

use glam::DVec3;

use super::SpmmMode;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
use meso_materials::image::Image;
use meso_render::layers::{AMBIENT, FIRST_LIGHT};
use meso_render::scene::test_scenes::edit_test_scene as scene;
use meso_render::scene::{Ambient, Background, Light, Material, Scene};
use meso_render::{Invalidation, RenderMode, SceneEdit};
use meso_render::{Pass, RenderModeExt};

const SIZE: u32 = 24;

fn rendered(scene: Scene, frames: u32) -> SpmmMode {
    let mut m = SpmmMode::new(scene, SIZE, SIZE).expect("size");
    for _ in 0..frames {
        m.render_frame();
    }
    m
}

/// Equal up to f32 rounding: 1e-5 relative, and 1e-7 absolute for values that come
/// from a difference of two images (`frames_between`) of radiance around 1e-2, whose
/// rounding is that of the images, not of the small result.
fn assert_close(a: &Image, b: &Image) {
    for (p, q) in a.pixels().iter().zip(b.pixels()) {
        for c in 0..3 {
            assert!(
                (p[c] - q[c]).abs() <= 1e-5 * p[c].abs().max(q[c].abs()).max(1e-2),
                "{p:?} vs {q:?}"
            );
        }
    }
}

/// The image of `m` through some emitters only: the lights not in `lights` at zero
/// emission, the ambient term only if `ambient`, a black background. Each is a
/// re-weighting (`Invalidation::Nothing`), so no sample changes.
fn through(m: &mut SpmmMode, lights: &[usize], ambient: bool) -> Image {
    let scene = m.scene().clone();
    for (i, l) in scene.lights.iter().enumerate() {
        let e = if lights.contains(&i) {
            l.emission()
        } else {
            DVec3::ZERO
        };
        let edit = SceneEdit::Light {
            index: i,
            light: l.with_emission(e),
        };
        assert_eq!(m.apply(edit), Ok(Invalidation::Nothing));
    }
    if !ambient {
        assert_eq!(m.apply(SceneEdit::Ambient(None)), Ok(Invalidation::Nothing));
    }
    let black = SceneEdit::Background(Background::Color(DVec3::ZERO));
    assert_eq!(m.apply(black), Ok(Invalidation::Nothing));
    m.image()
}

/// The mean of frames `early..late` from the means over `0..late` and `0..early`.
fn frames_between(late: &Image, late_n: u32, early: &Image, early_n: u32) -> Image {
    let mut out = late.clone();
    let (a, b) = (late_n as f32, early_n as f32);
    for (o, (p, q)) in out
        .pixels_mut()
        .iter_mut()
        .zip(late.pixels().iter().zip(early.pixels()))
    {
        for c in 0..3 {
            o[c] = (a * p[c] - b * q[c]) / (a - b);
        }
    }
    out
}

#[test]
fn emission_edits_keep_every_sample_and_equal_a_fresh_render() {
    let mut m = rendered(scene(), 3);
    let before = m.progress();
    let mut brighter = scene().lights;
    brighter[0] = brighter[0].with_emission(DVec3::new(9.0, 3.0, 1.0));
    brighter[1] = brighter[1].with_emission(DVec3::ZERO);
    for (i, l) in brighter.iter().enumerate() {
        let edit = SceneEdit::Light {
            index: i,
            light: *l,
        };
        assert_eq!(m.apply(edit), Ok(Invalidation::Nothing));
    }
    let ambient = Some(Ambient {
        radiance: DVec3::new(0.1, 0.2, 0.3),
        radius: 0.5,
    });
    assert_eq!(
        m.apply(SceneEdit::Ambient(ambient)),
        Ok(Invalidation::Nothing)
    );
    let bg = Background::Color(DVec3::new(1.0, 0.0, 0.0));
    assert_eq!(
        m.apply(SceneEdit::Background(bg.clone())),
        Ok(Invalidation::Nothing)
    );
    assert_eq!(m.progress(), before, "no sample was lost");
    let mut edited = scene();
    edited.lights = brighter;
    edited.ambient = ambient;
    edited.background = bg;
    assert_close(&m.image(), &rendered(edited, 3).image());
}

#[test]
fn a_moved_light_restarts_only_its_layer() {
    let mut m = rendered(scene(), 4);
    let mut moved = scene().lights[0];
    if let Light::Area { corner, .. } = &mut moved {
        corner.x += 0.5;
    }
    assert_eq!(
        m.apply(SceneEdit::Light {
            index: 0,
            light: moved
        }),
        Ok(Invalidation::Layer(FIRST_LIGHT))
    );
    assert_eq!(
        m.progress().min_samples,
        0,
        "the moved light's layer restarted"
    );
    for _ in 0..4 {
        m.render_frame();
    }
    // Its layer now holds frames 4..8, the others frames 0..8. Seen through the moved
    // light alone, that is a 4-frame render starting at frame 4; through the others
    // alone, an 8-frame render.
    let mut only_moved = scene();
    only_moved.lights = vec![moved, scene().lights[1].with_emission(DVec3::ZERO)];
    only_moved.ambient = None;
    only_moved.background = Background::Color(DVec3::ZERO);
    let mut fresh = SpmmMode::new(only_moved, SIZE, SIZE).expect("size");
    for _ in 0..8 {
        fresh.render_frame();
    }
    let isolate = |m: &mut SpmmMode, keep_moved: bool| {
        let lights = m.scene().lights.clone();
        for (i, l) in lights.iter().enumerate() {
            let e = if (i == 0) == keep_moved {
                l.emission()
            } else {
                DVec3::ZERO
            };
            m.apply(SceneEdit::Light {
                index: i,
                light: l.with_emission(e),
            })
            .expect("valid");
        }
        m.apply(SceneEdit::Ambient(None)).expect("valid");
        m.apply(SceneEdit::Background(Background::Color(DVec3::ZERO)))
            .expect("valid");
        m.image()
    };
    // The fresh render's first 4 frames are not in `m`'s layer: compare against the
    // mean of frames 4..8 of a fresh render, which is 2 * mean(0..8) - mean(0..4).
    let mut fresh4 = SpmmMode::new(fresh.scene().clone(), SIZE, SIZE).expect("size");
    for _ in 0..4 {
        fresh4.render_frame();
    }
    let (f8, f4) = (fresh.image(), fresh4.image());
    let mut expected = f8.clone();
    for (e, (p8, p4)) in expected
        .pixels_mut()
        .iter_mut()
        .zip(f8.pixels().iter().zip(f4.pixels()))
    {
        for c in 0..3 {
            e[c] = 2.0 * p8[c] - p4[c];
        }
    }
    assert_close(&isolate(&mut m, true), &expected);
    let mut unmoved = rendered(scene(), 8);
    let mut m2 = rendered(scene(), 4);
    m2.apply(SceneEdit::Light {
        index: 0,
        light: moved,
    })
    .expect("valid");
    for _ in 0..4 {
        m2.render_frame();
    }
    assert_close(&isolate(&mut m2, false), &isolate(&mut unmoved, false));
}

#[test]
fn a_material_edit_restarts_only_the_pixels_that_shaded_it() {
    let mut m = rendered(scene(), 2);
    let red = Material::Brdf {
        brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        albedo: DVec3::new(0.8, 0.1, 0.1),
    };
    let Ok(Invalidation::Pixels(n)) = m.apply(SceneEdit::Material {
        index: 1,
        material: red.clone(),
    }) else {
        panic!("a material edit restarts pixels");
    };
    let total = (SIZE * SIZE) as usize;
    assert!(
        n > 20 && n < total / 2,
        "{n} of {total} pixels see the panel"
    );
    // Pixels that never saw the panel keep their two frames and equal a fresh render's.
    let mut edited = scene();
    edited.materials[1] = red;
    let fresh = rendered(edited, 2).image();
    let kept = m.image();
    let equal = kept
        .pixels()
        .iter()
        .zip(fresh.pixels())
        .filter(|(a, b)| a == b)
        .count();
    assert!(equal >= total - n, "{equal} equal pixels, {n} restarted");
    // The first call traces the restarted pixels early; the next two complete two
    // frames, the first of them begun by it.
    assert_eq!(m.render_frame().counters.samples, n as u64);
    for _ in 0..2 {
        m.render_frame();
    }
    assert_eq!(
        m.progress().min_samples,
        2,
        "restarted pixels have 2 samples"
    );
}

#[test]
fn moving_keeps_the_first_components_and_stopping_restores_all() {
    let mut m = rendered(scene(), 1);
    let still = m.image();
    let Ok(Invalidation::Pixels(n)) = m.apply(SceneEdit::Moving(true)) else {
        panic!("moving restarts the residual material's pixels");
    };
    assert!(n > 0);
    m.render_frame();
    let moving = m.image();
    assert_ne!(still, moving, "the later components are skipped");
    // Every sample equals a still render's of the material with MOVING_NPCA components,
    // and differs from one without its residual somewhere.
    let with_npca = |npca: Option<usize>| {
        let mut s = scene();
        if let Material::Spmm {
            residual, npca: n, ..
        } = &mut s.materials[1]
        {
            *residual = npca.is_some();
            *n = npca.unwrap_or(*n);
        }
        SpmmMode::new(s, SIZE, SIZE).expect("size")
    };
    let reference = with_npca(Some(meso_materials::spmm::MOVING_NPCA));
    let no_residual = with_npca(None);
    let with_residual = SpmmMode::new(scene(), SIZE, SIZE).expect("size");
    let (mut differ, mut differ_from_none) = (0, 0);
    for (x, y) in (0..SIZE).flat_map(|y| (0..SIZE).map(move |x| (x, y))) {
        assert_eq!(
            m.sample(x, y, 5).0,
            reference.sample(x, y, 5).0,
            "pixel {x},{y}"
        );
        differ += usize::from(m.sample(x, y, 5).0 != with_residual.sample(x, y, 5).0);
        differ_from_none += usize::from(m.sample(x, y, 5).0 != no_residual.sample(x, y, 5).0);
    }
    assert!(differ_from_none > 0, "the kept components shade");
    assert!(differ > 0, "the later components matter somewhere");
    assert_eq!(m.apply(SceneEdit::Moving(true)), Ok(Invalidation::Nothing));
    assert!(matches!(m.apply(SceneEdit::Moving(false)), Ok(Invalidation::Pixels(k)) if k > 0));
    // Pixels that saw the panel restarted; the rest kept both frames.
    m.render_frame();
    assert_eq!(m.progress().min_samples, 1);
}

/// A residual of no more components than a moving camera keeps renders alike moving
/// or still: the flag restarts nothing.
#[test]
fn moving_restarts_nothing_when_the_residual_is_kept_whole() {
    let mut few = scene();
    if let Material::Spmm { npca, .. } = &mut few.materials[1] {
        *npca = meso_materials::spmm::MOVING_NPCA;
    }
    let mut m = rendered(few, 1);
    assert_eq!(m.apply(SceneEdit::Moving(true)), Ok(Invalidation::Nothing));
    assert_eq!(m.apply(SceneEdit::Moving(false)), Ok(Invalidation::Nothing));
}

#[test]
fn a_light_samples_edit_restarts_everything_and_equals_a_fresh_render() {
    let mut m = rendered(scene(), 2);
    assert_eq!(m.apply(SceneEdit::LightSamples(3)), Ok(Invalidation::All));
    assert_eq!(m.progress().min_samples, 0);
    m.render_frame();
    m.render_frame();
    let mut three = scene();
    three.render.light_samples = 3;
    assert_eq!(m.image(), rendered(three, 2).image());
    // The scene's area light makes the count matter.
    assert_ne!(m.image(), rendered(scene(), 2).image());
    for bad in [0, meso_render::scene::MAX_LIGHT_SAMPLES + 1] {
        assert_eq!(
            m.apply(SceneEdit::LightSamples(bad)),
            Err(meso_render::EditError::LightSamples(bad))
        );
    }
    assert_eq!(
        m.scene().render.light_samples,
        3,
        "a refused edit changes nothing"
    );
}

#[test]
fn camera_size_and_geometry_edits_restart_everything_and_refit() {
    let mut m = rendered(scene(), 2);
    let mut cam = scene().camera;
    cam.position.x += 0.1;
    assert_eq!(m.apply(SceneEdit::Camera(cam)), Ok(Invalidation::All));
    assert_eq!(m.progress().min_samples, 0);
    // From a full restart on, the image is exactly a fresh render's.
    m.render_frame();
    m.render_frame();
    let mut moved = scene();
    moved.camera = cam;
    assert_eq!(m.image(), rendered(moved, 2).image());
    let mut bad = cam;
    bad.look_at = bad.position;
    assert!(
        m.apply(SceneEdit::Camera(bad)).is_err(),
        "degenerate camera refused"
    );
    assert_eq!(m.scene().camera, cam, "a refused edit changes nothing");
    assert_eq!(
        m.apply(SceneEdit::Resize {
            width: 8,
            height: 6
        }),
        Ok(Invalidation::All)
    );
    m.render_frame();
    m.render_frame();
    // Samples restart with their indices: a fresh 8x6 render of the same scene.
    let fresh_8x6 = |scene: Scene| {
        let mut f = SpmmMode::new(scene, 8, 6).expect("size");
        f.render_frame();
        f.render_frame();
        f.image()
    };
    assert_eq!((m.image().width(), m.image().height()), (8, 6));
    assert_eq!(m.image(), fresh_8x6(m.scene().clone()));
    assert!(
        m.apply(SceneEdit::Resize {
            width: 0,
            height: 6
        })
        .is_err()
    );
    let mut meshes = scene().meshes;
    for p in &mut meshes[1].positions {
        p.x += 0.3;
    }
    assert_eq!(
        m.apply(SceneEdit::Meshes(meshes.clone())),
        Ok(Invalidation::All)
    );
    assert!(m.bvh().refitted(), "same triangles are refitted");
    // The refitted BVH renders what a fresh build of the moved scene renders.
    m.render_frame();
    m.render_frame();
    let mut moved_panel = m.scene().clone();
    moved_panel.meshes = meshes.clone();
    assert_eq!(m.image(), fresh_8x6(moved_panel));
    meshes[1].material = 7;
    assert!(
        m.apply(SceneEdit::Meshes(meshes)).is_err(),
        "unknown material refused"
    );
}

#[test]
fn lights_are_added_and_removed_and_the_ambient_radius_restarts_its_layer() {
    let mut m = rendered(scene(), 2);
    let extra = Light::Point {
        position: DVec3::new(-1.0, 1.0, 0.5),
        intensity: DVec3::splat(2.0),
    };
    assert_eq!(
        m.apply(SceneEdit::AddLight(extra)),
        Ok(Invalidation::Layer(FIRST_LIGHT + 2))
    );
    m.render_frame();
    assert_eq!(
        m.apply(SceneEdit::RemoveLight(0)),
        Ok(Invalidation::Nothing)
    );
    assert!(m.apply(SceneEdit::RemoveLight(5)).is_err());
    // Lights now: the point light (3 frames) and the extra one (1 frame).
    assert_eq!(m.progress().min_samples, 1);
    let wider = Some(Ambient {
        radiance: DVec3::splat(0.3),
        radius: 2.0,
    });
    assert_eq!(
        m.apply(SceneEdit::Ambient(wider)),
        Ok(Invalidation::Layer(AMBIENT))
    );
    assert_eq!(m.progress().min_samples, 0);
    // AO off and on again with the same radius keeps the layer's samples.
    m.render_frame();
    assert_eq!(m.apply(SceneEdit::Ambient(None)), Ok(Invalidation::Nothing));
    assert_eq!(
        m.apply(SceneEdit::Ambient(wider)),
        Ok(Invalidation::Nothing)
    );
    assert_eq!(m.progress().min_samples, 1);
}

#[test]
fn added_removed_lights_and_a_new_ambient_radius_keep_exactly_the_right_layers() {
    // What can be asserted exactly: a light added at the end leaves every other
    // emitter's random numbers where they were (lights draw in order, 2 numbers each),
    // so the kept lights equal a fresh render of the edited scene through them, and the
    // new light's layer equals frames 2..4 of it. (The ambient term draws after the
    // lights, so its numbers move with a new light: its kept samples are valid, but not
    // those of any one fresh render; it is left out here.)
    let extra = Light::Point {
        position: DVec3::new(-1.0, 1.0, 0.5),
        intensity: DVec3::splat(2.0),
    };
    let mut with_extra = scene();
    with_extra.lights.push(extra);
    let added = || {
        let mut m = rendered(scene(), 2);
        assert_eq!(
            m.apply(SceneEdit::AddLight(extra)),
            Ok(Invalidation::Layer(FIRST_LIGHT + 2))
        );
        m.render_frame();
        m.render_frame();
        m
    };
    assert_close(
        &through(&mut added(), &[0, 1], false),
        &through(&mut rendered(with_extra.clone(), 4), &[0, 1], false),
    );
    let new_light = |frames| through(&mut rendered(with_extra.clone(), frames), &[2], false);
    assert_close(
        &through(&mut added(), &[2], false),
        &frames_between(&new_light(4), 4, &new_light(2), 2),
    );

    // Removing a light drops its layer: at that moment the image is the same samples
    // with that light's emission at zero. (Later frames draw the remaining lights'
    // numbers one light earlier, so they match no single fresh render.)
    let mut removed = rendered(scene(), 3);
    assert_eq!(
        removed.apply(SceneEdit::RemoveLight(0)),
        Ok(Invalidation::Nothing)
    );
    let mut zeroed = rendered(scene(), 3);
    let dark = scene().lights[0].with_emission(DVec3::ZERO);
    assert_eq!(
        zeroed.apply(SceneEdit::Light {
            index: 0,
            light: dark
        }),
        Ok(Invalidation::Nothing)
    );
    assert_eq!(removed.image(), zeroed.image());

    // A new ambient radius restarts the ambient layer with the sample indices going on:
    // it holds frames 2..4 of the edited scene's ambient term, the lights all 4 frames.
    let wider = Some(Ambient {
        radiance: DVec3::splat(0.3),
        radius: 2.0,
    });
    let mut edited = scene();
    edited.ambient = wider;
    let widened = || {
        let mut m = rendered(scene(), 2);
        assert_eq!(
            m.apply(SceneEdit::Ambient(wider)),
            Ok(Invalidation::Layer(AMBIENT))
        );
        m.render_frame();
        m.render_frame();
        m
    };
    assert_close(
        &through(&mut widened(), &[0, 1], false),
        &through(&mut rendered(edited.clone(), 4), &[0, 1], false),
    );
    let ambient_only = |frames| through(&mut rendered(edited.clone(), frames), &[], true);
    assert_close(
        &through(&mut widened(), &[], true),
        &frames_between(&ambient_only(4), 4, &ambient_only(2), 2),
    );
}

/// A frame asked to stop between tiles keeps the rows it finished; the next call
/// finishes it with exactly the samples an uninterrupted frame takes, across an
/// emission edit applied while it was stopped; a camera edit restarts as always.
#[test]
fn a_frame_stopped_between_tiles_finishes_with_an_uninterrupted_frames_samples() {
    // 200 x 200 = 40,000 pixels: three tiles of `TILE_PIXELS` rows' worth.
    const W: u32 = 200;
    let brighter = SceneEdit::Light {
        index: 0,
        light: scene().lights[0].with_emission(DVec3::new(4.0, 2.0, 1.0)),
    };
    let mut whole = SpmmMode::new(scene(), W, W).expect("size");
    let mut stopped = SpmmMode::new(scene(), W, W).expect("size");
    let mut asked = 0;
    for frame in 0..3u32 {
        whole.render_frame();
        let part = stopped.render_frame_yielding(&mut || {
            asked += 1;
            true
        });
        let taken = part.counters.samples;
        assert!(
            taken > 0 && taken < u64::from(W * W),
            "frame {frame}: {taken} samples"
        );
        assert_eq!(stopped.progress().frames, frame, "the frame is unfinished");
        if frame == 1 {
            assert_eq!(stopped.apply(brighter.clone()), Ok(Invalidation::Nothing));
        }
        let rest = stopped.render_frame_yielding(&mut || false);
        assert_eq!(taken + rest.counters.samples, u64::from(W * W));
        assert_eq!(stopped.progress().frames, frame + 1);
    }
    assert_eq!(
        asked, 3,
        "asked once per stopped frame, never after the last tile"
    );
    assert_eq!(whole.apply(brighter), Ok(Invalidation::Nothing));
    assert!(
        whole.image().pixels() == stopped.image().pixels(),
        "stopped frames differ from uninterrupted ones"
    );

    // A camera edit while a frame is stopped restarts everything: a fresh render.
    let mut camera = scene().camera;
    camera.position += DVec3::new(0.3, 0.1, 0.0);
    stopped.render_frame_yielding(&mut || true);
    assert_eq!(
        stopped.apply(SceneEdit::Camera(camera)),
        Ok(Invalidation::All)
    );
    stopped.render_frame_yielding(&mut || false);
    // (A fresh render of the edited scene: the brighter light, the moved camera.)
    let mut fresh = SpmmMode::new(stopped.scene().clone(), W, W).expect("size");
    fresh.render_frame();
    assert!(stopped.image().pixels() == fresh.image().pixels());
}

/// A preview renders one pixel per block of the frame to come and nothing else; the
/// frame it starts completes the rest, so the film equals an uninterrupted render's;
/// there is no preview once pixels have samples, and again after a camera edit.
#[test]
fn a_preview_takes_the_frames_own_samples_of_one_pixel_per_block() {
    use meso_render::preview::grid_pixels;
    const W: u32 = 40;
    const STRIDE: u32 = 4;
    let mut whole = SpmmMode::new(scene(), W, W).expect("size");
    let mut previewed = SpmmMode::new(scene(), W, W).expect("size");
    let grid = grid_pixels(W, W, STRIDE);
    let preview = previewed
        .render_preview(STRIDE)
        .expect("an empty film previews");
    assert_eq!(preview.counters.samples, grid.len() as u64);
    assert_eq!(previewed.progress().frames, 0, "the frame is unfinished");
    let image = previewed.image();
    let lit = |p: usize| image.pixels()[p] != [0.0; 3];
    assert!(
        grid.iter().all(|&p| lit(p as usize)),
        "a previewed pixel is black"
    );
    let off_grid = (0..(W * W) as usize).filter(|p| !grid.contains(&(*p as u32)));
    assert!(
        off_grid.clone().all(|p| !lit(p)),
        "a pixel off the grid was sampled"
    );
    assert!(
        previewed.render_preview(STRIDE).is_none(),
        "previewed twice"
    );
    // The preview's guides are the full guides at the previewed pixels.
    let (full, small) = (
        previewed.guides(Pass::Frame).expect("guides"),
        previewed
            .guides(Pass::Preview { stride: STRIDE })
            .expect("preview guides"),
    );
    let size = meso_render::preview::grid_size(W, W, STRIDE);
    assert_eq!((small.width, small.height), size);
    for (i, &p) in grid.iter().enumerate() {
        let p = p as usize;
        assert_eq!(
            (small.normal[i], small.depth[i], small.albedo[i]),
            (full.normal[p], full.depth[p], full.albedo[p])
        );
    }

    let rest = previewed.render_frame();
    assert_eq!(rest.counters.samples, u64::from(W * W) - grid.len() as u64);
    whole.render_frame();
    for m in [&mut whole, &mut previewed] {
        m.render_frame();
        assert!(
            m.render_preview(STRIDE).is_none(),
            "a film with samples previews"
        );
    }
    assert!(whole.image().pixels() == previewed.image().pixels());

    let mut camera = scene().camera;
    camera.position += DVec3::new(0.3, 0.1, 0.0);
    assert_eq!(
        previewed.apply(SceneEdit::Camera(camera)),
        Ok(Invalidation::All)
    );
    assert!(
        previewed.render_preview(1).is_none(),
        "a stride of 1 is a whole frame"
    );
    assert!(
        previewed.render_preview(STRIDE).is_some(),
        "no preview after a camera edit"
    );
}

/// A moved light restarts its layer in every pixel, so its next frame is previewed as
/// a camera edit's is: the preview takes that frame's samples of one pixel per block
/// (every layer of them, as the frame would) and the frame completes the rest, so the
/// film equals one the same edit left to a whole frame.
#[test]
fn a_moved_light_is_previewed_and_the_frame_completes_it() {
    const W: u32 = 40;
    const STRIDE: u32 = 4;
    let mut moved = scene().lights[0];
    if let Light::Area { corner, .. } = &mut moved {
        corner.x += 0.5;
    }
    let grid = meso_render::preview::grid_pixels(W, W, STRIDE);
    let mut modes = [(); 2].map(|_| SpmmMode::new(scene(), W, W).expect("size"));
    for m in &mut modes {
        m.render_frame();
        m.render_frame();
        assert!(m.render_preview(STRIDE).is_none(), "a film with samples");
        let edit = SceneEdit::Light {
            index: 0,
            light: moved,
        };
        assert_eq!(m.apply(edit), Ok(Invalidation::Layer(FIRST_LIGHT)));
    }
    let [whole, previewed] = &mut modes;
    let preview = previewed
        .render_preview(STRIDE)
        .expect("a restarted layer previews");
    assert_eq!(preview.counters.samples, grid.len() as u64);
    assert!(
        previewed.render_preview(STRIDE).is_none(),
        "previewed twice"
    );
    let rest = previewed.render_frame();
    assert_eq!(rest.counters.samples, u64::from(W * W) - grid.len() as u64);
    whole.render_frame();
    assert!(whole.image().pixels() == previewed.image().pixels());
    assert!(previewed.progress().shows_every_pixel);
}
