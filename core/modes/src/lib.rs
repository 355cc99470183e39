//! The registry above every render mode: makes a mode by kind and device, says whether
//! a mode can render a scene (naming what it cannot), and holds what drives any mode
//! (the convergence report's reference seed). The one place that knows every mode:
//! `meso`, the studio and the reports ask it, never a mode's type directly. The GPU
//! mode is built with the `gpu` feature.

/// The `RenderMode` methods a GPU mode hands to its device half (`self.device`, a
/// `meso_gpu::GpuSpmmMode`) as they are: the device, the scene, the guides and the
/// denoiser.
#[cfg(feature = "gpu")]
macro_rules! device_half_methods {
    () => {
        fn device(&self) -> meso_render::Device {
            meso_render::Device::Gpu
        }

        fn scene(&self) -> &meso_render::scene::Scene {
            self.device.scene()
        }

        fn guides(&self, pass: meso_render::Pass) -> Option<meso_render::Guides> {
            self.device.guides(pass)
        }

        fn denoised_on_device(
            &self,
            image: &dyn meso_render::ImageOnDevice,
            denoiser: &meso_render::Denoiser,
            strength: f32,
        ) -> Option<std::sync::Arc<dyn meso_render::ImageOnDevice>> {
            self.device.denoised_on_device(image, denoiser, strength)
        }

        fn prepare_denoiser(&self) {
            self.device.prepare_denoiser();
        }

        fn failure(&self) -> Option<meso_render::ModeError> {
            self.device.failure()
        }
    };
}
#[cfg(feature = "gpu")]
pub(crate) use device_half_methods;

/// What a GPU mode's device half refuses (it names the spmm mode), named for `kind`.
#[cfg(feature = "gpu")]
pub(crate) fn refused_for(kind: ModeKind, u: Unsupported) -> Unsupported {
    Unsupported { mode: kind, ..u }
}

/// An edit the device half refuses by what it cannot shade, named for `kind`; other
/// errors as they are.
#[cfg(feature = "gpu")]
pub(crate) fn edit_refused_for(
    kind: ModeKind,
    e: meso_render::EditError,
) -> meso_render::EditError {
    match e {
        meso_render::EditError::Unsupported(u) => {
            meso_render::EditError::Unsupported(refused_for(kind, u))
        }
        e => e,
    }
}

/// A GPU mode's preparation: the stages its CPU part ran (`cpu`), then the device
/// half's (`device`) but its BVH, which the CPU part built or that duplicates it.
#[cfg(feature = "gpu")]
pub(crate) fn merge_preparation(
    cpu: &meso_render::PreparationReport,
    device: &mut meso_render::PreparationReport,
) {
    let mut stages = cpu.stages.clone();
    stages.extend(device.stages.drain(..).filter(|s| s.name != "bvh"));
    device.stages = stages;
}

pub mod adaptive;
pub mod biscale;
pub mod trace;

#[cfg(all(test, feature = "gpu"))]
mod gpu_test_support;

use crate::adaptive::AdaptiveMode;
#[cfg(feature = "gpu")]
use crate::adaptive::GpuAdaptiveMode;
use crate::biscale::BiscaleMode;
#[cfg(feature = "gpu")]
use crate::biscale::GpuBiscaleMode;
#[cfg(feature = "gpu")]
use meso_gpu::{GpuContext, GpuSpmmMode};
use meso_render::scene::Scene;
use meso_render::{Device, ModeError, ModeKind, Prepare, RenderMode, Unsupported};

use crate::trace::SpmmMode;

/// The reference renders with the scene's seed XOR this constant, so its samples are
/// independent of the progressive images it measures. With the scene's own seed the
/// reference would contain the first frames of every progressive image, and the error
/// after k of its N frames would come out as `sqrt(1/k - 1/N)` of one frame's noise
/// instead of `sqrt(1/k + 1/N)` (zero at k = N).
pub const REFERENCE_SEED_XOR: u64 = 0x5245_4645_5245_4e43; // "REFERENC"

/// One mode on one device: what it cannot render and how it is made. The registry
/// is the list of these (`MODES`); nothing else matches on modes.
pub struct ModeEntry {
    pub kind: ModeKind,
    pub device: Device,
    /// What the mode cannot render in a scene, each part by name.
    pub supports: fn(&Scene) -> Result<(), Unsupported>,
    /// Prepares the mode (GPU modes on the device `GpuDevice` says).
    pub create: CreateMode,
}

/// How a registry entry makes its mode: the device for GPU modes, the scene, the
/// film's width and height, the preparation's progress and cancel.
pub type CreateMode =
    fn(GpuDevice, Scene, u32, u32, Prepare) -> Result<Box<dyn RenderMode>, ModeError>;

/// Every mode this build has.
pub const MODES: &[ModeEntry] = &[
    ModeEntry {
        kind: ModeKind::Spmm,
        device: Device::Cpu,
        supports: SpmmMode::supports,
        create: |_, scene, width, height, prepare| {
            Ok(Box::new(SpmmMode::prepare(scene, width, height, prepare)?))
        },
    },
    #[cfg(feature = "gpu")]
    ModeEntry {
        kind: ModeKind::Spmm,
        device: Device::Gpu,
        supports: GpuSpmmMode::supports,
        create: |gpu, scene, width, height, prepare| {
            create_on_device(gpu, scene, GpuSpmmMode::supports, |ctx, scene| {
                GpuSpmmMode::prepare(ctx, scene, width, height, prepare)
            })
        },
    },
    ModeEntry {
        kind: ModeKind::Biscale,
        device: Device::Cpu,
        supports: BiscaleMode::supports,
        create: |_, scene, width, height, prepare| {
            Ok(Box::new(BiscaleMode::new(scene, width, height, prepare)?))
        },
    },
    #[cfg(feature = "gpu")]
    ModeEntry {
        kind: ModeKind::Biscale,
        device: Device::Gpu,
        supports: GpuBiscaleMode::supports,
        create: |gpu, scene, width, height, prepare| {
            create_on_device(gpu, scene, GpuBiscaleMode::supports, |ctx, scene| {
                GpuBiscaleMode::new(ctx, scene, width, height, prepare)
            })
        },
    },
    ModeEntry {
        kind: ModeKind::Adaptive,
        device: Device::Cpu,
        supports: AdaptiveMode::supports,
        create: |_, scene, width, height, prepare| {
            Ok(Box::new(AdaptiveMode::prepare(
                scene, width, height, prepare,
            )?))
        },
    },
    #[cfg(feature = "gpu")]
    ModeEntry {
        kind: ModeKind::Adaptive,
        device: Device::Gpu,
        supports: GpuAdaptiveMode::supports,
        create: |gpu, scene, width, height, prepare| {
            create_on_device(gpu, scene, GpuAdaptiveMode::supports, |ctx, scene| {
                GpuAdaptiveMode::new(ctx, scene, width, height, prepare)
            })
        },
    },
];

/// The registry's entry for `kind` on `device`, if this build has it.
pub fn entry(kind: ModeKind, device: Device) -> Option<&'static ModeEntry> {
    MODES.iter().find(|e| e.kind == kind && e.device == device)
}

/// True if the mode exists in this build on that device.
pub fn is_built(kind: ModeKind, device: Device) -> bool {
    entry(kind, device).is_some()
}

/// `Ok` if the mode exists and can render everything in `scene`; otherwise what stops
/// it (not built, or the materials and lights it cannot render, each by name).
pub fn supports(kind: ModeKind, device: Device, scene: &Scene) -> Result<(), ModeError> {
    let entry = entry(kind, device).ok_or(ModeError::NotBuilt { mode: kind, device })?;
    Ok((entry.supports)(scene)?)
}

/// Makes the mode for `scene` at `width` x `height`; a long preparation reports its
/// progress through `prepare` and stops when asked.
pub fn create(
    kind: ModeKind,
    device: Device,
    scene: Scene,
    width: u32,
    height: u32,
    prepare: Prepare,
) -> Result<Box<dyn RenderMode>, ModeError> {
    create_on(GpuDevice::Own, kind, device, scene, width, height, prepare)
}

/// The device a GPU mode renders on.
#[derive(Clone, Copy, Debug)]
pub enum GpuDevice<'a> {
    /// One of its own, made for the mode.
    Own,
    /// One of its own, because a shared one could not be had (the reason, which the
    /// mode's summary shows).
    OwnBecause(&'a str),
    /// One made elsewhere (the studio's window's) or kept for several modes.
    #[cfg(feature = "gpu")]
    Shared(&'a GpuContext),
}

/// `create`, with a GPU mode on the device `gpu` says.
pub fn create_on(
    gpu: GpuDevice,
    kind: ModeKind,
    device: Device,
    scene: Scene,
    width: u32,
    height: u32,
    prepare: Prepare,
) -> Result<Box<dyn RenderMode>, ModeError> {
    let entry = entry(kind, device).ok_or(ModeError::NotBuilt { mode: kind, device })?;
    (entry.create)(gpu, scene, width, height, prepare)
}

/// A GPU mode made by `make` on the device `gpu` names, once `supports` has judged
/// the scene: a scene at fault is named whether or not this machine has an adapter.
#[cfg(feature = "gpu")]
fn create_on_device<M: RenderMode + 'static>(
    gpu: GpuDevice,
    scene: Scene,
    supports: fn(&Scene) -> Result<(), Unsupported>,
    make: impl FnOnce(GpuContext, Scene) -> Result<M, ModeError>,
) -> Result<Box<dyn RenderMode>, ModeError> {
    supports(&scene)?;
    Ok(Box::new(make(context(gpu)?, scene)?))
}

/// The device `gpu` names: the shared one, or one of the mode's own.
#[cfg(feature = "gpu")]
fn context(gpu: GpuDevice) -> Result<GpuContext, ModeError> {
    let own = || GpuContext::new().map_err(|e| ModeError::NoDevice(e.to_string()));
    Ok(match gpu {
        GpuDevice::Shared(ctx) => ctx.clone(),
        GpuDevice::Own => own()?,
        GpuDevice::OwnBecause(why) => own()?.own_because(why),
    })
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicBool;

    use super::*;
    use meso_render::scene::test_scenes::edit_test_scene;
    use meso_render::{Unrenderable, Unsupported};

    #[test]
    fn modes_not_built_say_so() {
        let scene = edit_test_scene();
        let mut missing = Vec::new();
        if !cfg!(feature = "gpu") {
            missing.push((ModeKind::Biscale, Device::Gpu));
            missing.push((ModeKind::Adaptive, Device::Gpu));
        }
        for (kind, device) in missing {
            let err = create(kind, device, scene.clone(), 8, 8, Prepare::quietly())
                .err()
                .expect("not built");
            assert_eq!(err, ModeError::NotBuilt { mode: kind, device });
            assert!(err.to_string().contains(kind.name()), "{err}");
        }
        assert!(create(ModeKind::Spmm, Device::Cpu, scene, 8, 8, Prepare::quietly()).is_ok());
        assert_eq!(is_built(ModeKind::Spmm, Device::Gpu), cfg!(feature = "gpu"));
        assert_eq!(
            is_built(ModeKind::Biscale, Device::Gpu),
            cfg!(feature = "gpu")
        );
        assert_eq!(
            is_built(ModeKind::Adaptive, Device::Gpu),
            cfg!(feature = "gpu")
        );
    }

    #[test]
    fn a_cancelled_preparation_stops_and_progress_is_reported() {
        let scene = edit_test_scene();
        let cancel = AtomicBool::new(true);
        let err = create(
            ModeKind::Spmm,
            Device::Cpu,
            scene.clone(),
            8,
            8,
            Prepare::new(&|_, _| {}, &cancel),
        )
        .err()
        .expect("cancelled");
        assert_eq!(err, ModeError::Cancelled(meso_render::Cancelled));
        let stages = std::sync::Mutex::new(Vec::new());
        let record = |s: &str, f: f32| {
            stages
                .lock()
                .expect("not poisoned")
                .push((s.to_string(), f))
        };
        let cancel = AtomicBool::new(false);
        let mode = create(
            ModeKind::Spmm,
            Device::Cpu,
            scene,
            8,
            8,
            Prepare::new(&record, &cancel),
        )
        .expect("prepared");
        let seen = stages.into_inner().expect("not poisoned");
        for s in ["bvh", "materials", "environment"] {
            assert!(seen.iter().any(|(n, _)| n == s), "{seen:?}");
            assert!(mode.diagnostics().preparation().seconds(s).is_some());
        }
    }

    #[test]
    fn bad_sizes_are_refused_by_the_one_size_rule() {
        for (w, h) in [(0, 8), (8, 0), (16385, 8)] {
            let err = create(
                ModeKind::Spmm,
                Device::Cpu,
                edit_test_scene(),
                w,
                h,
                Prepare::quietly(),
            )
            .err()
            .expect("refused");
            assert!(
                matches!(err, ModeError::Size(ref m) if m.contains("16384")),
                "{err}"
            );
        }
    }

    #[test]
    fn the_spmm_mode_shades_every_material_kind() {
        use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
        use meso_materials::merl::tabulate;
        use meso_render::scene::Material;
        let gold = Material::Merl {
            brdf: std::sync::Arc::new(
                tabulate(
                    &AnalyticBrdf::with_defaults(BrdfModel::CookTorrance),
                    glam::DVec3::new(0.9, 0.7, 0.2),
                )
                .expect("tabulates"),
            ),
            tint: glam::DVec3::ONE,
        };
        let mut scene = edit_test_scene();
        scene.materials.push(gold);
        scene.material_names.push("gold".into());
        scene.materials.push(Material::Mirror {
            reflectance: glam::DVec3::splat(0.9),
        });
        scene.material_names.push("chrome".into());
        // brdf, spmm, merl and mirror.
        supports(ModeKind::Spmm, Device::Cpu, &scene).expect("all shaded");
        assert!(create(ModeKind::Spmm, Device::Cpu, scene, 8, 8, Prepare::quietly()).is_ok());
    }

    #[test]
    fn unsupported_names_every_part() {
        let u = Unsupported {
            mode: ModeKind::Biscale,
            device: Device::Cpu,
            parts: vec![
                Unrenderable::Material {
                    index: 2,
                    name: "gold".into(),
                    kind: "merl",
                },
                Unrenderable::Light {
                    index: 0,
                    kind: "point",
                },
            ],
        };
        assert_eq!(
            u.to_string(),
            "the biscale mode (cpu) cannot render material `gold` (merl), light[0] (point)"
        );
        assert!(!u.only_lights());
    }
}
