//! A fit's model as a file (`meso fit IN.btf --model-only -o MODEL`,
//! docs/formats/fit-model.md): the shared half of a fit (`model.rs`), found once, so
//! the shards of a split fit (`--shard K/N --model MODEL`) skip the model stage that
//! each would otherwise repeat. What the texel fits read is stored as computed
//! (centroids, dictionaries, weight caps and peaks, residual means and components);
//! what follows from it and the BTF's directions (each basis's values at every pair,
//! the Gram matrices) is computed again on loading, by the same code, so a fit from a
//! loaded model is bit for bit the fit from a model found in the same process.
//!
//! A model is used only where it was found: the same options (`options_text`) and the
//! same input as the seeded sample sees it (`model::input_hash`); anything else is
//! refused, naming the file.

use std::path::{Path, PathBuf};

use meso_materials::btf::texels::TexelSource;
use meso_materials::hash::fnv1a64;
use meso_materials::spmm::Cluster;

use crate::codec::{In, Out, read_basis, write_clusters};
use crate::model::{self, Model};
use crate::{FitError, FitSettings};

const MAGIC: &[u8; 8] = b"MESOMODL";
const VERSION: u32 = 1;

/// A fit's model with what it was found on.
#[derive(Clone, Debug)]
pub struct FitModel {
    /// The input as the fit named it (file name), for messages.
    pub input: String,
    /// `FitSettings::options_text` of the fit that found it.
    pub options: String,
    pub(crate) model: Model,
}

/// A model file that cannot be read, or a model that does not belong to this fit.
#[derive(Debug, thiserror::Error)]
pub enum ModelFileError {
    #[error("`{path}`: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("`{path}`: not a fit model: {problem}")]
    Corrupt { path: PathBuf, problem: String },
    #[error("`{path}` was found with other options: `{model_options}`; this fit's are `{options}`")]
    DifferentOptions {
        path: PathBuf,
        model_options: String,
        options: String,
    },
    #[error(
        "`{path}` was found on another input (`{model_input}`: its grid, directions or sampled texels differ from this BTF's)"
    )]
    DifferentInput { path: PathBuf, model_input: String },
    #[error("`{path}` does not fit this BTF: {problem}")]
    Shape { path: PathBuf, problem: String },
}

impl FitModel {
    /// The model file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let m = &self.model;
        let mut o = Out::default();
        o.0.extend_from_slice(MAGIC);
        o.u32(VERSION);
        o.str(&self.input);
        o.str(&self.options);
        o.u64(m.input_hash);
        o.u32(m.feature_pairs.len() as u32);
        m.feature_pairs.iter().for_each(|&p| o.u32(p as u32));
        o.f32s(&m.centroids);
        o.u32(m.clusters.len() as u32);
        write_clusters(&mut o, &m.clusters);
        for v in [&m.caps, &m.peaks] {
            v.iter().for_each(|&x| o.f64(x));
        }
        for (mean, comps) in m.means.iter().zip(&m.components) {
            o.u64(mean.len() as u64);
            mean.iter().for_each(|&x| o.f64(x));
            o.u32(comps.len() as u32);
            for c in comps {
                c.iter().for_each(|&x| o.f64(x));
            }
        }
        m.seconds.iter().for_each(|&x| o.f64(x));
        o.u64(m.hash());
        let sum = fnv1a64(&o.0);
        o.u64(sum);
        o.0
    }

    /// Parses a model file's bytes; the error says what is wrong and where. The
    /// basis tables are left empty: `attach` computes them for the BTF it is used on.
    pub fn decode(bytes: &[u8]) -> Result<FitModel, String> {
        if bytes.len() < 8 + 4 + 8 || &bytes[..8] != MAGIC {
            return Err("it does not start with `MESOMODL`".into());
        }
        let Some((body, sum)) = bytes.split_last_chunk::<8>() else {
            return Err("it is cut short before its checksum".into());
        };
        if fnv1a64(body) != u64::from_le_bytes(*sum) {
            return Err("checksum mismatch (damaged or cut short)".into());
        }
        let mut i = In { bytes: body, at: 8 };
        let version = i.u32("the version")?;
        if version != VERSION {
            return Err(format!("version {version}, this build reads {VERSION}"));
        }
        let input = i.str("the input name")?;
        let options = i.str("the options")?;
        let input_hash = i.u64("the input hash")?;
        let n = i.u32("the feature pairs")?;
        let n = i.count(u64::from(n), 4, "the feature pairs")?;
        let feature_pairs = (0..n)
            .map(|_| i.u32("a feature pair").map(|p| p as usize))
            .collect::<Result<Vec<_>, _>>()?;
        let centroids = i.f32s("the centroids")?;
        let k = i.u32("the cluster count")?;
        let k = i.count(u64::from(k), 4, "the clusters")?;
        let mut clusters = Vec::with_capacity(k);
        for c in 0..k {
            let what = format!("cluster {c}");
            let n = i.u32(&what)?;
            let n = i.count(u64::from(n), 1, &what)?;
            let bases = (0..n)
                .map(|_| read_basis(&mut i, &what))
                .collect::<Result<Vec<_>, _>>()?;
            clusters.push(Cluster { bases });
        }
        let bases: usize = clusters.iter().map(|c| c.bases.len()).sum();
        let mut f64s = |n: usize, what: &str| -> Result<Vec<f64>, String> {
            let n = i.count(n as u64, 8, what)?;
            (0..n).map(|_| i.f64(what)).collect()
        };
        let caps = f64s(bases, "the weight caps")?;
        let peaks = f64s(bases, "the peaks")?;
        let mut means = Vec::with_capacity(k);
        let mut components = Vec::with_capacity(k);
        for c in 0..k {
            let what = format!("cluster {c}'s residual");
            let len = i.u64(&what)?;
            let len = i.count(len, 8, &what)?;
            means.push(
                (0..len)
                    .map(|_| i.f64(&what))
                    .collect::<Result<Vec<_>, _>>()?,
            );
            let nc = i.u32(&what)?;
            let nc = i.count(u64::from(nc), len.max(1) * 8, &what)?;
            components.push(
                (0..nc)
                    .map(|_| (0..len).map(|_| i.f64(&what)).collect())
                    .collect::<Result<Vec<Vec<f64>>, _>>()?,
            );
        }
        let seconds = [
            i.f64("the stage seconds")?,
            i.f64("the stage seconds")?,
            i.f64("the stage seconds")?,
        ];
        let hash = i.u64("the model hash")?;
        if i.at != body.len() {
            return Err(format!("{} bytes after the model hash", body.len() - i.at));
        }
        let model = Model {
            feature_pairs,
            centroids,
            clusters,
            columns: Vec::new(),
            first_col: Vec::new(),
            grams: Vec::new(),
            caps,
            peaks,
            means,
            components,
            input_hash,
            seconds,
        };
        if model.hash() != hash {
            return Err("its numbers do not give its model hash".into());
        }
        Ok(FitModel {
            input,
            options,
            model,
        })
    }

    /// Reads and parses the model file at `path`.
    pub fn read(path: &Path) -> Result<FitModel, ModelFileError> {
        let bytes = std::fs::read(path).map_err(|source| ModelFileError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        FitModel::decode(&bytes).map_err(|problem| ModelFileError::Corrupt {
            path: path.to_path_buf(),
            problem,
        })
    }

    /// The model ready to fit `src`'s texels with `settings` (its basis tables
    /// computed), after checking that it was found with these options on this input.
    /// `path` names the file in errors; `block` bounds the texels read to check the
    /// input.
    pub(crate) fn attach(
        mut self,
        src: &dyn TexelSource,
        settings: &FitSettings,
        block: usize,
        path: &Path,
    ) -> Result<Model, FitError> {
        let err = |e: ModelFileError| FitError::Model(e.to_string());
        let options = settings.options_text();
        if self.options != options {
            return Err(err(ModelFileError::DifferentOptions {
                path: path.to_path_buf(),
                model_options: self.options,
                options,
            }));
        }
        let m = &self.model;
        let (pairs, k) = (src.pairs(), m.clusters.len());
        let problem = if k > settings.clusters {
            Some(format!("{k} clusters, --clusters is {}", settings.clusters))
        } else if m
            .clusters
            .iter()
            .any(|c| c.bases.is_empty() || c.bases.len() > usize::from(u16::MAX))
        {
            Some("a cluster has no bases, or more than a pack holds".to_string())
        } else if m.feature_pairs.iter().any(|&p| p >= pairs) {
            Some(format!("a feature pair is past the BTF's {pairs} pairs"))
        } else if k == 0 || m.centroids.len() != k * m.feature_pairs.len() * 3 {
            Some(format!(
                "{} centroid values for {k} clusters of {} features",
                m.centroids.len(),
                m.feature_pairs.len() * 3
            ))
        } else if m.means.iter().any(|v| v.len() != pairs * 3)
            || m.components.iter().flatten().any(|v| v.len() != pairs * 3)
        {
            Some(format!(
                "its residual tables are not {pairs} direction pairs x 3 long"
            ))
        } else {
            m.components
                .iter()
                .map(Vec::len)
                .max()
                .filter(|&n| n > settings.npca)
                .map(|n| {
                    format!(
                        "a cluster has {n} residual components, N_PCA is {}",
                        settings.npca
                    )
                })
        };
        if let Some(problem) = problem {
            return Err(err(ModelFileError::Shape {
                path: path.to_path_buf(),
                problem,
            }));
        }
        if model::input_hash(src, settings, block)? != m.input_hash {
            return Err(err(ModelFileError::DifferentInput {
                path: path.to_path_buf(),
                model_input: self.input,
            }));
        }
        let (columns, first_col, grams) = model::basis_tables(src, &self.model.clusters);
        self.model.columns = columns;
        self.model.first_col = first_col;
        self.model.grams = grams;
        Ok(self.model)
    }
}
