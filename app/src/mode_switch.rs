//! The render mode switch: the mode rendering now and the lights it renders without,
//! a mode being prepared to replace it (a background job with progress and Cancel,
//! while the old mode keeps rendering), the prompt for a mode that cannot render some
//! lights, the mode an opened scene asks for, and why the last switch did not happen.
//! Its own type so the switch's rules (check, prepare, install, replay the edits made
//! meanwhile, prepare again for new geometry) read in one place; the studio gives it
//! the document, the render size and the render thread.

use std::sync::Arc;
use std::time::Instant;

use meso_render::scene::Scene;
use meso_render::{
    Device, ModeError, ModeKind, Prepare, RenderMode, SceneEdit, Unrenderable, Unsupported,
};

use crate::disabled::Disabled;
use crate::document::Document;
use crate::jobs::Job;
use crate::render_link::RenderLink;
use crate::scene_panel::Switching;
use meso_viewport::maker::{ModeMaker, mode_name};
use meso_viewport::worker::Command;

/// A mode being prepared to replace the current one.
struct Switch {
    kind: ModeKind,
    device: Device,
    /// What the new mode renders without.
    disabled: Disabled,
    /// The document version of the scene it is prepared for.
    version: u64,
    job: Job<Result<Box<dyn RenderMode>, ModeError>>,
    /// Edits made while it is prepared, already translated for it: replayed after
    /// it is installed, so it ends at the document's current scene.
    replay: Vec<(u64, SceneEdit)>,
    /// A preparation of the current mode for new geometry (`prepares_geometry`): the
    /// mode on screen still shows the old meshes, so cancelling it cannot simply keep
    /// that mode.
    for_geometry: bool,
}

/// The edit a mode should get for a document edit (already applied to the document's
/// `scene`), or `None` if it only concerns parts the mode renders without. A light
/// added while a mode renders without some lights is checked: if the mode cannot
/// render it either, it is left out too.
fn route(
    maker: &dyn ModeMaker,
    mode: (ModeKind, Device),
    disabled: &mut Disabled,
    scene: &Scene,
    edit: SceneEdit,
) -> Option<SceneEdit> {
    if let SceneEdit::AddLight(_) = &edit
        && (!disabled.is_empty() || mode != (ModeKind::Spmm, Device::Cpu))
    {
        let mode_scene = disabled.scene_for_mode(scene);
        // The new light is the last of the document's and of the mode's.
        let last = mode_scene.lights.len().saturating_sub(1);
        if let Err(ModeError::Unsupported(u)) = maker.supports(mode.0, mode.1, &mode_scene)
            && u.parts
                .iter()
                .any(|p| matches!(p, Unrenderable::Light { index, .. } if *index == last))
        {
            disabled.disable_light(scene.lights.len().saturating_sub(1));
            return None;
        }
    }
    disabled.translate(edit)
}

/// Whether wgpu offers a hardware adapter (not a software one such as llvmpipe).
#[cfg(feature = "gpu")]
fn hardware_gpu() -> bool {
    meso_gpu::hardware_adapter().is_some()
}

/// Without the `gpu` feature there is no GPU to open scenes on.
#[cfg(not(feature = "gpu"))]
fn hardware_gpu() -> bool {
    false
}

/// The mode rendering now, and a switch to another.
pub struct ModeSwitch {
    /// Where render modes come from (core's registry unless a test injects one).
    maker: Arc<dyn ModeMaker>,
    repaint: Option<egui::Context>,
    /// The mode rendering now and what it renders without.
    mode: (ModeKind, Device),
    disabled: Disabled,
    /// A mode being prepared to replace it.
    switch: Option<Switch>,
    /// A mode that cannot render some lights, or needs the environment: switch
    /// without them, or stay?
    prompt: Option<Unsupported>,
    /// The mode an opened scene asks for (`[render] mode/device`), requested once the
    /// scene is loaded into the renderer in the spmm mode.
    scene_mode: Option<(ModeKind, Device)>,
    /// Why the last switch did not happen, shown until dismissed.
    message: Option<String>,
}

impl ModeSwitch {
    /// The spmm mode on the CPU, with modes made by `maker`.
    pub fn new(maker: Arc<dyn ModeMaker>, repaint: Option<egui::Context>) -> Self {
        Self {
            maker,
            repaint,
            mode: (ModeKind::Spmm, Device::Cpu),
            disabled: Disabled::default(),
            switch: None,
            prompt: None,
            scene_mode: None,
            message: None,
        }
    }

    /// The mode rendering now.
    pub fn mode(&self) -> (ModeKind, Device) {
        self.mode
    }

    /// The render thread fell back to another device (a notice): it renders `now`.
    pub fn now_renders(&mut self, now: (ModeKind, Device)) {
        self.mode = now;
    }

    /// Lights and ambient the current mode renders without.
    pub fn disabled(&self) -> &Disabled {
        &self.disabled
    }

    /// Whether a mode is being prepared to replace the current one.
    pub fn switching(&self) -> bool {
        self.switch.is_some()
    }

    /// The switch in progress as the scene panel shows it.
    pub fn panel_switching(&self) -> Option<Switching> {
        self.switch.as_ref().map(|sw| Switching {
            target: mode_name(sw.kind, sw.device),
            progress: sw.job.progress(),
            cancelling: sw.job.cancelled(),
        })
    }

    /// The preparation in progress, for the status bar: its name and start.
    pub fn job(&self) -> Option<(&String, Instant)> {
        self.switch.as_ref().map(|s| (&s.job.name, s.job.started))
    }

    /// Why the last switch did not happen.
    pub fn message(&self) -> Option<&String> {
        self.message.as_ref()
    }

    pub fn dismiss_message(&mut self) {
        self.message = None;
    }

    /// The question for a mode that cannot render some lights, while it is open.
    pub fn prompt(&self) -> Option<&Unsupported> {
        self.prompt.as_ref()
    }

    /// The prompt's "stay in the current mode".
    pub fn stay(&mut self) {
        self.prompt = None;
    }

    /// Asks for another render mode: it is checked first (`supports`); a mode that
    /// is not built or cannot render a material says so and the current mode stays;
    /// one that cannot render some lights asks whether to switch without them;
    /// otherwise the new mode is prepared in the background at `size`. Choosing the
    /// current mode stops a switch in progress.
    pub fn request(
        &mut self,
        doc: Option<&Document>,
        kind: ModeKind,
        device: Device,
        size: (u32, u32),
    ) {
        self.prompt = None;
        self.message = None;
        if let Some(sw) = self.switch.take() {
            sw.job.cancel();
        }
        let Some(doc) = doc else { return };
        if (kind, device) == self.mode {
            return;
        }
        let staying = mode_name(self.mode.0, self.mode.1);
        match self.maker.supports(kind, device, &doc.scene) {
            Ok(()) => self.start(doc, kind, device, Disabled::default(), size),
            Err(ModeError::Unsupported(u)) if u.only_lights() => self.prompt = Some(u),
            Err(e) => self.message = Some(format!("{e}; staying in {staying}.")),
        }
    }

    /// The prompt's "switch with these lights disabled": asks again (the lights may
    /// have changed while the prompt was open) and leaves out what the mode cannot
    /// render, if that is only lights and the ambient term.
    pub fn without_lights(
        &mut self,
        doc: Option<&Document>,
        kind: ModeKind,
        device: Device,
        size: (u32, u32),
    ) {
        self.prompt = None;
        let Some(doc) = doc else { return };
        match self.maker.supports(kind, device, &doc.scene) {
            Ok(()) => self.start(doc, kind, device, Disabled::default(), size),
            Err(ModeError::Unsupported(u)) if u.only_lights() => {
                self.start(doc, kind, device, Disabled::from_unsupported(&u), size)
            }
            Err(e) => {
                let staying = mode_name(self.mode.0, self.mode.1);
                self.message = Some(format!("{e}; staying in {staying}."));
            }
        }
    }

    /// Prepares `kind` on `device` in the background for the document's scene
    /// without the `disabled` parts, at `size`.
    fn start(
        &mut self,
        doc: &Document,
        kind: ModeKind,
        device: Device,
        disabled: Disabled,
        size: (u32, u32),
    ) {
        let scene = disabled.scene_for_mode(&doc.scene);
        let (w, h) = size;
        let maker = Arc::clone(&self.maker);
        let name = format!("preparing {}", mode_name(kind, device));
        let job = Job::spawn_controlled(name, self.repaint.clone(), move |c| {
            let report = |stage: &str, fraction: f32| c.report(stage, fraction);
            let prepare = Prepare::new(&report, c.cancel_flag());
            Ok(maker.create(kind, device, scene, w, h, prepare))
        });
        self.switch = Some(Switch {
            kind,
            device,
            disabled,
            version: doc.version,
            job,
            replay: Vec::new(),
            for_geometry: false,
        });
    }

    /// Stops preparing the new mode; the current one stays.
    pub fn cancel(&mut self) {
        if let Some(sw) = &self.switch {
            sw.job.cancel();
        }
    }

    /// Installs a prepared mode: the render thread swaps to it (the old mode renders
    /// until then), then gets the edits made while it was prepared.
    pub fn poll(&mut self, doc: Option<&Document>, link: &mut RenderLink, size: (u32, u32)) {
        let Some(r) = self.switch.as_ref().and_then(|s| s.job.poll()) else {
            return;
        };
        let Some(sw) = self.switch.take() else {
            return;
        };
        let target = mode_name(sw.kind, sw.device);
        let staying = mode_name(self.mode.0, self.mode.1);
        match r {
            Ok(Ok(mode)) => {
                link.send(Command::Install {
                    version: sw.version,
                    mode,
                });
                for (version, edit) in sw.replay {
                    link.send(Command::Edit {
                        version,
                        edit: Box::new(edit),
                    });
                }
                if let Some(doc) = doc {
                    link.send_tracked(
                        Command::Unchanged {
                            version: doc.version,
                        },
                        doc.version,
                    );
                }
                self.mode = (sw.kind, sw.device);
                self.disabled = sw.disabled;
            }
            Ok(Err(ModeError::Cancelled(_))) if sw.for_geometry => {
                // The mode on screen has the old meshes: show the new ones in the
                // spmm mode, which needs no precomputation, rather than a stale view.
                self.message = Some(format!(
                    "the {target} preparation for the new meshes was cancelled; showing them in spmm."
                ));
                if let Some(doc) = doc {
                    self.start(doc, ModeKind::Spmm, self.mode.1, Disabled::default(), size);
                }
            }
            Ok(Err(ModeError::Cancelled(_))) => {}
            Ok(Err(e)) => {
                self.message = Some(format!(
                    "switching to {target} failed: {e}; staying in {staying}."
                ))
            }
            Err(e) => {
                self.message = Some(format!(
                    "switching to {target} failed: {e}; staying in {staying}."
                ))
            }
        }
    }

    /// A newly opened scene (`doc`) renders in the spmm mode on the CPU, which renders
    /// everything; the mode it names is asked for once it is loaded
    /// (`take_scene_mode`). With `gpu_by_default`, the spmm mode on the CPU moves to
    /// the GPU when wgpu offers a hardware adapter and the GPU renders the scene.
    pub fn open_scene(&mut self, doc: &Document, gpu_by_default: bool) {
        let named = (doc.scene.render.mode, doc.scene.render.device);
        let gpu = (ModeKind::Spmm, Device::Gpu);
        let wanted = if named == (ModeKind::Spmm, Device::Cpu)
            && gpu_by_default
            && self.maker.supports(gpu.0, gpu.1, &doc.scene).is_ok()
            && hardware_gpu()
        {
            gpu
        } else {
            named
        };
        self.scene_mode = Some(wanted).filter(|m| *m != (ModeKind::Spmm, Device::Cpu));
        if let Some(sw) = self.switch.take() {
            sw.job.cancel();
        }
        self.prompt = None;
        self.mode = (ModeKind::Spmm, Device::Cpu);
        self.disabled = Disabled::default();
    }

    /// The mode the scene just loaded into the renderer asks for, once.
    pub fn take_scene_mode(&mut self) -> Option<(ModeKind, Device)> {
        self.scene_mode.take()
    }

    /// New geometry in the document (`SceneEdit::Meshes`, already applied): a mode
    /// whose preparation depends on it is prepared again in the background at `size`,
    /// with progress and Cancel, for the edited scene, instead of recomputing on the
    /// render thread. `true` if so (the edit is not sent).
    pub fn prepare_for_geometry(&mut self, doc: &Document, size: (u32, u32)) -> bool {
        let (kind, device, disabled) = match &self.switch {
            Some(sw) => (sw.kind, sw.device, sw.disabled.clone()),
            None => (self.mode.0, self.mode.1, self.disabled.clone()),
        };
        if !kind.prepares_geometry() {
            return false;
        }
        if let Some(sw) = self.switch.take() {
            sw.job.cancel();
        }
        self.start(doc, kind, device, disabled, size);
        if let Some(sw) = &mut self.switch {
            sw.for_geometry = true;
        }
        true
    }

    /// An edit already applied to `doc` as the current mode gets it (`None`: it only
    /// concerns parts the mode renders without), noted translated for a mode being
    /// prepared.
    pub fn translate(&mut self, doc: &Document, edit: SceneEdit) -> Option<SceneEdit> {
        if let Some(sw) = &mut self.switch
            && let Some(e) = route(
                self.maker.as_ref(),
                (sw.kind, sw.device),
                &mut sw.disabled,
                &doc.scene,
                edit.clone(),
            )
        {
            sw.replay.push((doc.version, e));
        }
        route(
            self.maker.as_ref(),
            self.mode,
            &mut self.disabled,
            &doc.scene,
            edit,
        )
    }
}
