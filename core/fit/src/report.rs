//! The fit report of `meso fit` (`--report` JSON and the human text): RMSE of the
//! SPMM against the BTF at its tabulated directions, per cluster and overall, without
//! the residual and with the mean plus N_PCA = 0, 1, 2, 4, 8 components (closed form
//! from the exact PCA projections, before the pack's f16 rounding of the tables),
//! retained energy per component, bases per texel, sizes and time per stage.

use serde::Serialize;

use super::FitSettings;
use meso_materials::spmm::SpmmMaterial;

/// RMSE rows: `rmse_basis` without the residual, `rmse_npca` as (N_PCA, RMSE) with
/// the residual's mean and the first N_PCA components.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ErrorRow {
    pub texels: usize,
    pub rmse_basis: f64,
    pub rmse_npca: Vec<(usize, f64)>,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ClusterReport {
    pub cluster: usize,
    /// Model names of the dictionary, in order.
    pub dictionary: Vec<&'static str>,
    pub errors: ErrorRow,
    /// Fraction of the residual's deviation energy kept by each component.
    pub retained_energy: Vec<f64>,
}

#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct StageSeconds {
    pub clustering: f64,
    pub dictionary: f64,
    pub weights: f64,
    pub residual: f64,
    pub total: f64,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct FitReport {
    pub width: u32,
    pub height: u32,
    pub lights: usize,
    pub views: usize,
    pub clusters: usize,
    pub subclusters: usize,
    pub max_bases: usize,
    pub npca: usize,
    pub seed: u64,
    /// Mean BTF value (all texels, pairs, channels): RMSEs are relative to it.
    pub mean_reflectance: f64,
    pub overall: ErrorRow,
    pub per_cluster: Vec<ClusterReport>,
    pub dictionary_bases: usize,
    pub bases_per_texel_mean: f64,
    pub bases_per_texel_min: usize,
    pub bases_per_texel_max: usize,
    /// The BTF's values as f32 (texels x lights x views x 3 x 4 bytes).
    pub btf_bytes: u64,
    /// Filled in by the writer: the pack file's size.
    pub pack_bytes: u64,
    pub compression_ratio: f64,
    pub seconds: StageSeconds,
    /// Under a byte budget (`--max-bytes`): the components kept per cluster, and the
    /// RMSE with them (closed form, before the file's f16 rounding).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cluster_npca: Option<Vec<usize>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rmse_budget: Option<f64>,
    /// Weight entries lowered to the lobe bound after the fit (the pack's maximum fell
    /// below the one the caps assumed); the RMSEs above are from before.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lowered_weights: Option<usize>,
}

/// The N_PCA values the report lists: 0, 1, 2, 4, 8 (up to the fit's N_PCA) and
/// the fit's N_PCA itself.
pub fn npca_levels(npca: usize) -> Vec<usize> {
    let mut v: Vec<usize> = [0, 1, 2, 4, 8].into_iter().filter(|&k| k <= npca).collect();
    if !v.contains(&npca) {
        v.push(npca);
    }
    v
}

/// A cluster's squared errors summed over its texels, in texel order.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct ClusterStats {
    pub texels: usize,
    /// Without the residual.
    pub sse_basis: f64,
    /// With the mean and the first k components, k = 0 ..= the cluster's components.
    pub sse_with: Vec<f64>,
    /// Squared coefficients summed per component: the error each one removes.
    pub energy: Vec<f64>,
}

impl ClusterStats {
    /// The empty sums of a cluster with `components` components.
    pub fn new(components: usize) -> Self {
        Self {
            sse_with: vec![0.0],
            energy: vec![0.0; components],
            ..Self::default()
        }
    }

    /// Adds one texel: its basis-only and mean-only errors and its coefficients.
    pub fn add(&mut self, sse_basis: f64, sse_mean: f64, coefficients: &[f64]) {
        self.texels += 1;
        self.sse_basis += sse_basis;
        self.sse_with[0] += sse_mean;
        for (e, c) in self.energy.iter_mut().zip(coefficients) {
            *e += c * c;
        }
    }

    /// Closes the sums: the error left after each component (exact projections on
    /// orthonormal components remove their energy each).
    pub fn finish(&mut self) {
        self.sse_with.truncate(1);
        for k in 0..self.energy.len() {
            let prev = self.sse_with[k];
            self.sse_with.push((prev - self.energy[k]).max(0.0));
        }
    }

    fn retained(&self) -> Vec<f64> {
        let total = self.sse_with[0];
        self.energy
            .iter()
            .map(|e| if total > 0.0 { e / total } else { 0.0 })
            .collect()
    }
}

fn row(stats: &[&ClusterStats], texels: usize, per_texel: usize, npca: usize) -> ErrorRow {
    let n = (texels * per_texel).max(1) as f64;
    let without: f64 = stats.iter().map(|r| r.sse_basis).sum();
    let rmse_npca = npca_levels(npca)
        .into_iter()
        .map(|k| {
            let sse: f64 = stats
                .iter()
                .map(|r| r.sse_with[k.min(r.sse_with.len() - 1)])
                .sum();
            (k, (sse / n).sqrt())
        })
        .collect();
    ErrorRow {
        texels,
        rmse_basis: (without / n).sqrt(),
        rmse_npca,
    }
}

/// What the report takes from the fit besides the material and the sums.
pub(crate) struct ReportInput<'a> {
    pub stats: &'a [ClusterStats],
    /// Weights per texel.
    pub counts: &'a [usize],
    /// Sum of every BTF value.
    pub value_sum: f64,
    pub lights: usize,
    pub views: usize,
    pub settings: &'a FitSettings,
    pub seconds: StageSeconds,
}

pub(super) fn build(material: &SpmmMaterial, input: ReportInput) -> FitReport {
    let ReportInput {
        stats,
        counts,
        value_sum,
        lights,
        views,
        settings,
        seconds,
    } = input;
    let per_texel = lights * views * 3;
    let texels = material.width() as usize * material.height() as usize;
    let per_cluster = stats
        .iter()
        .enumerate()
        .map(|(c, r)| ClusterReport {
            cluster: c,
            dictionary: material.clusters()[c]
                .bases
                .iter()
                .map(|b| b.brdf().model().name())
                .collect(),
            errors: row(&[r], r.texels, per_texel, settings.npca),
            retained_energy: r.retained(),
        })
        .collect();
    let all: Vec<&ClusterStats> = stats.iter().collect();
    let btf_bytes = (texels * per_texel * 4) as u64;
    FitReport {
        width: material.width(),
        height: material.height(),
        lights,
        views,
        clusters: material.clusters().len(),
        subclusters: settings.subclusters,
        max_bases: settings.max_bases,
        npca: settings.npca,
        seed: settings.seed,
        mean_reflectance: value_sum / (texels * per_texel).max(1) as f64,
        overall: row(&all, texels, per_texel, settings.npca),
        per_cluster,
        dictionary_bases: material.clusters().iter().map(|c| c.bases.len()).sum(),
        bases_per_texel_mean: counts.iter().sum::<usize>() as f64 / counts.len().max(1) as f64,
        bases_per_texel_min: counts.iter().copied().min().unwrap_or(0),
        bases_per_texel_max: counts.iter().copied().max().unwrap_or(0),
        btf_bytes,
        pack_bytes: 0,
        compression_ratio: 0.0,
        seconds,
        cluster_npca: None,
        rmse_budget: None,
        lowered_weights: None,
    }
}

impl FitReport {
    /// Records the per-cluster component counts a byte budget chose, and the error
    /// they leave.
    pub(super) fn set_cluster_npca(&mut self, stats: &[ClusterStats], counts: Vec<usize>) {
        let n = (self.width as usize * self.height as usize * self.lights * self.views * 3).max(1);
        let sse: f64 = stats
            .iter()
            .zip(&counts)
            .map(|(r, &k)| r.sse_with[k.min(r.sse_with.len() - 1)])
            .sum();
        self.rmse_budget = Some((sse / n as f64).sqrt());
        self.cluster_npca = Some(counts);
    }

    /// Records the written pack's size and the compression ratio.
    pub fn set_pack_bytes(&mut self, bytes: u64) {
        self.pack_bytes = bytes;
        self.compression_ratio = self.btf_bytes as f64 / bytes.max(1) as f64;
    }

    /// The human-readable report.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let rel = |x: f64| 100.0 * x / self.mean_reflectance.max(1e-30);
        s.push_str(&format!(
            "BTF {}x{} texels, {} x {} directions; {} clusters, {} representatives each, <= {} bases per texel, N_PCA {} (seed {})\n",
            self.width, self.height, self.lights, self.views, self.clusters, self.subclusters, self.max_bases, self.npca, self.seed
        ));
        s.push_str(&format!(
            "mean reflectance {:.5}; RMSE without residual {:.5} ({:.2}%)\n",
            self.mean_reflectance,
            self.overall.rmse_basis,
            rel(self.overall.rmse_basis)
        ));
        for (k, e) in &self.overall.rmse_npca {
            s.push_str(&format!(
                "  with residual, N_PCA = {k}: RMSE {e:.5} ({:.2}%)\n",
                rel(*e)
            ));
        }
        if let (Some(counts), Some(e)) = (&self.cluster_npca, self.rmse_budget) {
            let list: Vec<String> = counts.iter().map(usize::to_string).collect();
            s.push_str(&format!(
                "  under the byte budget, N_PCA per cluster [{}]: RMSE {e:.5} ({:.2}%)\n",
                list.join(", "),
                rel(e)
            ));
        }
        if let Some(n) = self.lowered_weights {
            s.push_str(&format!(
                "  {n} weight entries lowered to the lobe bound after the fit (the RMSEs above are from before)\n"
            ));
        }
        s.push_str(&format!(
            "dictionary bases {} in all; bases per texel mean {:.2} (min {}, max {})\n",
            self.dictionary_bases,
            self.bases_per_texel_mean,
            self.bases_per_texel_min,
            self.bases_per_texel_max
        ));
        if self.pack_bytes > 0 {
            s.push_str(&format!(
                "BTF {} bytes (f32) / pack {} bytes = compression {:.1}x\n",
                self.btf_bytes, self.pack_bytes, self.compression_ratio
            ));
        }
        s.push_str(&format!(
            "time: clustering {:.2} s, dictionaries {:.2} s, weights {:.2} s, residual {:.2} s, total {:.2} s\n",
            self.seconds.clustering, self.seconds.dictionary, self.seconds.weights, self.seconds.residual, self.seconds.total
        ));
        s.push_str("cluster  texels  bases  RMSE basis  RMSE +residual(N_PCA max)  first components' energy\n");
        for c in &self.per_cluster {
            let last = c.errors.rmse_npca.last().map_or(0.0, |x| x.1);
            let energy: Vec<String> = c
                .retained_energy
                .iter()
                .take(4)
                .map(|e| format!("{:.3}", e))
                .collect();
            s.push_str(&format!(
                "{:>7}  {:>6}  {:>5}  {:>10.5}  {:>25.5}  {}\n",
                c.cluster,
                c.errors.texels,
                c.dictionary.len(),
                c.errors.rmse_basis,
                last,
                energy.join(" ")
            ));
        }
        s
    }
}
