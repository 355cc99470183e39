//! The mode switch, the environment panel and the compare view driven through the
//! real window with egui_kittest, with injected mode makers: a slow preparation that
//! waits on its cancel flag (the old mode keeps rendering, Cancel keeps it), a mode
//! that refuses lights (stay, or switch with them disabled), a mode that is not
//! built, the compare view's numbers against `metrics::compare`, and environment
//! edits with undo.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use egui::accesskit::Role;
use egui_kittest::Harness;
use egui_kittest::kittest::{NodeT, Queryable};
use glam::DVec3;
use meso_materials::image::Image;
use meso_render::scene::{Light, Scene};
use meso_render::{
    Device, Diagnostic, Diagnostics, EditError, FrameStats, Invalidation, ModeError, ModeKind,
    Pass, Prepare, Progress, RenderMode, SceneEdit, Unrenderable, Unsupported,
};

use super::tests::{loaded, wait_for_current_frame};
use super::*;
use meso_render::RenderModeExt;
use meso_viewport::maker::{CoreModes, ModeMaker};

/// Light edits a test mode received: (mode index, light).
type Applied = Arc<Mutex<Vec<(usize, Light)>>>;

/// Core's spmm mode under another kind's name, noting the light edits it gets.
struct Tagged {
    kind: ModeKind,
    inner: Box<dyn RenderMode>,
    applied: Applied,
}

impl RenderMode for Tagged {
    fn kind(&self) -> ModeKind {
        self.kind
    }
    fn device(&self) -> Device {
        Device::Cpu
    }
    fn scene(&self) -> &Scene {
        self.inner.scene()
    }
    /// Whole frames, no preview.
    fn render(
        &mut self,
        pass: Pass,
        _stop: Option<&mut dyn FnMut() -> bool>,
    ) -> Option<FrameStats> {
        (pass == Pass::Frame).then(|| self.inner.render_frame())
    }
    fn image(&self) -> Image {
        self.inner.image()
    }
    fn progress(&self) -> Progress {
        self.inner.progress()
    }
    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        if let SceneEdit::Light { index, light } = &edit {
            self.applied
                .lock()
                .expect("not poisoned")
                .push((*index, *light));
        }
        self.inner.apply(edit)
    }
    fn set_samples_per_frame(&mut self, samples: u32) {
        self.inner.set_samples_per_frame(samples);
    }
    fn diagnostics(&self) -> Diagnostics {
        Diagnostics(vec![Diagnostic::Preparation(
            self.inner.diagnostics().preparation(),
        )])
    }
}

/// spmm as core has it; biscale prepares until `release` is set (or it is
/// cancelled); adaptive cannot render any light. Both render with core's spmm.
struct TestModes {
    release: Arc<AtomicBool>,
    applied: Applied,
}

impl ModeMaker for TestModes {
    fn supports(&self, kind: ModeKind, device: Device, scene: &Scene) -> Result<(), ModeError> {
        match (kind, device) {
            (ModeKind::Spmm, Device::Cpu) => CoreModes::default().supports(kind, device, scene),
            (ModeKind::Biscale, Device::Cpu) => Ok(()),
            (ModeKind::Adaptive, Device::Cpu) => {
                let parts = scene
                    .lights
                    .iter()
                    .enumerate()
                    .map(|(index, l)| Unrenderable::Light {
                        index,
                        kind: l.kind_name(),
                    })
                    .collect();
                Ok(Unsupported::check(kind, device, parts)?)
            }
            _ => Err(ModeError::NotBuilt { mode: kind, device }),
        }
    }

    fn create(
        &self,
        kind: ModeKind,
        device: Device,
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Box<dyn RenderMode>, ModeError> {
        self.supports(kind, device, &scene)?;
        if kind == ModeKind::Spmm {
            return CoreModes::default().create(kind, device, scene, width, height, prepare);
        }
        let mut step = 0u32;
        while kind == ModeKind::Biscale && !self.release.load(Ordering::Relaxed) {
            prepare.report("waiting for the test", (step % 100) as f32 / 100.0)?;
            step += 1;
            std::thread::sleep(Duration::from_millis(2));
        }
        let inner = CoreModes::default().create(
            ModeKind::Spmm,
            Device::Cpu,
            scene,
            width,
            height,
            prepare,
        )?;
        Ok(Box::new(Tagged {
            kind,
            inner,
            applied: Arc::clone(&self.applied),
        }))
    }
}

pub(super) fn small() -> Settings {
    Settings {
        resolution: 0.25,
        max_samples: 1_000_000,
        show_timings: false,
        ..Settings::for_tests()
    }
}

fn harness_with(maker: Arc<dyn ModeMaker>, settings: Settings) -> Harness<'static, Studio> {
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .build_ui_state(
            |ui, s: &mut Studio| s.show(ui),
            Studio::with_maker(None, None, settings, maker),
        );
    loaded(&mut h);
    h
}

/// The studio with core's modes on a scene of tests/scenes/, loaded.
fn shipped_scene(name: &str) -> Harness<'static, Studio> {
    let scene = default_scene_path()
        .parent()
        .expect("scenes folder")
        .join(name);
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .build_ui_state(
            |ui, s: &mut Studio| s.show(ui),
            Studio::with_maker(None, Some(scene), small(), Arc::new(CoreModes::default())),
        );
    loaded(&mut h);
    h
}

fn test_modes() -> (Arc<AtomicBool>, Applied, Arc<dyn ModeMaker>) {
    let release = Arc::new(AtomicBool::new(false));
    let applied: Applied = Arc::default();
    let maker = Arc::new(TestModes {
        release: Arc::clone(&release),
        applied: Arc::clone(&applied),
    });
    (release, applied, maker)
}

/// Steps until `done`, failing after 60 s with `what`.
pub(super) fn step_until(
    h: &mut Harness<'_, Studio>,
    what: &str,
    mut done: impl FnMut(&Harness<'_, Studio>) -> bool,
) {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        h.step();
        if done(h) {
            return;
        }
        assert!(Instant::now() < deadline, "{what} within 60 s");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Steps until a frame newer than the one on screen arrives; returns its mode.
pub(super) fn next_frame_mode(h: &mut Harness<'_, Studio>) -> ModeKind {
    let before = h.state().frame().map(|f| f.finished);
    step_until(h, "a new frame", |h| {
        h.state().frame().map(|f| f.finished) != before
    });
    h.state().frame().expect("a frame").mode
}

/// Steps until a frame of the document's version rendered by `mode` is shown (the
/// old mode may still show that version until the new one is installed).
fn wait_for_mode_frame(h: &mut Harness<'_, Studio>, mode: ModeKind) {
    step_until(h, "a frame of the new mode", |h| {
        let version = h.state().doc.as_ref().expect("doc").version;
        h.state()
            .frame()
            .is_some_and(|f| f.mode == mode && f.version >= version)
    });
}

/// Picks a render mode in the panel's combo box.
fn choose_mode(h: &mut Harness<'_, Studio>, name: &str) {
    h.get_by_role_and_label(Role::ComboBox, "Render mode")
        .click();
    h.run_steps(2);
    h.get_by_label(name).click();
    h.run_steps(2);
}

#[test]
fn a_slow_switch_keeps_the_old_mode_rendering_cancel_keeps_it_and_a_finished_one_installs() {
    let (release, applied, maker) = test_modes();
    let mut h = harness_with(maker, small());
    wait_for_current_frame(&mut h);
    choose_mode(&mut h, "biscale");
    assert!(
        h.state().switching(),
        "the preparation runs in the background"
    );
    step_until(&mut h, "the progress bar", |h| {
        h.query_all_by_role(Role::ProgressIndicator).any(|n| {
            n.accesskit_node()
                .label()
                .is_some_and(|l| l.contains("waiting for the test"))
        })
    });
    assert!(
        h.query_by_label_contains("switching to biscale (cpu)")
            .is_some()
    );
    // The old mode keeps rendering meanwhile.
    for _ in 0..2 {
        assert_eq!(next_frame_mode(&mut h), ModeKind::Spmm);
    }
    assert!(h.state().switching());
    h.get_by_label("Cancel").click();
    step_until(&mut h, "the cancelled job to end", |h| {
        !h.state().switching()
    });
    assert_eq!(h.state().mode(), (ModeKind::Spmm, Device::Cpu));
    assert!(
        h.query_by_role(Role::ProgressIndicator).is_none(),
        "no bar, no spinner"
    );
    assert!(h.state().mode_message().is_none(), "cancelling is no error");
    assert_eq!(next_frame_mode(&mut h), ModeKind::Spmm);

    // Again; a light edit made while it prepares reaches the new mode.
    choose_mode(&mut h, "biscale");
    assert!(h.state().switching());
    let mut light = h.state().doc.as_ref().expect("doc").scene.lights[0];
    if let Light::Area { radiance, .. } = &mut light {
        *radiance = DVec3::new(3.0, 2.0, 1.0);
    }
    h.state_mut().edit(SceneEdit::Light { index: 0, light });
    release.store(true, Ordering::Relaxed);
    step_until(&mut h, "the switch", |h| !h.state().switching());
    assert_eq!(h.state().mode(), (ModeKind::Biscale, Device::Cpu));
    wait_for_mode_frame(&mut h, ModeKind::Biscale);
    assert_eq!(next_frame_mode(&mut h), ModeKind::Biscale);
    assert_eq!(
        *applied.lock().expect("not poisoned"),
        vec![(0, light)],
        "the edit made during the preparation was replayed on the new mode"
    );
}

#[test]
fn a_mode_that_cannot_render_a_light_asks_and_renders_without_it() {
    let (_release, applied, maker) = test_modes();
    let mut h = harness_with(maker, small());
    wait_for_current_frame(&mut h);
    choose_mode(&mut h, "adaptive");
    assert!(!h.state().switching(), "nothing starts before the answer");
    assert!(
        h.query_by_label_contains("cannot render light[0] (area)")
            .is_some(),
        "the message names the light"
    );
    h.get_by_label("Stay in spmm (cpu)").click();
    h.run_steps(2);
    assert_eq!(h.state().mode(), (ModeKind::Spmm, Device::Cpu));
    assert!(
        h.query_by_label_contains("cannot render light[0]")
            .is_none()
    );
    assert_eq!(next_frame_mode(&mut h), ModeKind::Spmm);

    choose_mode(&mut h, "adaptive");
    h.get_by_label("Switch with these lights disabled for adaptive")
        .click();
    step_until(&mut h, "the switch", |h| !h.state().switching());
    assert_eq!(h.state().mode(), (ModeKind::Adaptive, Device::Cpu));
    wait_for_mode_frame(&mut h, ModeKind::Adaptive);
    h.run_steps(2);
    assert!(
        h.query_by_label_contains("light 0: area (disabled in adaptive)")
            .is_some(),
        "the lights panel marks the light"
    );
    // Its edits stay in the document; the mode never gets them, frames still come.
    let mut light = h.state().doc.as_ref().expect("doc").scene.lights[0];
    if let Light::Area { radiance, .. } = &mut light {
        *radiance = DVec3::splat(1.0);
    }
    h.state_mut().edit(SceneEdit::Light { index: 0, light });
    wait_for_current_frame(&mut h);
    assert_eq!(h.state().doc.as_ref().expect("doc").scene.lights[0], light);
    assert!(applied.lock().expect("not poisoned").is_empty());
    // A light added now cannot be rendered either: it is disabled too.
    h.get_by_label("Add point light").click();
    wait_for_current_frame(&mut h);
    assert!(h.state().disabled().light(1));
    assert_eq!(h.state().frame().expect("frame").mode, ModeKind::Adaptive);
}

#[test]
fn a_mode_that_is_not_built_says_so_and_the_old_mode_keeps_rendering() {
    // The test modes build nothing on the GPU (core builds the spmm mode there).
    let (_, _, maker) = test_modes();
    let mut h = harness_with(maker, small());
    wait_for_current_frame(&mut h);
    h.get_by_role_and_label(Role::ComboBox, "Device").click();
    h.run_steps(2);
    h.get_by_label("gpu").click();
    h.run_steps(2);
    assert!(!h.state().switching());
    let message = h.state().mode_message().expect("a message");
    assert!(
        message.contains("not built") && message.contains("staying in spmm (cpu)"),
        "{message}"
    );
    assert!(
        h.query_by_label_contains("not built").is_some(),
        "it is shown"
    );
    assert_eq!(h.state().mode(), (ModeKind::Spmm, Device::Cpu));
    assert_eq!(next_frame_mode(&mut h), ModeKind::Spmm);
    let f = h.state().frame().expect("frame");
    assert!(
        f.image()
            .pixels()
            .iter()
            .any(|p| p.iter().any(|&c| c > 0.0)),
        "not black"
    );
}

#[test]
fn the_compare_view_shows_exactly_what_metrics_compare_says() {
    let settings = Settings {
        max_samples: 4,
        reference_spp: 8,
        ..small()
    };
    let mut h = harness_with(Arc::new(CoreModes::default()), settings);
    wait_for_current_frame(&mut h);
    h.get_by_label("View").click();
    h.run_steps(2);
    h.get_by_label("Compare with a reference").click();
    h.run_steps(2);
    assert!(h.state().settings.compare);
    // The comparison of the final live frame (4 spp): an earlier one is replaced as
    // frames arrive, and the status bar shows the newest.
    step_until(
        &mut h,
        "a comparison of the final frame with the 8-spp reference",
        |h| {
            let final_frame = h
                .state()
                .frame()
                .filter(|f| f.progress.min_samples >= 4)
                .map(|f| f.image());
            h.state().measured().is_some_and(|m| {
                m.reference_spp >= 8
                    && final_frame
                        .as_ref()
                        .is_some_and(|f| Arc::ptr_eq(f, &m.live))
            })
        },
    );
    let m = h.state().measured().expect("measured").clone();
    let again = meso_materials::metrics::compare(&m.reference, &m.live, 0.0).expect("same size");
    assert_eq!(again, m.comparison);
    assert!(
        m.comparison.rmse > 0.0 && m.comparison.mssim < 1.0,
        "4 spp is not converged"
    );
    // Waited for as the numbers below are: on a loaded machine the panel can take
    // more than two steps to show them.
    step_until(&mut h, "the reference's samples in the status bar", |h| {
        h.query_by_label_contains("reference: spmm, 8 spp")
            .is_some()
    });
    let shown = format!("RMSE {:.4}", m.comparison.rmse);
    step_until(&mut h, "the numbers in the status bar", |h| {
        h.query_by_label_contains(&shown).is_some()
    });
}

#[test]
fn environment_edits_are_undoable_and_reach_the_renderer() {
    let mut h = harness_with(Arc::new(CoreModes::default()), small());
    wait_for_current_frame(&mut h);
    assert!(
        h.state()
            .doc
            .as_ref()
            .expect("doc")
            .scene
            .environment
            .is_none()
    );
    h.get_by_label("env_studio").click();
    h.step();
    loaded(&mut h);
    let env = |h: &Harness<'_, Studio>| {
        h.state()
            .doc
            .as_ref()
            .expect("doc")
            .scene
            .environment
            .clone()
    };
    let on = env(&h).expect("the environment is on");
    assert_eq!((on.strength, on.rotate_y_deg), (1.0, 0.0));
    wait_for_current_frame(&mut h);

    h.get_by_role_and_label(Role::Slider, "environment strength")
        .set_value_accesskit(2.5);
    h.step();
    let strong = env(&h).expect("on");
    assert_eq!(strong.strength, 2.5);
    assert!(Arc::ptr_eq(&strong.map, &on.map), "the same map");
    wait_for_current_frame(&mut h);

    h.get_by_role_and_label(Role::Slider, "environment rotation (deg)")
        .set_value_accesskit(-90.0);
    h.step();
    assert_eq!(env(&h).expect("on").rotate_y_deg, -90.0);
    wait_for_current_frame(&mut h);

    h.state_mut().undo();
    h.step();
    assert_eq!(env(&h).expect("on").rotate_y_deg, 0.0);
    h.state_mut().undo();
    h.step();
    let back = env(&h).expect("on");
    assert_eq!(back.strength, 1.0);
    assert!(Arc::ptr_eq(&back.map, &on.map));
    wait_for_current_frame(&mut h);
    h.state_mut().undo();
    h.step();
    assert!(env(&h).is_none(), "undo turns it off again");
    wait_for_current_frame(&mut h);
}

#[test]
fn a_scene_that_names_a_mode_asks_for_it_once_loaded() {
    // The default scene with `[render] mode = "biscale"`: it opens in spmm (which
    // renders everything), then asks for biscale, which renders every scene (without an
    // environment its precomputed part is dark and the lights are traced): no prompt,
    // the switch starts in the background while spmm's frames keep coming.
    let dir = tempfile::tempdir().expect("temp dir");
    let default = default_scene_path();
    let folder = default
        .parent()
        .expect("scenes folder")
        .display()
        .to_string();
    // Paths in a scene are relative to it: make them absolute for the copy.
    let text = std::fs::read_to_string(&default)
        .expect("default scene")
        .replace("[render]\n", "[render]\nmode = \"biscale\"\n")
        .replace("path = \"", &format!("path = \"{folder}/"))
        .replace("pack = \"", &format!("pack = \"{folder}/"));
    assert!(
        text.contains("mode = \"biscale\""),
        "the default scene has [render]"
    );
    let copy = dir.path().join("biscale.toml");
    std::fs::write(&copy, text).expect("write scene");
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .build_ui_state(
            |ui, s: &mut Studio| s.show(ui),
            Studio::with_maker(
                None,
                Some(copy.clone()),
                small(),
                Arc::new(CoreModes::default()),
            ),
        );
    loaded(&mut h);
    wait_for_current_frame(&mut h);
    step_until(&mut h, "the scene's mode to be asked for", |h| {
        h.state().switching()
    });
    assert!(h.state().mode_prompt().is_none() && h.state().mode_message().is_none());
    assert_eq!(h.state().mode(), (ModeKind::Spmm, Device::Cpu));
    // Cancelled at once (the precomputation itself is the env scene's test's), so
    // spmm stays and keeps rendering.
    h.state_mut().cancel_switch();
    step_until(&mut h, "the cancelled switch to end", |h| {
        !h.state().switching()
    });
    assert_eq!(h.state().mode(), (ModeKind::Spmm, Device::Cpu));
    assert_eq!(next_frame_mode(&mut h), ModeKind::Spmm);
}

#[test]
fn the_adaptive_mode_renders_a_shipped_merl_scene_and_shows_its_debug_overlays() {
    // The real registry on the MERL bunny (inline tabulated tables, env_studio.exr
    // and an area light): the toggle reaches the adaptive mode, whose frames carry
    // the bandwidth level and samples-per-pixel maps the View menu offers.
    let mut h = shipped_scene("merl_bunny.toml");
    wait_for_current_frame(&mut h);
    choose_mode(&mut h, "adaptive");
    step_until(&mut h, "the switch", |h| !h.state().switching());
    assert_eq!(h.state().mode(), (ModeKind::Adaptive, Device::Cpu));
    wait_for_mode_frame(&mut h, ModeKind::Adaptive);
    let frame = h.state().frame().expect("frame").clone();
    let names: Vec<&str> = frame.overlays.iter().map(|o| o.0).collect();
    assert_eq!(names, ["bandwidth level", "samples per pixel"]);
    for (_, img) in &frame.overlays {
        assert_eq!((img.width(), img.height()), frame.estimate.size());
    }
    h.state_mut()
        .viewport
        .set_overlay(Some("samples per pixel"));
    h.run_steps(2);
    assert_eq!(h.state().viewport.overlay(), Some("samples per pixel"));
}

#[test]
fn the_biscale_mode_renders_a_shipped_scene_turns_its_light_and_reprepares_for_new_meshes() {
    // The real registry on tests/scenes/env.toml (the low-res bunny and a floor under
    // the studio map, no lights): the toggle precomputes in the background (or reads
    // the cache), the status bar names the biclusters and the FLOP ratio, turning the
    // map is a light change of the same mode, and new meshes start a new preparation
    // in the background instead of an edit on the render thread; cancelling it shows
    // the new meshes in spmm rather than a stale view.
    let mut h = shipped_scene("env.toml");
    wait_for_current_frame(&mut h);
    choose_mode(&mut h, "biscale");
    assert!(
        h.state().switching(),
        "the precomputation runs in the background"
    );
    let deadline = Instant::now() + Duration::from_secs(300);
    while h.state().switching() {
        assert!(Instant::now() < deadline, "biscale prepared within 300 s");
        h.step();
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(h.state().mode(), (ModeKind::Biscale, Device::Cpu));
    wait_for_mode_frame(&mut h, ModeKind::Biscale);
    h.run_steps(2);
    let summary = h.state().frame().and_then(|f| f.summary.clone());
    let summary = summary.expect("the biscale mode describes itself");
    assert!(summary.contains("biclusters") && summary.contains("FLOP ratio"));
    assert!(
        h.query_by_label_contains("FLOP ratio").is_some(),
        "in the status bar"
    );
    let before = h.state().frame().expect("frame").image();

    h.get_by_role_and_label(Role::Slider, "environment rotation (deg)")
        .set_value_accesskit(120.0);
    h.step();
    wait_for_current_frame(&mut h);
    let frame = h.state().frame().expect("frame");
    assert_eq!(
        frame.mode,
        ModeKind::Biscale,
        "a light change keeps the mode"
    );
    let changed = before
        .pixels()
        .iter()
        .zip(frame.image().pixels())
        .filter(|(a, b)| (a[0] - b[0]).abs() > 1e-3)
        .count();
    assert!(changed > 0, "turning the map changes the image");

    let mut meshes = h.state().doc.as_ref().expect("doc").scene.meshes.clone();
    meshes.truncate(1);
    h.state_mut().edit(SceneEdit::Meshes(meshes));
    h.step();
    assert!(h.state().switching(), "new meshes are a new preparation");
    h.state_mut().cancel_switch();
    step_until(&mut h, "the fallback to spmm", |h| {
        h.state().mode().0 == ModeKind::Spmm
    });
    assert!(
        h.state()
            .mode_message()
            .as_deref()
            .is_some_and(|m| m.contains("showing them in spmm")),
        "{:?}",
        h.state().mode_message()
    );
    wait_for_mode_frame(&mut h, ModeKind::Spmm);
}
