//! The `.spmm` pack: an SPMM material in the safetensors container (named tensors and a
//! string metadata map with `format = "meso-spmm"`, `version = "1"`), specified in
//! docs/formats/spmm.md. Reading parses the container with the `safetensors` crate
//! (offsets and sizes checked against the real file, so a lying header cannot make
//! it allocate) and then checks every shape, dtype, index and range before building
//! the material. Writing emits a deterministic header, so save -> load -> save is
//! byte-identical, and goes through `atomic::write_atomic`.

use std::collections::BTreeMap;
use std::path::Path;

use glam::DVec3;
use safetensors::{Dtype, SafeTensors};

use super::material::{Cluster, Residual, SparseWeights, SpmmError, SpmmMaterial};
use crate::atomic::write_bytes_atomic;
use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfError, BrdfModel};
use crate::container::{self, ContainerError, FileError, Tensor, dtype_name};

pub const FORMAT: &str = "meso-spmm";
pub const VERSION: &str = "1";
/// Columns of `basis_params`: enough for the model with the most parameters.
pub const PARAM_COLUMNS: usize = 4;
/// Packs larger than this are refused before reading (a material is MBs, not GBs).
pub const MAX_FILE_BYTES: u64 = 1 << 31;

/// Precision of the residual tables on disk (f16 halves the largest part of a pack).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResidualPrecision {
    F16,
    F32,
    /// Components as signed 8-bit integers, each run of `V x 3` values (one component,
    /// one light direction) scaled by a power of two of its own; the mean as F16. Half
    /// the bytes of F16 per component, so twice the components at equal bytes.
    I8,
}

impl ResidualPrecision {
    /// The command-line and documentation name.
    pub fn name(self) -> &'static str {
        match self {
            Self::F16 => "f16",
            Self::F32 => "f32",
            Self::I8 => "i8",
        }
    }
}

/// Exponent range of an I8 residual run: a run holds `q * 2^e` with `|q| <= 127`. The
/// lowest step, 2^-24, is a half float's finest, so decoded values of runs under 1 in
/// magnitude are half floats (a render keeps its tables as halves, `spmm::prepared`).
pub const I8_EXPONENT_MIN: i32 = -24;
/// The highest: runs up to 127 x 2^100 in magnitude.
pub const I8_EXPONENT_MAX: i32 = 100;

/// The exponent of an I8 run whose largest magnitude is `max_abs`: the smallest `e` in
/// range with `max_abs <= 127 * 2^e`. A decoded run gets its own exponent back (its
/// largest `|q|` is then 64..=127, or the exponent is a bound of the range), so
/// encoding what was decoded gives the same bytes.
fn i8_exponent(max_abs: f64) -> i32 {
    let fits = |e: i32| max_abs <= 127.0 * 2f64.powi(e);
    let mut e = if max_abs > 0.0 {
        (max_abs.log2().ceil() as i32 - 7).clamp(I8_EXPONENT_MIN, I8_EXPONENT_MAX)
    } else {
        I8_EXPONENT_MIN
    };
    while e < I8_EXPONENT_MAX && !fits(e) {
        e += 1;
    }
    while e > I8_EXPONENT_MIN && fits(e - 1) {
        e -= 1;
    }
    e
}

/// `values` in runs of `run` values as I8 codes and one exponent per run (round to
/// nearest; a run beyond 127 x 2^100 saturates, far outside any fitted residual).
fn quantize_i8(values: &[f32], run: usize) -> (Vec<u8>, Vec<u8>) {
    let mut codes = Vec::with_capacity(values.len());
    let mut exponents = Vec::with_capacity(values.len() / run.max(1));
    for chunk in values.chunks(run.max(1)) {
        let max_abs = chunk.iter().fold(0.0f64, |m, &x| m.max(f64::from(x).abs()));
        let e = i8_exponent(max_abs);
        let scale = 2f64.powi(-e);
        exponents.push(e as i8 as u8);
        codes.extend(
            chunk
                .iter()
                .map(|&x| (f64::from(x) * scale).round().clamp(-127.0, 127.0) as i8 as u8),
        );
    }
    (codes, exponents)
}

/// Decodes I8 runs: `q * 2^e`, exact in f32 over the exponent range. An exponent
/// outside the range, or a code of -128, is refused naming the run.
fn dequantize_i8(codes: &[u8], exponents: &[u8], run: usize) -> Result<Vec<f32>, PackErrorKind> {
    let mut out = Vec::with_capacity(codes.len());
    for (i, (chunk, &e)) in codes.chunks(run.max(1)).zip(exponents).enumerate() {
        let e = i32::from(e as i8);
        if !(I8_EXPONENT_MIN..=I8_EXPONENT_MAX).contains(&e) {
            return Err(PackErrorKind::Quantized(format!(
                "tensor `residual_component_exponents`[{i}] = {e} is outside \
                 {I8_EXPONENT_MIN}..={I8_EXPONENT_MAX}"
            )));
        }
        if let Some(q) = chunk.iter().find(|&&q| q as i8 == i8::MIN) {
            return Err(PackErrorKind::Quantized(format!(
                "tensor `residual_components`: code {} in run {i} is outside -127..=127",
                *q as i8
            )));
        }
        let scale = 2f64.powi(e);
        out.extend(chunk.iter().map(|&q| (f64::from(q as i8) * scale) as f32));
    }
    Ok(out)
}

/// A pack that cannot be read or written: the file and what is wrong with it.
pub type PackError = FileError<PackErrorKind>;

/// What is wrong with a pack: what every container file can have wrong
/// (`ContainerError`), or what only a pack can.
#[derive(Debug, thiserror::Error)]
pub enum PackErrorKind {
    #[error(transparent)]
    Container(#[from] ContainerError),
    #[error(
        "tensor `basis_model`[{index}] = {value}: model ids are 0..=6 (lambertian .. ashikhmin_shirley)"
    )]
    ModelId { index: usize, value: u8 },
    #[error("basis {index} (tensors basis_params/basis_normal row {index}): {source}")]
    Basis { index: usize, source: BrdfError },
    #[error(
        "tensor `basis_params`[{index}][{column}] = {value}: model `{model}` has {used} parameter(s), unused columns must be 0"
    )]
    UnusedParam {
        index: usize,
        column: usize,
        value: f64,
        model: &'static str,
        used: usize,
    },
    #[error("{0}")]
    Ragged(String),
    /// An I8 residual table that cannot be decoded (docs/formats/spmm.md).
    #[error("{0}")]
    Quantized(String),
    #[error("tensor `cluster_basis_offsets`: {0}")]
    ClusterOffsets(String),
    #[error("{0}")]
    Material(#[from] SpmmError),
}

/// How a pack's size limit and unknown tensors are named in `ContainerError`.
const FILE_NOUN: &str = "a pack";
const FORMAT_NOUN: &str = "format";

/// The model id stored in `basis_model`: the index in `BrdfModel::ALL`.
pub fn model_id(model: BrdfModel) -> u8 {
    BrdfModel::ALL
        .iter()
        .position(|m| *m == model)
        .expect("ALL lists every model") as u8
}

/// Reads and validates a pack file.
pub fn read_pack(path: &Path) -> Result<SpmmMaterial, PackError> {
    let at = |kind: PackErrorKind| PackError::at(path, kind);
    let bytes = container::read_limited(path, MAX_FILE_BYTES, FILE_NOUN)
        .map_err(|e| at(e.into()))?;
    decode_pack(&bytes).map_err(at)
}

/// Writes a pack atomically (the previous file survives a failed write).
pub fn write_pack(
    path: &Path,
    material: &SpmmMaterial,
    precision: ResidualPrecision,
) -> Result<(), PackError> {
    write_bytes_atomic(path, &encode_pack(material, precision))
        .map_err(|e| PackError::at(path, ContainerError::from(e)))
}

fn le_bytes<T: Copy, const N: usize>(values: &[T], to: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    values.iter().flat_map(|v| to(*v)).collect()
}

/// Serialises a material. The header lists tensors by name with sorted keys, and the
/// data follows in the order of decreasing element size then name, so every tensor
/// starts aligned to its element size.
pub fn encode_pack(m: &SpmmMaterial, precision: ResidualPrecision) -> Vec<u8> {
    let mut tensors: BTreeMap<&'static str, Tensor> = BTreeMap::new();
    let (w, h) = (m.width() as usize, m.height() as usize);
    let mut put = |name, dtype, shape: Vec<usize>, data| {
        tensors.insert(name, Tensor { dtype, shape, data });
    };
    put(
        "texel_cluster",
        Dtype::U32,
        vec![h, w],
        le_bytes(m.texel_cluster(), u32::to_le_bytes),
    );
    let bases: Vec<&BasisFunction> = m.clusters().iter().flat_map(|c| &c.bases).collect();
    let mut offsets = vec![0u32];
    for c in m.clusters() {
        offsets.push(offsets.last().copied().unwrap_or(0) + c.bases.len() as u32);
    }
    put(
        "cluster_basis_offsets",
        Dtype::U32,
        vec![offsets.len()],
        le_bytes(&offsets, u32::to_le_bytes),
    );
    let models: Vec<u8> = bases.iter().map(|b| model_id(b.brdf().model())).collect();
    put("basis_model", Dtype::U8, vec![bases.len()], models);
    let params: Vec<f64> = bases
        .iter()
        .flat_map(|b| {
            let mut row = [0.0; PARAM_COLUMNS];
            for (slot, v) in row.iter_mut().zip(b.brdf().param_values()) {
                *slot = v;
            }
            row
        })
        .collect();
    put(
        "basis_params",
        Dtype::F64,
        vec![bases.len(), PARAM_COLUMNS],
        le_bytes(&params, f64::to_le_bytes),
    );
    let normals: Vec<f64> = bases.iter().flat_map(|b| b.normal().to_array()).collect();
    put(
        "basis_normal",
        Dtype::F64,
        vec![bases.len(), 3],
        le_bytes(&normals, f64::to_le_bytes),
    );
    let wts = m.weights();
    put(
        "weight_offsets",
        Dtype::U32,
        vec![wts.offsets.len()],
        le_bytes(&wts.offsets, u32::to_le_bytes),
    );
    put(
        "weight_basis",
        Dtype::U16,
        vec![wts.basis.len()],
        le_bytes(&wts.basis, u16::to_le_bytes),
    );
    put(
        "weight_rgb",
        Dtype::F32,
        vec![wts.rgb.len(), 3],
        le_bytes(wts.rgb.as_flattened(), f32::to_le_bytes),
    );
    if let Some(r) = m.residual() {
        let dirs = |d: &[DVec3]| {
            le_bytes(
                &d.iter().flat_map(|v| v.to_array()).collect::<Vec<_>>(),
                f64::to_le_bytes,
            )
        };
        put(
            "light_dirs",
            Dtype::F64,
            vec![r.light_dirs.len(), 3],
            dirs(&r.light_dirs),
        );
        put(
            "view_dirs",
            Dtype::F64,
            vec![r.view_dirs.len(), 3],
            dirs(&r.view_dirs),
        );
        let (c, l, v, k) = (
            m.clusters().len(),
            r.light_dirs.len(),
            r.view_dirs.len(),
            r.npca,
        );
        let half = |values: &[f32]| {
            (
                Dtype::F16,
                le_bytes(values, |x| half::f16::from_f32(x).to_le_bytes()),
            )
        };
        let (dt, data) = match precision {
            ResidualPrecision::F32 => (Dtype::F32, le_bytes(&r.mean, f32::to_le_bytes)),
            ResidualPrecision::F16 | ResidualPrecision::I8 => half(&r.mean),
        };
        put("residual_mean", dt, vec![c, l, v, 3], data);
        // Components, shaped `[.., L, V, 3]` (`lead` leading dimensions); at I8 with
        // their exponents, shaped `[.., L]`.
        let mut put_components = |values: &[f32], lead: Vec<usize>| {
            let shape = |tail: &[usize]| [lead.as_slice(), tail].concat();
            match precision {
                ResidualPrecision::F32 => put(
                    "residual_components",
                    Dtype::F32,
                    shape(&[l, v, 3]),
                    le_bytes(values, f32::to_le_bytes),
                ),
                ResidualPrecision::F16 => {
                    let (dt, data) = half(values);
                    put("residual_components", dt, shape(&[l, v, 3]), data);
                }
                ResidualPrecision::I8 => {
                    let (codes, exponents) = quantize_i8(values, v * 3);
                    put("residual_components", Dtype::I8, shape(&[l, v, 3]), codes);
                    put(
                        "residual_component_exponents",
                        Dtype::I8,
                        shape(&[l]),
                        exponents,
                    );
                }
            }
        };
        let counts = cluster_component_counts(m);
        if counts.iter().all(|&n| n == k) {
            put_components(&r.components, vec![c, k]);
            put(
                "residual_coefficients",
                Dtype::F32,
                vec![w * h, k],
                le_bytes(&r.coefficients, f32::to_le_bytes),
            );
        } else {
            // Ragged: each cluster stores only its leading components that are not all
            // zero (a trailing zero component adds nothing whatever its coefficients).
            let d = l * v * 3;
            let components: Vec<f32> = (0..c)
                .flat_map(|ci| &r.components[ci * k * d..(ci * k + counts[ci]) * d])
                .copied()
                .collect();
            let coefficients: Vec<f32> = m
                .texel_cluster()
                .iter()
                .enumerate()
                .flat_map(|(t, &ci)| &r.coefficients[t * k..t * k + counts[ci as usize]])
                .copied()
                .collect();
            let total: usize = counts.iter().sum();
            let n_coef = coefficients.len();
            put_components(&components, vec![total]);
            put(
                "residual_coefficients",
                Dtype::F32,
                vec![n_coef],
                le_bytes(&coefficients, f32::to_le_bytes),
            );
            let counts: Vec<u32> = counts.iter().map(|&n| n as u32).collect();
            put(
                "cluster_npca",
                Dtype::U32,
                vec![c],
                le_bytes(&counts, u32::to_le_bytes),
            );
        }
    }

    let mut metadata = vec![
        ("format", FORMAT.to_string()),
        ("version", VERSION.to_string()),
        ("name", m.name().to_string()),
        ("provenance", m.provenance().to_string()),
        (
            "edited",
            if m.edited() { "true" } else { "false" }.to_string(),
        ),
        ("width", m.width().to_string()),
        ("height", m.height().to_string()),
        ("clusters", m.clusters().len().to_string()),
        ("npca", m.npca().to_string()),
    ];
    if m.edited() {
        let list: Vec<String> = m.edited_clusters().iter().map(|c| c.to_string()).collect();
        metadata.push(("edited_clusters", list.join(",")));
    }
    container::encode(&metadata, &tensors)
}

/// Per cluster, how many leading components the file must store: one past the last
/// component that is not all zero in the table or in a coefficient of the cluster's
/// texels (the fitter's per-cluster choice of N_PCA, and `fit::budget`'s trimming,
/// leave the rest zero in both, so dropping them loses nothing; a cluster whose
/// residual was switched off keeps its coefficients and so its components). Empty
/// without a residual.
pub fn cluster_component_counts(m: &SpmmMaterial) -> Vec<usize> {
    let Some(r) = m.residual() else {
        return Vec::new();
    };
    let (clusters, k) = (m.clusters().len(), r.npca);
    let d = r.light_dirs.len() * r.view_dirs.len() * 3;
    let mut used = vec![false; clusters * k];
    for (t, &c) in m.texel_cluster().iter().enumerate() {
        for (kk, x) in r.coefficients[t * k..(t + 1) * k].iter().enumerate() {
            used[c as usize * k + kk] |= *x != 0.0;
        }
    }
    (0..clusters)
        .map(|c| {
            (0..k)
                .rev()
                .find(|&kk| {
                    let at = (c * k + kk) * d;
                    used[c * k + kk] || r.components[at..at + d].iter().any(|x| *x != 0.0)
                })
                .map_or(0, |kk| kk + 1)
        })
        .collect()
}

const KNOWN_TENSORS: [&str; 15] = [
    "texel_cluster",
    "cluster_basis_offsets",
    "basis_model",
    "basis_params",
    "basis_normal",
    "weight_offsets",
    "weight_basis",
    "weight_rgb",
    "light_dirs",
    "view_dirs",
    "residual_mean",
    "residual_components",
    "residual_coefficients",
    "cluster_npca",
    "residual_component_exponents",
];

/// The validated contents of one tensor, typed.
struct Reader<'a> {
    st: SafeTensors<'a>,
}

impl<'a> Reader<'a> {
    fn view(
        &self,
        name: &'static str,
        dtypes: &[Dtype],
        expected: &[Option<usize>],
    ) -> Result<(Dtype, Vec<usize>, &'a [u8]), PackErrorKind> {
        let t = self
            .st
            .tensor(name)
            .map_err(|_| ContainerError::MissingTensor(name))?;
        if !dtypes.contains(&t.dtype()) {
            let expected = match dtypes {
                [one] => dtype_name(*one),
                [_, _] => "F16 or F32",
                _ => "F16, F32 or I8",
            };
            return Err(ContainerError::Dtype {
                name,
                found: format!("{:?}", t.dtype()),
                expected,
            }
            .into());
        }
        let shape = t.shape().to_vec();
        let matches = shape.len() == expected.len()
            && shape
                .iter()
                .zip(expected)
                .all(|(s, e)| e.is_none_or(|e| e == *s));
        if !matches {
            let expected: Vec<usize> = expected.iter().map(|e| e.unwrap_or(0)).collect();
            return Err(ContainerError::Shape {
                name,
                found: shape,
                expected: format!("{expected:?}"),
            }
            .into());
        }
        Ok((t.dtype(), shape, t.data()))
    }
}

fn u32s(data: &[u8]) -> Vec<u32> {
    data.chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}
fn u16s(data: &[u8]) -> Vec<u16> {
    data.chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect()
}
fn f32s(data: &[u8]) -> Vec<f32> {
    data.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}
fn f64s(data: &[u8]) -> Vec<f64> {
    data.chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8")))
        .collect()
}
fn table_f32(dtype: Dtype, data: &[u8]) -> Vec<f32> {
    match dtype {
        Dtype::F16 => data
            .chunks_exact(2)
            .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect(),
        _ => f32s(data),
    }
}

fn meta_usize(
    meta: &std::collections::HashMap<String, String>,
    key: &'static str,
    max: usize,
) -> Result<usize, PackErrorKind> {
    let raw = meta
        .get(key)
        .ok_or_else(|| ContainerError::missing_metadata(key))?;
    let v: usize = raw.parse().map_err(|_| ContainerError::Metadata {
        key,
        problem: format!("`{raw}` is not a count"),
    })?;
    if v > max {
        return Err(ContainerError::Metadata {
            key,
            problem: format!("{v} exceeds the limit {max}"),
        }
        .into());
    }
    Ok(v)
}

/// Parses and validates pack bytes (see `read_pack`); also used by the fuzz tests.
pub fn decode_pack(bytes: &[u8]) -> Result<SpmmMaterial, PackErrorKind> {
    let opened = container::open(bytes, FORMAT, VERSION)?;
    let container::Opened {
        tensors: st,
        metadata: meta,
    } = opened;
    let text = |key: &'static str| {
        meta.get(key)
            .cloned()
            .ok_or_else(|| ContainerError::missing_metadata(key))
    };
    let name = text("name")?;
    let provenance = text("provenance")?;
    let edited = match text("edited")?.as_str() {
        "true" => true,
        "false" => false,
        other => {
            return Err(ContainerError::Metadata {
                key: "edited",
                problem: format!("`{other}`, expected true or false"),
            }
            .into());
        }
    };
    let width = meta_usize(&meta, "width", 16384)?;
    let height = meta_usize(&meta, "height", 16384)?;
    let n_clusters = meta_usize(&meta, "clusters", 1 << 20)?;
    let npca = meta_usize(&meta, "npca", 4096)?;
    for name in st.names() {
        if !KNOWN_TENSORS.contains(&name) {
            return Err(ContainerError::UnknownTensor {
                name: name.to_string(),
                format: FORMAT_NOUN,
                version: VERSION,
            }
            .into());
        }
    }

    let r = Reader { st };
    let texels = width * height;
    let (_, _, data) = r.view("texel_cluster", &[Dtype::U32], &[Some(height), Some(width)])?;
    let texel_cluster = u32s(data);
    let (_, _, data) = r.view(
        "cluster_basis_offsets",
        &[Dtype::U32],
        &[Some(n_clusters + 1)],
    )?;
    let cluster_offsets = u32s(data);
    let (_, shape, data) = r.view("basis_model", &[Dtype::U8], &[None])?;
    let n_bases = shape[0];
    let models = data.to_vec();
    let (_, _, data) = r.view(
        "basis_params",
        &[Dtype::F64],
        &[Some(n_bases), Some(PARAM_COLUMNS)],
    )?;
    let params = f64s(data);
    let (_, _, data) = r.view("basis_normal", &[Dtype::F64], &[Some(n_bases), Some(3)])?;
    let normals = f64s(data);

    if cluster_offsets.first() != Some(&0)
        || cluster_offsets.last().map(|&v| v as usize) != Some(n_bases)
    {
        return Err(PackErrorKind::ClusterOffsets(format!(
            "must start at 0 and end at the basis count {n_bases}, found {:?} .. {:?}",
            cluster_offsets.first(),
            cluster_offsets.last()
        )));
    }
    if let Some(i) = cluster_offsets.windows(2).position(|w| w[1] < w[0]) {
        return Err(PackErrorKind::ClusterOffsets(format!(
            "element {} decreases",
            i + 1
        )));
    }
    let mut bases = Vec::with_capacity(n_bases);
    for i in 0..n_bases {
        let model = *BrdfModel::ALL
            .get(usize::from(models[i]))
            .ok_or(PackErrorKind::ModelId {
                index: i,
                value: models[i],
            })?;
        let row = &params[i * PARAM_COLUMNS..(i + 1) * PARAM_COLUMNS];
        let used = model.param_specs().len();
        // Garbage in an unused column would hide a model id written wrongly.
        if let Some(column) =
            (used..PARAM_COLUMNS).find(|&k| row[k] != 0.0 || row[k].is_sign_negative())
        {
            return Err(PackErrorKind::UnusedParam {
                index: i,
                column,
                value: row[column],
                model: model.name(),
                used,
            });
        }
        let named: Vec<(&str, f64)> = model
            .param_specs()
            .iter()
            .map(|s| s.name)
            .zip(row.iter().copied())
            .collect();
        let brdf = AnalyticBrdf::new(model, &named)
            .map_err(|source| PackErrorKind::Basis { index: i, source })?;
        let n = DVec3::from_slice(&normals[i * 3..i * 3 + 3]);
        bases.push(
            BasisFunction::new(brdf, n)
                .map_err(|source| PackErrorKind::Basis { index: i, source })?,
        );
    }
    let clusters: Vec<Cluster> = cluster_offsets
        .windows(2)
        .map(|w| Cluster {
            bases: bases[w[0] as usize..w[1] as usize].to_vec(),
        })
        .collect();

    let (_, _, data) = r.view("weight_offsets", &[Dtype::U32], &[Some(texels + 1)])?;
    let offsets = u32s(data);
    let (_, shape, data) = r.view("weight_basis", &[Dtype::U16], &[None])?;
    let nnz = shape[0];
    let basis = u16s(data);
    let (_, _, data) = r.view("weight_rgb", &[Dtype::F32], &[Some(nnz), Some(3)])?;
    let rgb: Vec<[f32; 3]> = f32s(data)
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();

    let has_residual = KNOWN_TENSORS[8..].iter().any(|n| r.st.tensor(n).is_ok());
    let residual = if has_residual {
        let (_, shape, data) = r.view("light_dirs", &[Dtype::F64], &[None, Some(3)])?;
        let light_dirs: Vec<DVec3> = f64s(data).chunks_exact(3).map(DVec3::from_slice).collect();
        let l = shape[0];
        let (_, shape, data) = r.view("view_dirs", &[Dtype::F64], &[None, Some(3)])?;
        let view_dirs: Vec<DVec3> = f64s(data).chunks_exact(3).map(DVec3::from_slice).collect();
        let v = shape[0];
        let halves = [Dtype::F16, Dtype::F32];
        let (dt, _, data) = r.view(
            "residual_mean",
            &halves,
            &[Some(n_clusters), Some(l), Some(v), Some(3)],
        )?;
        let mean = table_f32(dt, data);
        let (components, coefficients) = if r.st.tensor("cluster_npca").is_ok() {
            read_ragged_residual(&r, n_clusters, npca, l, v, &texel_cluster)?
        } else {
            let components = read_components(&r, &[Some(n_clusters), Some(npca)], l, v)?;
            let (_, _, data) = r.view(
                "residual_coefficients",
                &[Dtype::F32],
                &[Some(texels), Some(npca)],
            )?;
            (components, f32s(data))
        };
        Some(Residual {
            light_dirs,
            view_dirs,
            npca,
            mean,
            components,
            coefficients,
        })
    } else {
        if npca != 0 {
            return Err(ContainerError::Metadata {
                key: "npca",
                problem: format!("{npca} but the pack has no residual tensors"),
            }
            .into());
        }
        None
    };

    let mut material = SpmmMaterial::new(
        name,
        provenance,
        width as u32,
        height as u32,
        clusters,
        texel_cluster,
        SparseWeights {
            offsets,
            basis,
            rgb,
        },
        residual,
    )?;
    match (edited, meta.get("edited_clusters")) {
        (false, None) => {}
        // Written before clusters were tracked: any cluster may have changed.
        (true, None) => material.mark_edited(),
        (true, Some(list)) => {
            let clusters = edited_cluster_list(list, n_clusters)?;
            material.mark_clusters_edited(clusters);
        }
        (false, Some(_)) => {
            return Err(ContainerError::Metadata {
                key: "edited_clusters",
                problem: "present in a pack whose `edited` is false".into(),
            }
            .into());
        }
    }
    Ok(material)
}

/// The ragged residual (docs/formats/spmm.md, "Per-cluster N_PCA"): `cluster_npca`
/// components per cluster, stored one cluster after the other, and per texel its
/// cluster's count of coefficients; expanded to the padded in-memory layout
/// [C, npca, L, V, 3] and [T, npca] with zeros, so every reader of a material sees
/// one layout.
fn read_ragged_residual(
    r: &Reader,
    n_clusters: usize,
    npca: usize,
    l: usize,
    v: usize,
    texel_cluster: &[u32],
) -> Result<(Vec<f32>, Vec<f32>), PackErrorKind> {
    let (_, _, data) = r.view("cluster_npca", &[Dtype::U32], &[Some(n_clusters)])?;
    let counts = u32s(data);
    if let Some((c, &n)) = counts.iter().enumerate().find(|(_, n)| **n as usize > npca) {
        return Err(PackErrorKind::Ragged(format!(
            "tensor `cluster_npca`[{c}] = {n}: more than the metadata `npca` = {npca}"
        )));
    }
    let total: usize = counts.iter().map(|&n| n as usize).sum();
    let stored = read_components(r, &[Some(total)], l, v)?;
    if let Some(i) = stored.iter().position(|x| !x.is_finite()) {
        return Err(PackErrorKind::Ragged(format!(
            "tensor `residual_components`[{i}] = {} is not finite",
            stored[i]
        )));
    }
    let d = l * v * 3;
    let mut components = vec![0.0f32; n_clusters * npca * d];
    let mut at = 0;
    for (c, &n) in counts.iter().enumerate() {
        let n = n as usize;
        components[c * npca * d..(c * npca + n) * d].copy_from_slice(&stored[at..at + n * d]);
        at += n * d;
    }
    // Texel clusters are checked against C only when the material is built.
    let count_of = |t: usize| {
        counts
            .get(texel_cluster[t] as usize)
            .map_or(0, |&n| n as usize)
    };
    let expected: usize = (0..texel_cluster.len()).map(count_of).sum();
    let (_, _, data) = r.view("residual_coefficients", &[Dtype::F32], &[Some(expected)])?;
    let stored = f32s(data);
    let mut coefficients = vec![0.0f32; texel_cluster.len() * npca];
    let mut at = 0;
    for t in 0..texel_cluster.len() {
        let n = count_of(t);
        coefficients[t * npca..t * npca + n].copy_from_slice(&stored[at..at + n]);
        at += n;
    }
    Ok((components, coefficients))
}

/// `residual_components`, shaped `lead` then `[L, V, 3]`, as f32: F16 and F32 as
/// stored, I8 decoded with `residual_component_exponents` (shaped `lead` then `[L]`),
/// which must be present exactly when the components are I8.
fn read_components(
    r: &Reader,
    lead: &[Option<usize>],
    l: usize,
    v: usize,
) -> Result<Vec<f32>, PackErrorKind> {
    let shape = |tail: &[usize]| -> Vec<Option<usize>> {
        lead.iter()
            .copied()
            .chain(tail.iter().map(|&n| Some(n)))
            .collect()
    };
    let (dt, _, data) = r.view(
        "residual_components",
        &[Dtype::F16, Dtype::F32, Dtype::I8],
        &shape(&[l, v, 3]),
    )?;
    let has_exponents = r.st.tensor("residual_component_exponents").is_ok();
    match (dt, has_exponents) {
        (Dtype::I8, true) => {
            let (_, _, exponents) =
                r.view("residual_component_exponents", &[Dtype::I8], &shape(&[l]))?;
            dequantize_i8(data, exponents, v * 3)
        }
        (Dtype::I8, false) => {
            Err(ContainerError::MissingTensor("residual_component_exponents").into())
        }
        (_, true) => Err(PackErrorKind::Quantized(
            "tensor `residual_component_exponents` is present but `residual_components` \
             is not I8"
                .into(),
        )),
        (dt, false) => Ok(table_f32(dt, data)),
    }
}

/// The `edited_clusters` metadata: comma-separated cluster indices below `clusters`
/// (empty: an edit that changed no cluster's mixture, such as a residual switched off).
fn edited_cluster_list(list: &str, clusters: usize) -> Result<Vec<usize>, PackErrorKind> {
    if list.is_empty() {
        return Ok(Vec::new());
    }
    list.split(',')
        .map(|item| match item.parse::<usize>() {
            Ok(c) if c < clusters => Ok(c),
            _ => Err(ContainerError::Metadata {
                key: "edited_clusters",
                problem: format!("`{item}` is not a cluster index below {clusters}"),
            }
            .into()),
        })
        .collect()
}

/// The precision a pack's residual tables were stored in (F32 when it has none).
pub fn residual_precision(bytes: &[u8]) -> ResidualPrecision {
    let Ok(st) = SafeTensors::deserialize(bytes) else {
        return ResidualPrecision::F32;
    };
    let dtype = |name| st.tensor(name).ok().map(|t| t.dtype());
    match dtype("residual_mean") {
        Some(Dtype::F16) if dtype("residual_components") == Some(Dtype::I8) => {
            ResidualPrecision::I8
        }
        Some(Dtype::F16) => ResidualPrecision::F16,
        _ => ResidualPrecision::F32,
    }
}

/// Bytes taken by each tensor of a pack, and by the header, for `meso pack info`.
pub fn tensor_sizes(bytes: &[u8]) -> Result<Vec<(String, usize)>, PackErrorKind> {
    let invalid = |e: safetensors::SafeTensorError| ContainerError::Invalid(e.to_string());
    let (header_len, _) = SafeTensors::read_metadata(bytes).map_err(invalid)?;
    let mut sizes: Vec<(String, usize)> = vec![("(header)".into(), 8 + header_len)];
    let st = SafeTensors::deserialize(bytes).map_err(invalid)?;
    let mut tensors: Vec<(String, usize)> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| (n, v.data().len()))
        .collect();
    tensors.sort();
    sizes.extend(tensors);
    Ok(sizes)
}
