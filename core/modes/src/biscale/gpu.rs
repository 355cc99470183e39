//! `GpuBiscaleMode`: the biscale mode with its per-pixel work on a wgpu device. The
//! CPU prepares what the CPU mode prepares (BVH, the precomputation or its cache, the
//! BTF tables, the environment's split, L* = T L by Algorithm 2) and hands it to the
//! device (`meso_gpu::BiscaleInputs`: the refinement's quadtrees, L* per refined
//! vertex, the tables' rows, the split's peaks with their sampler). A frame is
//! `shaders/biscale.wgsl` once per sample: eq. 3 into the environment layer, the peaks
//! traced, the lights and the ambient term by the GPU spmm mode's estimators, all into
//! the device film (`meso_gpu::GpuSpmmMode`, whose skeleton, film and light table it
//! reuses). This lives here rather than in `meso-gpu` because the preparation is this
//! crate's and `meso-modes` already depends on `meso-gpu`.
//!
//! Differences from the CPU mode, by design: the view rows are always picked
//! stochastically (the CPU's nearest-view shortcut while the camera moves is not
//! needed on the device), and above 16 lights the device's stochastic light selection
//! is used (the CPU biscale mode samples every light); both have the same expectation.
//! SPMM packs: their biscale tables (per cluster, basis rows and the residual's
//! terms, views x cells) go up for the clusters a ray can reach; the texels' clusters,
//! weights and PCA coefficients are read from the pack the device half uploads for
//! its own shading, not uploaded twice.

use std::sync::Arc;
use std::time::Instant;

use meso_gpu::{
    BiscaleBlock, BiscaleInputs, BiscaleTable as DeviceTable, GpuContext, GpuSpmmMode, SpmmRows,
};
use meso_materials::image::Image;
use meso_render::geometry::SceneBvh;
use meso_render::scene::{Environment, Material, RenderSettings, Scene};
use meso_render::{
    Diagnostic, Diagnostics, EditError, FrameStats, Invalidation, ModeError, ModeKind, Pass,
    PreparationReport, Prepare, Progress, RenderMode, SceneEdit, Unsupported,
};

use super::BiscaleSettings;
use super::btf_table::{BtfTable, Tabulation};
use super::mode::{per_vertex, precompute_and_tabulate, split_lighting};
use super::precompute::{Precomputed, precompute};
use super::refine::FlatQuadtrees;
use meso_render::environment::EnvironmentSplit;

pub struct GpuBiscaleMode {
    /// The device half: skeleton, device film, geometry, lights, biscale words.
    device: GpuSpmmMode,
    settings: BiscaleSettings,
    tab: Tabulation,
    tables: Vec<Option<BtfTable>>,
    pre: Arc<Precomputed>,
    quadtrees: FlatQuadtrees,
    split: Option<EnvironmentSplit>,
    /// Per refined vertex, L* [channel][M] (`None` without an environment).
    lstar: Option<Vec<f32>>,
    /// The CPU's stages (precomputation, tables, lighting).
    preparation: PreparationReport,
    light_change_ms: f64,
}

/// A device-side refusal of the CPU's preparation (a broken invariant, named).
fn upload_error(e: String) -> ModeError {
    ModeError::Size(format!("biscale upload: {e}"))
}

impl GpuBiscaleMode {
    /// What the device cannot render: what its device half cannot shade (a `btf`
    /// table read from disk, which has no values in memory to upload), named for this
    /// mode. Analytic BRDFs, MERL tables and SPMM packs read their tables (a pack's
    /// texel weights are the device half's own upload), `btf` materials are evaluated
    /// per cell by the device's material code, mirrors reflect the ray.
    pub fn supports(scene: &Scene) -> Result<(), Unsupported> {
        GpuSpmmMode::supports(scene).map_err(|u| crate::refused_for(ModeKind::Biscale, u))
    }

    /// Prepares `scene` on `ctx` with the default settings.
    pub fn new(
        ctx: GpuContext,
        scene: Scene,
        width: u32,
        height: u32,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        Self::prepare(
            ctx,
            scene,
            (width, height),
            BiscaleSettings::default(),
            prepare,
        )
    }

    pub fn prepare(
        ctx: GpuContext,
        scene: Scene,
        (width, height): (u32, u32),
        settings: BiscaleSettings,
        prepare: Prepare,
    ) -> Result<Self, ModeError> {
        if let Some(p) = settings.problem() {
            return Err(ModeError::Size(format!("biscale settings: {p}")));
        }
        // Checked before the precomputation, which can take minutes.
        if let Some(p) = RenderSettings::size_problem(width, height) {
            return Err(ModeError::Size(p));
        }
        Self::supports(&scene)?;
        let mut report = PreparationReport::default();
        let bvh = prepare.bvh(&scene.meshes, &mut report)?;
        let (pre, tab, tables) =
            precompute_and_tabulate(&scene, &bvh, &settings, &prepare, &mut report)?;
        prepare.report("lighting", 0.0)?;
        let start = Instant::now();
        let quadtrees = pre
            .refinement
            .flat(&pre.frames.mesh_offsets, meso_gpu::LEAF_BIT);
        let (split, lstar) = lighting(&settings, &pre, scene.environment.as_ref(), None);
        report.record_since("lighting", start);
        let block = encode(
            &settings,
            &scene,
            &tables,
            &quadtrees,
            lstar.as_deref(),
            split.as_ref(),
        )
        .map_err(upload_error)?;
        let device =
            GpuSpmmMode::prepare_biscale(ctx, scene, (width, height), prepare, bvh, block)?;
        Ok(Self {
            device,
            settings,
            tab,
            tables,
            pre: Arc::new(pre),
            quadtrees,
            split,
            lstar,
            preparation: report,
            light_change_ms: 0.0,
        })
    }

    /// The precomputation in use.
    pub fn precomputed(&self) -> &Precomputed {
        &self.pre
    }

    /// The device half (device bytes, traversal overflows).
    pub fn device_mode(&self) -> &GpuSpmmMode {
        &self.device
    }

    /// The biscale words for the scene as it is, uploaded.
    fn upload(&mut self) -> Result<(), EditError> {
        let block = encode(
            &self.settings,
            self.device.scene(),
            &self.tables,
            &self.quadtrees,
            self.lstar.as_deref(),
            self.split.as_ref(),
        )
        .map_err(|e| EditError::Size(format!("biscale upload: {e}")))?;
        self.device.replace_biscale(block)
    }

    /// A light change: a new split and L* (T is unchanged), uploaded.
    fn relight(&mut self) -> Result<(), EditError> {
        let start = Instant::now();
        let env = self.device.scene().environment.clone();
        (self.split, self.lstar) =
            lighting(&self.settings, &self.pre, env.as_ref(), self.split.take());
        self.light_change_ms = start.elapsed().as_secs_f64() * 1e3;
        self.upload()
    }

    fn summary(&self) -> String {
        let b = self.device.biscale_bytes();
        let traced = match &self.split {
            Some(s) if s.traced_power > 0.0 => {
                format!(
                    " · traced: {:.0}% of the map's power",
                    100.0 * s.traced_power
                )
            }
            _ => String::new(),
        };
        let inner = self.device.diagnostics().summary().unwrap_or_default();
        format!(
            "{inner} · biscale: {} vertices ({} added), {} biclusters, L* {:.1} MB, tables {:.1} MB{traced} · light change {:.1} ms",
            self.pre.frames.len(),
            self.pre.stats.refined_vertices,
            self.pre.biclusters.len(),
            b.lstar as f64 / 1e6,
            b.tables as f64 / 1e6,
            self.light_change_ms
        )
    }
}

/// The split of `env` and L* per vertex for its remainder (`None` without an
/// environment: the precomputed part is dark).
fn lighting(
    settings: &BiscaleSettings,
    pre: &Precomputed,
    env: Option<&Environment>,
    kept: Option<EnvironmentSplit>,
) -> (Option<EnvironmentSplit>, Option<Vec<f32>>) {
    let (split, light) = split_lighting(settings, env, kept);
    let m = (settings.local_res * settings.local_res) as usize;
    let lstar = env.map(|_| per_vertex(&pre.biclusters.apply(&light), m));
    (split, lstar)
}

/// The device's words for the preparation.
fn encode(
    settings: &BiscaleSettings,
    scene: &Scene,
    tables: &[Option<BtfTable>],
    quadtrees: &FlatQuadtrees,
    lstar: Option<&[f32]>,
    split: Option<&EnvironmentSplit>,
) -> Result<BiscaleBlock, String> {
    // An SPMM pack's rows go up for the clusters a ray can reach, as its pack does
    // for the GPU spmm mode's shading (`reachable_clusters`); a pack no mesh carries
    // has none.
    let reach = meso_gpu::reachable_clusters(scene);
    let spmm_rows: Vec<Option<Vec<Option<SpmmRows>>>> = tables
        .iter()
        .zip(&reach)
        .map(|(t, used)| match (t, used) {
            (Some(BtfTable::Spmm(t)), Some(used)) if used.contains(&true) => Some(
                (0..t.clusters())
                    .map(|c| {
                        used.get(c).copied().unwrap_or(false).then(|| SpmmRows {
                            bases: t.basis_rows(c),
                            residual: t.residual_rows(c),
                        })
                    })
                    .collect(),
            ),
            _ => None,
        })
        .collect();
    let device_tables: Vec<DeviceTable> = scene
        .materials
        .iter()
        .zip(tables)
        .zip(&spmm_rows)
        .map(|((m, t), rows)| match (m, t) {
            (_, Some(BtfTable::Spmm(t))) => match rows {
                Some(clusters) => DeviceTable::Spmm {
                    clusters,
                    terms: t.terms() as u32,
                },
                None => DeviceTable::None,
            },
            (_, Some(BtfTable::Brdf { rows, albedo })) => DeviceTable::Gray {
                rows,
                albedo: *albedo,
            },
            (_, Some(BtfTable::Rgb { rows })) => DeviceTable::Rgb { rows },
            (Material::Btf { .. }, _) => DeviceTable::Cells,
            // Mirrors (the ray is followed).
            _ => DeviceTable::None,
        })
        .collect();
    let peaks: Option<(&Image, _)> =
        split.and_then(|s| s.sampler.as_ref().map(|sampler| (&s.peaks, sampler)));
    BiscaleBlock::encode(&BiscaleInputs {
        local_res: settings.local_res,
        view_res: settings.view_res,
        mesh_first: &quadtrees.mesh_first,
        roots: &quadtrees.roots,
        nodes: &quadtrees.nodes,
        leaves: &quadtrees.leaves,
        lstar,
        tables: &device_tables,
        peaks,
    })
}

impl RenderMode for GpuBiscaleMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Biscale
    }

    fn render(&mut self, pass: Pass, stop: Option<&mut dyn FnMut() -> bool>) -> Option<FrameStats> {
        self.device.render(pass, stop)
    }

    // The device, the scene, the guides (what each pixel's centre ray first sees does
    // not depend on how the environment is integrated) and the denoiser.
    crate::device_half_methods!();

    fn image(&self) -> Image {
        self.device.image()
    }

    fn image_on_device(&self) -> Option<Arc<dyn meso_render::ImageOnDevice>> {
        self.device.image_on_device()
    }

    fn progress(&self) -> Progress {
        self.device.progress()
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.device.set_samples_per_frame(samples);
    }

    fn diagnostics(&self) -> Diagnostics {
        let mut list = self.device.diagnostics().0;
        for d in &mut list {
            match d {
                Diagnostic::Preparation(p) => crate::merge_preparation(&self.preparation, p),
                Diagnostic::DeviceMemory(memory) => {
                    let b = self.device.biscale_bytes();
                    // The biscale words sit in the environment's buffer: shown apart.
                    for (name, bytes) in memory.iter_mut() {
                        if *name == "environment" {
                            *bytes = bytes.saturating_sub(b.total());
                        }
                    }
                    memory.push(("biscale_lstar", b.lstar));
                    memory.push(("biscale_tables", b.tables));
                    memory.push(("biscale_quadtrees", b.quadtrees));
                    memory.push(("biscale_peaks", b.peaks));
                }
                Diagnostic::Summary(s) => *s = self.summary(),
                _ => {}
            }
        }
        Diagnostics(list)
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        match edit {
            SceneEdit::Material { index, material } => {
                let previous = self.scene().materials.get(index).cloned();
                let before = self.tables.get(index).and_then(Option::as_ref);
                let table = self.tab.table_reusing(before, &material);
                // The device half refuses what it cannot shade, named for this mode.
                let invalidation = (self.device)
                    .apply(SceneEdit::Material { index, material })
                    .map_err(|e| crate::edit_refused_for(ModeKind::Biscale, e))?;
                let table_before = std::mem::replace(&mut self.tables[index], table);
                if let Err(e) = self.upload() {
                    // The new tables do not fit: the material goes back as it was on
                    // the device too, so the words and the materials agree.
                    self.tables[index] = table_before;
                    if let Some(m) = previous {
                        self.device
                            .apply(SceneEdit::Material { index, material: m })?;
                    }
                    return Err(e);
                }
                Ok(invalidation)
            }
            edit @ SceneEdit::Meshes(_) => {
                // New geometry: new visibility, so the precomputation runs again, before
                // the device takes the meshes (nothing changes if it fails). Meshes the
                // scene would refuse are refused before any of it.
                edit.apply_to(&mut self.scene().clone())?;
                let SceneEdit::Meshes(meshes) = &edit else {
                    return self.device.apply(edit);
                };
                let bvh = SceneBvh::build(meshes);
                let pre = precompute(meshes, &bvh, &self.settings, &Prepare::quietly())
                    .map_err(|e| EditError::Size(format!("biscale precomputation: {e}")))?;
                let invalidation = self.device.apply(edit)?;
                self.quadtrees = pre
                    .refinement
                    .flat(&pre.frames.mesh_offsets, meso_gpu::LEAF_BIT);
                self.pre = Arc::new(pre);
                self.relight()?;
                Ok(invalidation)
            }
            SceneEdit::Environment(env) => {
                let relit = match (&env, &self.scene().environment) {
                    (Some(e), Some(old)) => !old.same_but_strength(e),
                    _ => true,
                };
                let invalidation = self.device.apply(SceneEdit::Environment(env))?;
                if relit {
                    self.relight()?;
                }
                Ok(invalidation)
            }
            // Lights, the ambient term, the camera, the size, the background, the moving
            // flag and light samples: L* and the tables stand; the device half restarts
            // what they change.
            other => self.device.apply(other),
        }
    }
}
