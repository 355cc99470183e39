//! The pack and the report from the model's tables and every texel's fit, in texel
//! order. The one place both an unsharded fit and `merge` of shard parts end: the same
//! inputs make the same pack, bit for bit, whichever way the texels were fitted.
//! Then, as before, the optional byte budget (`budget.rs`) and the lobe bound's
//! hemisphere check against the finished pack's own maximum (weights clamped where
//! the sample's maximum, which the caps assumed, exceeds the pack's).

use glam::DVec3;

use crate::model::Model;
use crate::report::{self, ClusterStats, ReportInput, StageSeconds};
use crate::texel_fit::TexelFit;
use crate::{FitError, FitOutput, FitSettings, budget};
use meso_materials::spmm::{Cluster, Residual, SparseWeights, SpmmMaterial, lobe_bound};

/// Everything of a fit but the texels' own results: what every shard part carries.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Tables {
    pub name: String,
    pub provenance: String,
    pub width: u32,
    pub height: u32,
    pub light_dirs: Vec<DVec3>,
    pub view_dirs: Vec<DVec3>,
    pub settings: FitSettings,
    pub clusters: Vec<Cluster>,
    /// Per basis its hemisphere peak (the lobe bound).
    pub peaks: Vec<f64>,
    /// Per cluster its components (at most `settings.npca`).
    pub cluster_components: Vec<usize>,
    /// Residual means, `k x d`, as the pack stores them.
    pub mean: Vec<f32>,
    /// Components, `k x npca x d` (zeros past a cluster's own count).
    pub components: Vec<f32>,
    /// Seconds of the clustering, dictionary and residual-model stages.
    pub seconds: [f64; 3],
    /// `Model::hash`: which model the texels were fitted against.
    pub model_hash: u64,
}

impl Tables {
    /// Moves the model's tables (clusters, peaks, residual means and components) out,
    /// leaving this with the small fields only (names, grid, settings, the model's
    /// hash): what a merge compares across parts, so it holds the tables once.
    pub fn take_model(&mut self) -> Tables {
        Tables {
            name: self.name.clone(),
            provenance: self.provenance.clone(),
            width: self.width,
            height: self.height,
            light_dirs: self.light_dirs.clone(),
            view_dirs: self.view_dirs.clone(),
            settings: self.settings,
            clusters: std::mem::take(&mut self.clusters),
            peaks: std::mem::take(&mut self.peaks),
            cluster_components: std::mem::take(&mut self.cluster_components),
            mean: std::mem::take(&mut self.mean),
            components: std::mem::take(&mut self.components),
            seconds: self.seconds,
            model_hash: self.model_hash,
        }
    }

    pub fn new(
        model: &Model,
        (name, provenance): (&str, &str),
        src: &dyn meso_materials::btf::texels::TexelSource,
        settings: &FitSettings,
    ) -> Self {
        let d = src.pairs() * 3;
        let (k, npca) = (model.k(), settings.npca);
        let mut mean = vec![0.0f32; k * d];
        let mut components = vec![0.0f32; k * npca * d];
        for c in 0..k {
            for (dst, src) in mean[c * d..(c + 1) * d].iter_mut().zip(&model.means[c]) {
                *dst = *src as f32;
            }
            for (kk, comp) in model.components[c].iter().enumerate() {
                let at = (c * npca + kk) * d;
                for (dst, src) in components[at..at + d].iter_mut().zip(comp) {
                    *dst = *src as f32;
                }
            }
        }
        Self {
            name: name.to_string(),
            provenance: provenance.to_string(),
            width: src.width(),
            height: src.height(),
            light_dirs: src.light_dirs().to_vec(),
            view_dirs: src.view_dirs().to_vec(),
            settings: crate::part::kept_settings(settings),
            clusters: model.clusters.clone(),
            peaks: model.peaks.clone(),
            cluster_components: model.components.iter().map(Vec::len).collect(),
            mean,
            components,
            seconds: model.seconds,
            model_hash: model.hash(),
        }
    }

    pub fn texels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// The pack and report of `tables` and `fits` (every texel's, in order); `texel_seconds`
/// is the time the texel fits took.
pub(crate) fn assemble(
    tables: &Tables,
    fits: &[TexelFit],
    texel_seconds: f64,
) -> Result<FitOutput, FitError> {
    let started = std::time::Instant::now();
    let settings = &tables.settings;
    let (k, npca) = (tables.clusters.len(), settings.npca);
    let texels = tables.texels();
    let mut stats: Vec<ClusterStats> = tables
        .cluster_components
        .iter()
        .map(|&n| ClusterStats::new(n))
        .collect();
    let mut assignment = Vec::with_capacity(texels);
    let mut coefficients = vec![0.0f32; texels * npca];
    let mut sparse = SparseWeights {
        offsets: vec![0],
        basis: Vec::new(),
        rgb: Vec::new(),
    };
    let mut value_sum = 0.0;
    for (t, f) in fits.iter().enumerate() {
        let c = f.cluster as usize;
        assignment.push(f.cluster);
        for (dst, src) in coefficients[t * npca..].iter_mut().zip(&f.coefficients) {
            *dst = *src as f32;
        }
        for &(j, rgb) in &f.weights {
            sparse.basis.push(j);
            sparse.rgb.push(rgb);
        }
        sparse.offsets.push(sparse.basis.len() as u32);
        stats[c].add(f.sse_basis, f.sse_mean, &f.coefficients);
        value_sum += f.value_sum;
    }
    stats.iter_mut().for_each(ClusterStats::finish);
    let counts: Vec<usize> = fits.iter().map(|f| f.weights.len()).collect();
    let mut material = SpmmMaterial::new(
        tables.name.clone(),
        tables.provenance.clone(),
        tables.width,
        tables.height,
        tables.clusters.clone(),
        assignment,
        sparse,
        Some(Residual {
            light_dirs: tables.light_dirs.clone(),
            view_dirs: tables.view_dirs.clone(),
            npca,
            mean: tables.mean.clone(),
            components: tables.components.clone(),
            coefficients,
        }),
    )?;
    debug_assert_eq!(material.clusters().len(), k);
    let mut cluster_npca = None;
    let mut lowered = None;
    if let Some(max_bytes) = settings.max_bytes {
        let trimmed = budget::trim_to_bytes(&material, max_bytes, settings.precision)?;
        material = trimmed.material;
        cluster_npca = Some(trimmed.cluster_npca);
    }
    if settings.hemisphere_bound {
        // The caps assumed the sample's brightest value; the pack's own maximum is
        // the bound's reference. Where it falls short, the weights over it are lowered.
        let pack_max = lobe_bound::tabulated_maximum(&material);
        let worst = lobe_bound::largest_weights(&material)
            .iter()
            .flatten()
            .zip(&tables.peaks)
            .map(|(w, p)| w * p)
            .fold(0.0f64, f64::max);
        if worst > lobe_bound::HEMISPHERE_MULTIPLE * 0.97 * pack_max {
            let (clamped, n) =
                budget::clamp_to_lobe_bound(&material).map_err(|_| FitError::LobeBound)?;
            material = clamped;
            lowered = Some(n);
        }
    }
    let [clustering, dictionary, residual] = tables.seconds;
    let seconds = StageSeconds {
        clustering,
        dictionary,
        weights: texel_seconds,
        residual,
        total: clustering + dictionary + residual + texel_seconds + started.elapsed().as_secs_f64(),
    };
    let mut report = report::build(
        &material,
        ReportInput {
            stats: &stats,
            counts: &counts,
            value_sum,
            lights: tables.light_dirs.len(),
            views: tables.view_dirs.len(),
            settings,
            seconds,
        },
    );
    if let Some(counts) = cluster_npca {
        report.set_cluster_npca(&stats, counts);
    }
    report.lowered_weights = lowered;
    Ok(FitOutput {
        material,
        report,
        precision: settings.precision,
    })
}
