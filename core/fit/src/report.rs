//! The fit report of `meso fit` (`--report` JSON and the human text): RMSE of the
//! SPMM against the BTF at its tabulated directions, per cluster and overall, without
//! the residual and with the mean plus N_PCA = 0, 1, 2, 4, 8 components (closed form
//! from the exact PCA projections, before the pack's f16 rounding of the tables),
//! retained energy per component, bases per texel, sizes and time per stage.

use serde::Serialize;

use super::FitSettings;
use super::residual::ClusterResidual;
use meso_materials::btf::Btf;
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

fn row(residuals: &[&ClusterResidual], texels: usize, per_texel: usize, npca: usize) -> ErrorRow {
    let n = (texels * per_texel).max(1) as f64;
    let without: f64 = residuals.iter().map(|r| r.sse_without).sum();
    let rmse_npca = npca_levels(npca)
        .into_iter()
        .map(|k| {
            let sse: f64 = residuals
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

pub(super) fn build(
    btf: &Btf,
    material: &SpmmMaterial,
    members: &[Vec<usize>],
    residuals: &[ClusterResidual],
    weights: &[Vec<(usize, [f64; 3])>],
    settings: &FitSettings,
    seconds: StageSeconds,
) -> FitReport {
    let per_texel = btf.pairs() * 3;
    let per_cluster = residuals
        .iter()
        .enumerate()
        .map(|(c, r)| ClusterReport {
            cluster: c,
            dictionary: material.clusters()[c]
                .bases
                .iter()
                .map(|b| b.brdf().model().name())
                .collect(),
            errors: row(&[r], members[c].len(), per_texel, settings.npca),
            retained_energy: r.retained(),
        })
        .collect();
    let all: Vec<&ClusterResidual> = residuals.iter().collect();
    let counts: Vec<usize> = weights.iter().map(Vec::len).collect();
    let btf_bytes = (btf.data().len() * 4) as u64;
    FitReport {
        width: btf.width(),
        height: btf.height(),
        lights: btf.light_dirs().len(),
        views: btf.view_dirs().len(),
        clusters: material.clusters().len(),
        subclusters: settings.subclusters,
        max_bases: settings.max_bases,
        npca: settings.npca,
        seed: settings.seed,
        mean_reflectance: btf.mean_value(),
        overall: row(&all, btf.texels(), per_texel, settings.npca),
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
    }
}

impl FitReport {
    /// Records the per-cluster component counts a byte budget chose, and the error
    /// they leave.
    pub(super) fn set_cluster_npca(&mut self, residuals: &[ClusterResidual], counts: Vec<usize>) {
        let n = (self.width as usize * self.height as usize * self.lights * self.views * 3).max(1);
        let sse: f64 = residuals
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
