//! A brush stroke on the object: it covers exactly the texels under the brush (found
//! here from the quad, the camera and the brush by hand, not through picking), the
//! edit changes only those texels, and only pixels whose samples saw them restart.

use std::sync::Arc;

use glam::{DVec2, DVec3};

use super::SpmmMode;
use meso_materials::spmm::{Falloff, TexelMask, WeightTarget};
use meso_render::RenderModeExt;
use meso_render::geometry::brush::{self, Brush, BrushUnits};
use meso_render::scene::Material;
use meso_render::scene::test_scenes::edit_test_scene;
use meso_render::{Invalidation, RenderMode, SceneEdit};

const SIZE: u32 = 64;

/// Where the ray through image point (x, y) meets the panel (the quad at z = 0, x in
/// [-0.4, 0.4], y in [0, 0.8], u along x and v along y), as its UV; the camera of
/// `edit_test_scene` written out: at (0, 1.2, 2) looking at (0, 0.2, 0), 50 degrees.
fn panel_uv(x: f64, y: f64) -> Option<DVec2> {
    let eye = DVec3::new(0.0, 1.2, 2.0);
    let forward = (DVec3::new(0.0, 0.2, 0.0) - eye).normalize();
    let right = forward.cross(DVec3::Y).normalize();
    let up = right.cross(forward);
    let half = 25f64.to_radians().tan();
    let sx = x / SIZE as f64 * 2.0 - 1.0;
    let sy = 1.0 - y / SIZE as f64 * 2.0;
    let dir = forward + right * (sx * half) + up * (sy * half);
    let t = -eye.z / dir.z;
    let p = eye + dir * t;
    // The floor (y = 0 plane, in front of the panel) hides the panel below y = 0.
    let floor_t = -eye.y / dir.y;
    if dir.y < 0.0 && floor_t < t {
        return None;
    }
    ((-0.4..=0.4).contains(&p.x) && (0.0..=0.8).contains(&p.y))
        .then(|| DVec2::new((p.x + 0.4) / 0.8, p.y / 0.8))
}

/// Continuous texel coordinates of a panel UV: tiled twice, 4 x 4 texels, v up.
fn texel_xy(uv: DVec2) -> DVec2 {
    let (u, v) = ((uv.x * 2.0).rem_euclid(1.0), (uv.y * 2.0).rem_euclid(1.0));
    DVec2::new(u * 4.0, (1.0 - v) * 4.0)
}

fn texel_index(p: DVec2) -> usize {
    (p.y.floor().min(3.0) as usize) * 4 + p.x.floor().min(3.0) as usize
}

#[test]
fn a_stroke_changes_only_the_texels_under_the_brush_and_restarts_only_pixels_that_saw_them() {
    let scene = edit_test_scene();
    let mut mode = SpmmMode::new(scene.clone(), SIZE, SIZE).expect("size");
    for _ in 0..3 {
        mode.render_frame();
    }
    let brush = Brush {
        radius: 0.9,
        units: BrushUnits::Texels,
        strength: 1.0,
        falloff: Falloff::Constant,
    };
    // One dab at an image point on the panel.
    let at = DVec2::new(30.3, 28.6);
    let mut mask = TexelMask::empty(4, 4);
    assert!(brush::dab(
        &scene,
        mode.bvh(),
        (SIZE, SIZE),
        at,
        &brush,
        1,
        &mut mask
    ));
    // By hand: texel centres within 0.9 texels of the point under the cursor, wrapping.
    let centre = texel_xy(panel_uv(at.x, at.y).expect("the dab is on the panel"));
    let expected: Vec<usize> = (0..16)
        .filter(|t| {
            let c = DVec2::new((t % 4) as f64 + 0.5, (t / 4) as f64 + 0.5);
            let d = c - centre;
            let wrap = |v: f64| v - 4.0 * (v / 4.0).round();
            DVec2::new(wrap(d.x), wrap(d.y)).length() <= 0.9
        })
        .collect();
    assert!(!expected.is_empty() && expected.len() < 16);
    assert_eq!(mask.covered().collect::<Vec<_>>(), expected);

    // The edit changes exactly those texels (every texel of the pack has weights).
    let Material::Spmm {
        material,
        uv_scale,
        residual,
        npca,
    } = &scene.materials[1]
    else {
        panic!("material 1 is the SPMM panel");
    };
    let edited = material
        .with_weight_scale(&WeightTarget::default().within(&mask), [0.0, 2.0, 4.0])
        .expect("valid");
    let changed = material.changed_texels(&edited).expect("same grid");
    let changed_list: Vec<usize> = (0..16).filter(|&t| changed[t]).collect();
    assert_eq!(changed_list, expected);

    let before = mode.image();
    let edit = SceneEdit::Material {
        index: 1,
        material: Material::Spmm {
            material: Arc::new(edited),
            uv_scale: *uv_scale,
            residual: *residual,
            npca: *npca,
        },
    };
    let Ok(Invalidation::Pixels(n)) = mode.apply(edit) else {
        panic!("a material edit restarts pixels");
    };
    // Restarted pixels have no sample yet: they resolve to exactly black, which no
    // kept pixel is (the background and the lit floor are not black).
    let after = mode.image();
    let restarted = |x: u32, y: u32| after.get(x, y) == [0.0; 3];
    let count = (0..SIZE)
        .flat_map(|y| (0..SIZE).map(move |x| (x, y)))
        .filter(|&(x, y)| restarted(x, y))
        .count();
    assert_eq!(count, n);
    let mut panel_pixels = 0;
    let mut must = 0;
    for y in 0..SIZE {
        for x in 0..SIZE {
            assert!(before.get(x, y) != [0.0; 3], "every pixel had light before");
            // Nine points over the pixel, corners included: every sample's UV lies in
            // their box (the panel is flat and seen through a pinhole).
            let points: Vec<Option<DVec2>> = (0..9)
                .map(|k| {
                    panel_uv(
                        x as f64 + (k % 3) as f64 * 0.5,
                        y as f64 + (k / 3) as f64 * 0.5,
                    )
                })
                .collect();
            if points.iter().all(Option::is_none) {
                // Off the panel, and so are the neighbours' centres: kept.
                let near_panel = (-1..=1).any(|dy: i32| {
                    (-1..=1).any(|dx: i32| {
                        panel_uv(
                            x as f64 + 0.5 + f64::from(dx),
                            y as f64 + 0.5 + f64::from(dy),
                        )
                        .is_some()
                    })
                });
                if !near_panel {
                    assert!(!restarted(x, y), "pixel ({x}, {y}) never saw the panel");
                }
                continue;
            }
            if points.iter().any(Option::is_none) {
                continue; // on the panel's edge
            }
            panel_pixels += 1;
            let texels: Vec<DVec2> = points
                .iter()
                .map(|p| texel_xy(p.expect("on panel")))
                .collect();
            let first = texel_index(texels[0]);
            if expected.contains(&first) && texels.iter().all(|&t| texel_index(t) == first) {
                must += 1;
                assert!(
                    restarted(x, y),
                    "pixel ({x}, {y}) saw only changed texel {first}"
                );
            }
            // Far: no changed texel within the pixel's texel box grown by one texel
            // (a tile seam inside the pixel makes the box span the texture: skipped).
            let lo = texels.iter().fold(DVec2::INFINITY, |a, &b| a.min(b));
            let hi = texels.iter().fold(DVec2::NEG_INFINITY, |a, &b| a.max(b));
            if hi.x - lo.x > 2.0 || hi.y - lo.y > 2.0 {
                continue;
            }
            let near_changed =
                ((lo.y - 1.01).floor() as i64..=(hi.y + 1.01).floor() as i64).any(|ty| {
                    ((lo.x - 1.01).floor() as i64..=(hi.x + 1.01).floor() as i64).any(|tx| {
                        expected.contains(&((ty.rem_euclid(4) * 4 + tx.rem_euclid(4)) as usize))
                    })
                });
            if !near_changed {
                assert!(
                    !restarted(x, y),
                    "pixel ({x}, {y}) is far from every changed texel"
                );
            }
        }
    }
    assert!(must > 0, "some pixels saw only the changed texels");
    assert!(
        n < panel_pixels,
        "a stroke restarts fewer pixels than the whole panel ({n} of {panel_pixels})"
    );
    // The next call traces the restarted pixels alone (the early part of the next
    // frame) and fills them again; every other pixel keeps exactly its value.
    assert_eq!(mode.pending_restarted(), n);
    let stats = mode.render_frame();
    assert_eq!(stats.counters.samples, n as u64);
    let filled = mode.image();
    assert!((0..SIZE).all(|y| (0..SIZE).all(|x| filled.get(x, y) != [0.0; 3])));
    for y in 0..SIZE {
        for x in 0..SIZE {
            if !restarted(x, y) {
                assert_eq!(filled.get(x, y), after.get(x, y), "pixel ({x}, {y}) kept");
            }
        }
    }
    // The frame completes with the other pixels' samples; then whole frames again.
    assert_eq!(mode.pending_restarted(), 0);
    assert_eq!(
        mode.render_frame().counters.samples,
        u64::from(SIZE * SIZE) - n as u64
    );
    assert_eq!(mode.progress().min_samples, 1);
    assert_eq!(mode.render_frame().counters.samples, u64::from(SIZE * SIZE));
    assert_eq!(mode.progress().min_samples, 2);
}

/// With the catch-up off, the frame after an edit is a whole frame (the previous
/// behaviour, kept for comparisons); with it on, a camera move drops the queue.
#[test]
fn restarted_pixels_first_can_be_turned_off_and_a_full_restart_drops_the_queue() {
    let scene = edit_test_scene();
    let Material::Spmm {
        material,
        uv_scale,
        residual,
        npca,
    } = scene.materials[1].clone()
    else {
        panic!("material 1 is the SPMM panel");
    };
    let edit = SceneEdit::Material {
        index: 1,
        material: Material::Spmm {
            material: Arc::new(
                material
                    .with_weight_scale(&WeightTarget::cluster(0), [2.0; 3])
                    .expect("valid"),
            ),
            uv_scale,
            residual,
            npca,
        },
    };
    let mut old = SpmmMode::new(scene.clone(), SIZE, SIZE).expect("size");
    old.set_restarted_first(false);
    old.render_frame();
    let Ok(Invalidation::Pixels(n)) = old.apply(edit.clone()) else {
        panic!("pixels restart");
    };
    assert!(n > 0 && old.pending_restarted() == 0);
    assert_eq!(old.render_frame().counters.samples, u64::from(SIZE * SIZE));

    let mut new = SpmmMode::new(scene.clone(), SIZE, SIZE).expect("size");
    new.render_frame();
    new.apply(edit).expect("applies");
    assert_eq!(new.pending_restarted(), n);
    new.apply(SceneEdit::Camera(scene.camera)).expect("applies");
    assert_eq!(new.pending_restarted(), 0);
    assert_eq!(new.render_frame().counters.samples, u64::from(SIZE * SIZE));
}
