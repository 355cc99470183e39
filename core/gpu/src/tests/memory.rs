//! Device memory and limits: uploading only the clusters a scene reaches, refusing
//! an edit past the buffer limit by size, and dispatch grids within the workgroup
//! limit.

use super::{context, gpu_mode};

/// Large images dispatch in rows of workgroups: every pixel gets one invocation.
#[test]
fn dispatch_grids_cover_every_pixel_within_the_limit() {
    use crate::kernel::{MAX_GROUPS_X, WORKGROUP, groups};
    for pixels in [1, 64, 65, 2048 * 2048, 4096 * 4096, 16384 * 16384] {
        let (x, y) = groups(pixels);
        assert!(
            (1..=MAX_GROUPS_X).contains(&x) && y >= 1,
            "{pixels}: {x} x {y}"
        );
        let threads = u64::from(x) * u64::from(y) * u64::from(WORKGROUP);
        assert!(threads >= u64::from(pixels), "{pixels}: {threads}");
        // At most one partial row of workgroups beyond the pixels.
        assert!(threads - u64::from(pixels) < u64::from(x) * u64::from(WORKGROUP) + 64);
    }
}

/// Only the clusters the scene can reach go up: a panel whose UVs cover part of its
/// texture (one cluster of two) uploads fewer basis and residual bytes than a full
/// upload and renders the same image bit for bit; a mesh edit that widens the UVs to
/// the whole texture uploads the rest and again renders as a full upload; a pack no
/// mesh carries uploads nothing.
#[test]
fn a_scene_reaching_part_of_a_pack_uploads_less_and_renders_the_same() {
    use meso_render::{Prepare, RenderMode, SceneEdit, run_frames};
    let scene = crate::reach::tests::partial_panel_scene();
    let size = 24;
    let make = |scene: &meso_render::scene::Scene, all| {
        crate::GpuSpmmMode::prepare_uploading(
            context().clone(),
            scene.clone(),
            (size, size),
            Prepare::quietly(),
            all,
        )
        .expect("the GPU mode renders the scene")
    };
    let (mut partial, mut full) = (make(&scene, false), make(&scene, true));
    let (p, f) = (partial.device_bytes(), full.device_bytes());
    eprintln!("partial {p:?}\nfull {f:?}");
    assert!(
        p.residual_tables < f.residual_tables && p.spmm_bases < f.spmm_bases,
        "{p:?} against {f:?}"
    );
    run_frames(&mut partial, 3, |_, _| {});
    run_frames(&mut full, 3, |_, _| {});
    assert!(
        partial.image().pixels() == full.image().pixels(),
        "the images differ"
    );
    assert_eq!(partial.overflows(), (0, 0));

    // The panel's UVs over the whole texture: the edit uploads the other cluster.
    let mut meshes = scene.meshes.clone();
    for m in meshes.iter_mut().filter(|m| m.material == 1) {
        for uv in &mut m.uvs {
            *uv = (*uv - glam::DVec2::new(0.33, 0.15)) / glam::DVec2::new(0.06, 0.1);
        }
    }
    partial
        .apply(SceneEdit::Meshes(meshes))
        .expect("a mesh edit");
    assert_eq!(partial.device_bytes().residual_tables, f.residual_tables);
    let mut reference = make(partial.scene(), true);
    run_frames(&mut partial, 3, |_, _| {});
    run_frames(&mut reference, 3, |_, _| {});
    assert!(
        partial.image().pixels() == reference.image().pixels(),
        "the images differ after the edit"
    );

    let mut bare = scene.clone();
    bare.meshes.retain(|m| m.material != 1);
    let b = make(&bare, false).device_bytes();
    assert_eq!(
        (b.spmm_bases, b.spmm_weights, b.residual_tables),
        (0, 0, 0),
        "{b:?}"
    );
}

/// A material edit whose data would pass the adapter's buffer limit is refused with
/// the limit's message (bytes and adapter), not a device failure, and leaves the
/// material and the film as they were.
#[test]
fn a_material_edit_past_the_buffer_limit_is_refused_by_size() {
    use meso_render::{EditError, RenderMode, SceneEdit, run_frames};
    let scene = crate::reach::tests::partial_panel_scene();
    let mut gpu = gpu_mode(scene.clone(), 8);
    run_frames(&mut gpu, 2, |_, _| {});
    gpu.limit_buffers(gpu.data_words_bytes() + 64);
    let meso_render::scene::Material::Spmm {
        material,
        residual,
        npca,
        ..
    } = &scene.materials[1]
    else {
        panic!("the panel is a pack");
    };
    // A finer tiling reaches every cluster: more residual tables than the limit.
    let finer = meso_render::scene::Material::Spmm {
        material: material.clone(),
        uv_scale: glam::DVec2::splat(40.0),
        residual: *residual,
        npca: *npca,
    };
    let err = gpu
        .apply(SceneEdit::Material {
            index: 1,
            material: finer,
        })
        .expect_err("past the limit");
    let EditError::Size(message) = &err else {
        panic!("not a size error: {err}");
    };
    assert!(
        message.contains("byte") && message.contains(&context().adapter_name()),
        "{message}"
    );
    assert!(matches!(
        gpu.scene().materials[1],
        meso_render::scene::Material::Spmm { uv_scale, .. } if uv_scale == glam::DVec2::splat(2.0)
    ));
    assert_eq!(gpu.progress().min_samples, 2);
    run_frames(&mut gpu, 1, |_, _| {});
    assert!(gpu.failure().is_none());
    assert_eq!(gpu.progress().min_samples, 3);
}

/// The adaptive mode's film keeps 13 words a pixel in `aux`, more than the sums of a
/// three-layer film: a device that holds the sums but not those words refuses the
/// mode by size before anything is allocated, naming the bytes.
#[test]
fn an_adaptive_film_past_the_buffer_limit_is_refused_by_size() {
    use crate::adaptive::AdaptiveKnobs;
    use crate::film::{ADAPTIVE_AUX_WORDS, largest_buffer};
    use meso_render::{ModeError, Prepare};
    let mut scene = super::test_scene("env.toml");
    scene.lights.clear();
    let layers = meso_render::layers::Layers::new(&scene).layer_count(&scene);
    let (w, h) = (64, 64);
    let sums = largest_buffer(w, h, layers, 0);
    let aux = u64::from(w * h) * ADAPTIVE_AUX_WORDS as u64 * 4;
    assert!(
        sums < aux,
        "{layers} layers: {sums} bytes of sums, {aux} of aux words"
    );
    let knobs = AdaptiveKnobs {
        mean_samples: 4.0,
        max_samples: 256,
        min_share: 0.125,
        refine_frames: 2,
        split_environment: true,
    };
    // The film is checked first: the limit is met there, whatever the other buffers.
    let limited = context().with_buffer_limit(sums);
    match crate::GpuSpmmMode::prepare_adaptive(limited, scene, (w, h), Prepare::quietly(), knobs) {
        Err(ModeError::Size(p)) => assert!(p.contains(&aux.to_string()), "{p}"),
        Err(e) => panic!("refused, but not by size: {e}"),
        Ok(_) => panic!("an adaptive film past the limit was made"),
    }
}
