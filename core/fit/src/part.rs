//! Fits split across machines: `Shard` (`--shard K/N`, the texels a shard fits), the
//! part file one shard writes (docs/formats/fit-part.md) and `merge`, which checks a
//! set of parts belongs together (same input, options and model; every shard once)
//! and assembles them exactly as the unsharded fit does (`assemble.rs`).
//!
//! A part is little-endian binary: a fixed header, the tables every shard shares,
//! the shard's texels' fits, and an FNV-1a checksum of everything before it. Floats
//! are stored as their bits, so a merged pack is the unsharded one bit for bit.

use std::path::{Path, PathBuf};

use crate::assemble::Tables;
use crate::codec::{In, Out, read_basis, write_clusters};
use crate::texel_fit::TexelFit;
use crate::{FitSettings, ResidualPrecision};
use meso_materials::hash::fnv1a64;
use meso_materials::spmm::Cluster;

const MAGIC: &[u8; 8] = b"MESOPART";
const VERSION: u32 = 1;

/// Shard `k` of `n` (1-based): the texels `[(k-1)T/N, kT/N)` of `T`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub k: u32,
    pub n: u32,
}

impl Shard {
    /// Parses `K/N` with 1 <= K <= N.
    pub fn parse(text: &str) -> Result<Shard, String> {
        let (k, n) = text
            .split_once('/')
            .ok_or_else(|| format!("`{text}` is not K/N (for example 2/4)"))?;
        let num = |s: &str| {
            s.trim()
                .parse::<u32>()
                .map_err(|_| format!("`{text}`: `{s}` is not a count"))
        };
        let (k, n) = (num(k)?, num(n)?);
        Shard::new(k, n).map_err(|e| format!("`{text}`: {e}"))
    }

    /// Shard `k` of `n`, refused outside 1 <= k <= n.
    pub fn new(k: u32, n: u32) -> Result<Shard, String> {
        if n == 0 || k == 0 || k > n {
            return Err(format!("shard {k} of {n} is out of range (1 <= K <= N)"));
        }
        Ok(Shard { k, n })
    }

    /// This shard's texels out of `texels`.
    pub fn texels(self, texels: usize) -> std::ops::Range<usize> {
        let at = |k: u32| (k as u128 * texels as u128 / self.n as u128) as usize;
        at(self.k - 1)..at(self.k)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

/// One shard's part of a fit.
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    pub shard: Shard,
    /// The input as the shard named it (file name), for messages.
    pub input: String,
    /// `FitSettings::options_text` of the fit.
    pub options: String,
    pub input_hash: u64,
    pub(crate) tables: Tables,
    pub(crate) fits: Vec<TexelFit>,
    /// Seconds the shard's texel fits took.
    pub texel_seconds: f64,
}

/// A part file that cannot be read, or parts that do not make one fit. Every
/// message names the file(s) at fault.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("`{path}`: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("`{path}`: not a fit part: {problem}")]
    Corrupt { path: PathBuf, problem: String },
    #[error("no parts to merge")]
    NoParts,
    #[error("`{second}` is shard {} of {}, `{first}` of {}: parts of one fit share N", .shard.k, .shard.n, .first_n)]
    ShardCount {
        first: PathBuf,
        first_n: u32,
        second: PathBuf,
        shard: Shard,
    },
    #[error("`{first}` and `{second}` are both shard {shard}")]
    Duplicate {
        first: PathBuf,
        second: PathBuf,
        shard: Shard,
    },
    #[error("shard(s) {} of {n} missing (merge needs every shard once)", .missing.iter().map(u32::to_string).collect::<Vec<_>>().join(", "))]
    Missing { missing: Vec<u32>, n: u32 },
    #[error(
        "`{second}` fits a different input than `{first}` (`{second_input}` vs `{first_input}`: grid, directions or sampled texels differ)"
    )]
    DifferentInput {
        first: PathBuf,
        first_input: String,
        second: PathBuf,
        second_input: String,
    },
    #[error(
        "`{second}` was fitted with other options than `{first}`: `{second_options}` vs `{first_options}`"
    )]
    DifferentOptions {
        first: PathBuf,
        first_options: String,
        second: PathBuf,
        second_options: String,
    },
    #[error(
        "`{second}` was fitted against another model than `{first}` (same input and options; a different build of meso?)"
    )]
    DifferentModel { first: PathBuf, second: PathBuf },
}

fn precision_id(p: ResidualPrecision) -> u8 {
    match p {
        ResidualPrecision::F16 => 0,
        ResidualPrecision::F32 => 1,
        ResidualPrecision::I8 => 2,
    }
}

/// The settings a part keeps: those the assembly and the report read (the rest shaped
/// the model, which the part holds, and are compared through `options`).
pub(crate) fn kept_settings(s: &FitSettings) -> FitSettings {
    FitSettings {
        clusters: s.clusters,
        subclusters: s.subclusters,
        max_bases: s.max_bases,
        npca: s.npca,
        seed: s.seed,
        hemisphere_bound: s.hemisphere_bound,
        max_bytes: s.max_bytes,
        precision: s.precision,
        ..FitSettings::default()
    }
}

fn write_tables(o: &mut Out, t: &Tables) {
    o.str(&t.name);
    o.str(&t.provenance);
    o.u32(t.width);
    o.u32(t.height);
    o.dirs(&t.light_dirs);
    o.dirs(&t.view_dirs);
    let s = &t.settings;
    for v in [s.clusters, s.subclusters, s.max_bases, s.npca] {
        o.u32(v as u32);
    }
    o.u64(s.seed);
    o.u8(u8::from(s.hemisphere_bound));
    o.u8(u8::from(s.max_bytes.is_some()));
    o.u64(s.max_bytes.unwrap_or(0));
    o.u8(precision_id(s.precision));
    o.u32(t.clusters.len() as u32);
    write_clusters(o, &t.clusters);
    o.u32(t.peaks.len() as u32);
    t.peaks.iter().for_each(|&x| o.f64(x));
    t.cluster_components.iter().for_each(|&n| o.u32(n as u32));
    o.f32s(&t.mean);
    o.f32s(&t.components);
    t.seconds.iter().for_each(|&x| o.f64(x));
    o.u64(t.model_hash);
}

fn read_tables(i: &mut In) -> Result<Tables, String> {
    let name = i.str("the name")?;
    let provenance = i.str("the provenance")?;
    let width = i.u32("the width")?;
    let height = i.u32("the height")?;
    let light_dirs = i.dirs("the light directions")?;
    let view_dirs = i.dirs("the view directions")?;
    let mut counts = [0usize; 4];
    for c in counts.iter_mut() {
        *c = i.u32("the settings")? as usize;
    }
    let seed = i.u64("the seed")?;
    let hemisphere_bound = i.u8("the lobe bound flag")? != 0;
    let has_budget = i.u8("the byte budget flag")? != 0;
    let budget = i.u64("the byte budget")?;
    let precision = match i.u8("the precision")? {
        0 => ResidualPrecision::F16,
        1 => ResidualPrecision::F32,
        2 => ResidualPrecision::I8,
        p => return Err(format!("precision id {p} is not 0..=2")),
    };
    let settings = kept_settings(&FitSettings {
        clusters: counts[0],
        subclusters: counts[1],
        max_bases: counts[2],
        npca: counts[3],
        seed,
        hemisphere_bound,
        max_bytes: has_budget.then_some(budget),
        precision,
        ..FitSettings::default()
    });
    let k = i.u32("the cluster count")? as u64;
    let k = i.count(k, 4, "the clusters")?;
    let mut clusters = Vec::with_capacity(k);
    for c in 0..k {
        let n = i.u32("a dictionary size")? as u64;
        let n = i.count(n, 26, "a dictionary")?;
        let bases = (0..n)
            .map(|j| read_basis(i, &format!("cluster {c} basis {j}")))
            .collect::<Result<Vec<_>, _>>()?;
        clusters.push(Cluster { bases });
    }
    let n = i.u32("the peak count")? as u64;
    let n = i.count(n, 8, "the peaks")?;
    let peaks = (0..n)
        .map(|_| i.f64("the peaks"))
        .collect::<Result<_, _>>()?;
    let cluster_components = (0..k)
        .map(|_| i.u32("the component counts").map(|n| n as usize))
        .collect::<Result<_, _>>()?;
    let mean = i.f32s("the residual means")?;
    let components = i.f32s("the residual components")?;
    let mut seconds = [0.0; 3];
    for s in seconds.iter_mut() {
        *s = i.f64("the stage seconds")?;
    }
    let model_hash = i.u64("the model hash")?;
    Ok(Tables {
        name,
        provenance,
        width,
        height,
        light_dirs,
        view_dirs,
        settings,
        clusters,
        peaks,
        cluster_components,
        mean,
        components,
        seconds,
        model_hash,
    })
}

impl Part {
    /// The part file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut o = Out::default();
        o.0.extend_from_slice(MAGIC);
        o.u32(VERSION);
        o.u32(self.shard.k);
        o.u32(self.shard.n);
        o.u64(self.input_hash);
        o.str(&self.input);
        o.str(&self.options);
        write_tables(&mut o, &self.tables);
        o.f64(self.texel_seconds);
        o.u64(self.fits.len() as u64);
        for f in &self.fits {
            o.u32(f.cluster);
            o.u8(f.weights.len() as u8);
            for &(j, rgb) in &f.weights {
                o.u16(j);
                rgb.iter().for_each(|&x| o.f32(x));
            }
            o.u16(f.coefficients.len() as u16);
            f.coefficients.iter().for_each(|&x| o.f64(x));
            o.f64(f.sse_basis);
            o.f64(f.sse_mean);
            o.f64(f.value_sum);
        }
        let sum = fnv1a64(&o.0);
        o.u64(sum);
        o.0
    }

    /// Parses a part file's bytes; the error says what is wrong and where.
    pub fn decode(bytes: &[u8]) -> Result<Part, String> {
        if bytes.len() < 8 + 4 + 8 || &bytes[..8] != MAGIC {
            return Err("it does not start with `MESOPART`".into());
        }
        let Some((body, sum)) = bytes.split_last_chunk::<8>() else {
            return Err("it is cut short before its checksum".into());
        };
        let sum = u64::from_le_bytes(*sum);
        if fnv1a64(body) != sum {
            return Err("checksum mismatch (damaged or cut short)".into());
        }
        let mut i = In { bytes: body, at: 8 };
        let version = i.u32("the version")?;
        if version != VERSION {
            return Err(format!("version {version}, this build reads {VERSION}"));
        }
        let k = i.u32("the shard")?;
        let n = i.u32("the shard count")?;
        let shard = Shard::new(k, n)?;
        let input_hash = i.u64("the input hash")?;
        let input = i.str("the input name")?;
        let options = i.str("the options")?;
        let tables = read_tables(&mut i)?;
        let texel_seconds = i.f64("the texel seconds")?;
        let count = i.u64("the texel count")?;
        let range = shard.texels(tables.texels());
        if count != range.len() as u64 {
            return Err(format!(
                "{count} texels, shard {shard} of {} texels has {}",
                tables.texels(),
                range.len()
            ));
        }
        let k_clusters = tables.clusters.len();
        let mut fits = Vec::with_capacity(range.len());
        for t in range {
            let what = format!("texel {t}");
            let cluster = i.u32(&what)?;
            let bases = tables
                .clusters
                .get(cluster as usize)
                .map(|c| c.bases.len())
                .ok_or_else(|| format!("{what}: cluster {cluster} of {k_clusters}"))?;
            let nw = i.u8(&what)?;
            let mut weights = Vec::with_capacity(nw as usize);
            for _ in 0..nw {
                let j = i.u16(&what)?;
                if j as usize >= bases {
                    return Err(format!("{what}: basis {j} of {bases}"));
                }
                weights.push((j, [i.f32(&what)?, i.f32(&what)?, i.f32(&what)?]));
            }
            let nc = i.u16(&what)? as usize;
            if nc > tables.settings.npca {
                return Err(format!(
                    "{what}: {nc} coefficients, N_PCA is {}",
                    tables.settings.npca
                ));
            }
            let coefficients = (0..nc).map(|_| i.f64(&what)).collect::<Result<_, _>>()?;
            fits.push(TexelFit {
                cluster,
                weights,
                coefficients,
                sse_basis: i.f64(&what)?,
                sse_mean: i.f64(&what)?,
                value_sum: i.f64(&what)?,
            });
        }
        if i.at != body.len() {
            return Err(format!("{} bytes after the last texel", body.len() - i.at));
        }
        Ok(Part {
            shard,
            input,
            options,
            input_hash,
            tables,
            fits,
            texel_seconds,
        })
    }

    /// Reads and parses the part file at `path`.
    pub fn read(path: &Path) -> Result<Part, MergeError> {
        let bytes = std::fs::read(path).map_err(|source| MergeError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Part::decode(&bytes).map_err(|problem| MergeError::Corrupt {
            path: path.to_path_buf(),
            problem,
        })
    }
}

/// Checks that `parts` (with their paths) are every shard of one fit, once each, and
/// returns them in shard order.
pub fn check_parts(parts: Vec<(PathBuf, Part)>) -> Result<Vec<(PathBuf, Part)>, MergeError> {
    let Some((first_path, first)) = parts.first() else {
        return Err(MergeError::NoParts);
    };
    let n = first.shard.n;
    let mut by_shard: Vec<Option<usize>> = vec![None; n as usize];
    for (idx, (path, p)) in parts.iter().enumerate() {
        if p.shard.n != n {
            return Err(MergeError::ShardCount {
                first: first_path.clone(),
                first_n: n,
                second: path.clone(),
                shard: p.shard,
            });
        }
        if p.options != first.options {
            return Err(MergeError::DifferentOptions {
                first: first_path.clone(),
                first_options: first.options.clone(),
                second: path.clone(),
                second_options: p.options.clone(),
            });
        }
        if p.input_hash != first.input_hash {
            return Err(MergeError::DifferentInput {
                first: first_path.clone(),
                first_input: first.input.clone(),
                second: path.clone(),
                second_input: p.input.clone(),
            });
        }
        if p.tables.model_hash != first.tables.model_hash {
            return Err(MergeError::DifferentModel {
                first: first_path.clone(),
                second: path.clone(),
            });
        }
        let slot = &mut by_shard[p.shard.k as usize - 1];
        if let Some(other) = *slot {
            return Err(MergeError::Duplicate {
                first: parts[other].0.clone(),
                second: path.clone(),
                shard: p.shard,
            });
        }
        *slot = Some(idx);
    }
    let missing: Vec<u32> = (1..=n)
        .filter(|k| by_shard[*k as usize - 1].is_none())
        .collect();
    if !missing.is_empty() {
        return Err(MergeError::Missing { missing, n });
    }
    // Every shard 1..=N once: in shard order the parts are the texels in order.
    let mut parts = parts;
    parts.sort_by_key(|(_, p)| p.shard.k);
    Ok(parts)
}
