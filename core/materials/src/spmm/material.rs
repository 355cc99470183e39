//! The SPMM material as the editor edits it: texel grid, clusters with their basis
//! dictionaries, sparse per-texel weights, and an optional residual. Constructed only
//! through `SpmmMaterial::new`, which checks every count, index and value, so code
//! holding one never re-checks. Evaluation at shading points lives elsewhere.

use std::sync::Arc;

use glam::DVec3;

use super::directions::{DirectionTable, DirectionTableError};
use super::view::BasisView;
use crate::brdf::BasisFunction;

/// A cluster's dictionary: the basis functions its texels' weights refer to.
#[derive(Clone, Debug, PartialEq)]
pub struct Cluster {
    pub bases: Vec<BasisFunction>,
}

/// Per-texel sparse weights in CSR form: texel `t` has entries
/// `offsets[t]..offsets[t + 1]` of `basis` (index into its cluster's dictionary) and
/// `rgb` (the weight alpha_j(t) per channel).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct SparseWeights {
    pub offsets: Vec<u32>,
    pub basis: Vec<u16>,
    pub rgb: Vec<[f32; 3]>,
}

/// The per-cluster residual eps(c, wi, wo) = mean + sum_k coef_k(t) component_k, each
/// tabulated RGB on `light_dirs` x `view_dirs` (tangent-frame unit vectors, z > 0).
/// Layouts (row-major): `mean` [clusters][lights][views][3], `components`
/// [clusters][npca][lights][views][3], `coefficients` [texels][npca].
#[derive(Clone, Debug, PartialEq)]
pub struct Residual {
    pub light_dirs: Vec<DVec3>,
    pub view_dirs: Vec<DVec3>,
    pub npca: usize,
    pub mean: Vec<f32>,
    pub components: Vec<f32>,
    pub coefficients: Vec<f32>,
}

/// A material's name, provenance and edit marks.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Header {
    pub name: String,
    pub provenance: String,
    pub edited: bool,
    pub edited_clusters: Vec<bool>,
}

/// A validated SPMM material.
#[derive(Clone, Debug, PartialEq)]
pub struct SpmmMaterial {
    name: String,
    provenance: String,
    edited: bool,
    /// Per cluster, whether an edit changed its dictionary or its texels' weights
    /// (its fitted residual no longer matches the mixture); all set for a pack marked
    /// edited before clusters were tracked.
    edited_clusters: Vec<bool>,
    width: u32,
    height: u32,
    clusters: Vec<Cluster>,
    texel_cluster: Vec<u32>,
    weights: SparseWeights,
    /// Shared with prepared data, which lays out a cluster's tables when a ray first
    /// needs them (`spmm::PreparedSpmm`).
    residual: Option<Arc<Residual>>,
    /// Which bases the view shows (mute and solo): never written to a pack.
    view: BasisView,
    /// Interpolation tables of the residual's light and view directions, built once.
    residual_tables: Option<(DirectionTable, DirectionTable)>,
    /// Every value of the residual's tables (mean and components) is a half float
    /// exactly, as in a pack read from a file stored in f16 (the default): prepared
    /// tables then hold the same values in half the bytes.
    residual_half: bool,
}

/// What is wrong with a material; each message names the part, the element index and
/// the rule broken.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SpmmError {
    /// An editor operation that does not fit the material.
    #[error("{0}")]
    Edit(String),
    #[error("texel grid {width}x{height}: both sides must be in 1..=16384")]
    GridSize { width: u32, height: u32 },
    #[error("{part}: {len} elements, expected {expected}")]
    Length {
        part: &'static str,
        len: usize,
        expected: usize,
    },
    #[error("{part}[{index}] = {value}: must be below {bound}")]
    Index {
        part: &'static str,
        index: usize,
        value: u64,
        bound: u64,
    },
    #[error(
        "weight_offsets[{index}] = {value} is below weight_offsets[{prev_index}] = {prev}: offsets must not decrease"
    )]
    Offsets {
        index: usize,
        value: u32,
        prev_index: usize,
        prev: u32,
    },
    #[error("{part}[{index}] = {value} is not finite")]
    NonFinite {
        part: &'static str,
        index: usize,
        value: f32,
    },
    #[error("{part}[{index}] = {value:?} is not a unit vector with z > 0 (|v| within 1e-3 of 1)")]
    Direction {
        part: &'static str,
        index: usize,
        value: [f64; 3],
    },
    #[error("cluster {cluster} has {count} basis functions; at most 65536 are addressable")]
    TooManyBases { cluster: usize, count: usize },
    #[error("texel {texel} uses basis {basis} twice")]
    DuplicateBasis { texel: usize, basis: u16 },
    #[error("{part}: {source}")]
    DirectionSet {
        part: &'static str,
        source: DirectionTableError,
    },
}

const MAX_SIDE: u32 = 16384;

fn check_len(part: &'static str, len: usize, expected: usize) -> Result<(), SpmmError> {
    if len == expected {
        Ok(())
    } else {
        Err(SpmmError::Length {
            part,
            len,
            expected,
        })
    }
}

fn check_finite(part: &'static str, values: &[f32]) -> Result<(), SpmmError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(SpmmError::NonFinite {
            part,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

fn check_directions(part: &'static str, dirs: &[DVec3]) -> Result<(), SpmmError> {
    for (index, d) in dirs.iter().enumerate() {
        if !d.is_finite() || (d.length() - 1.0).abs() > 1e-3 || d.z <= 0.0 {
            return Err(SpmmError::Direction {
                part,
                index,
                value: d.to_array(),
            });
        }
    }
    Ok(())
}

/// The texel grid, the cluster map and the CSR weights' invariants (`SpmmMaterial::new`).
fn check_mixture(
    width: u32,
    height: u32,
    clusters: &[Cluster],
    texel_cluster: &[u32],
    weights: &SparseWeights,
) -> Result<(), SpmmError> {
    if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
        return Err(SpmmError::GridSize { width, height });
    }
    let texels = width as usize * height as usize;
    check_len("texel_cluster", texel_cluster.len(), texels)?;
    if clusters.is_empty() {
        return Err(SpmmError::Length {
            part: "clusters",
            len: 0,
            expected: 1,
        });
    }
    for (cluster, c) in clusters.iter().enumerate() {
        if c.bases.len() > usize::from(u16::MAX) + 1 {
            return Err(SpmmError::TooManyBases {
                cluster,
                count: c.bases.len(),
            });
        }
    }
    for (index, &c) in texel_cluster.iter().enumerate() {
        if c as usize >= clusters.len() {
            return Err(SpmmError::Index {
                part: "texel_cluster",
                index,
                value: c.into(),
                bound: clusters.len() as u64,
            });
        }
    }
    check_len("weight_offsets", weights.offsets.len(), texels + 1)?;
    check_len("weight_rgb", weights.rgb.len(), weights.basis.len())?;
    if weights.offsets[0] != 0 {
        return Err(SpmmError::Index {
            part: "weight_offsets",
            index: 0,
            value: weights.offsets[0].into(),
            bound: 1,
        });
    }
    for i in 1..weights.offsets.len() {
        if weights.offsets[i] < weights.offsets[i - 1] {
            return Err(SpmmError::Offsets {
                index: i,
                value: weights.offsets[i],
                prev_index: i - 1,
                prev: weights.offsets[i - 1],
            });
        }
    }
    let nnz = weights.basis.len();
    check_len(
        "weight entries (last weight_offsets)",
        weights.offsets[texels] as usize,
        nnz,
    )?;
    for t in 0..texels {
        let dictionary = clusters[texel_cluster[t] as usize].bases.len();
        let range = weights.offsets[t] as usize..weights.offsets[t + 1] as usize;
        for (k, &b) in weights.basis[range.clone()].iter().enumerate() {
            if usize::from(b) >= dictionary {
                return Err(SpmmError::Index {
                    part: "weight_basis",
                    index: range.start + k,
                    value: b.into(),
                    bound: dictionary as u64,
                });
            }
            if weights.basis[range.start..range.start + k].contains(&b) {
                return Err(SpmmError::DuplicateBasis { texel: t, basis: b });
            }
        }
    }
    check_finite("weight_rgb", weights.rgb.as_flattened())?;
    Ok(())
}

/// The residual's directions, table sizes and values (`SpmmMaterial::new`).
fn check_residual(r: &Residual, clusters: usize, texels: usize) -> Result<(), SpmmError> {
    check_directions("light_dirs", &r.light_dirs)?;
    check_directions("view_dirs", &r.view_dirs)?;
    let table = r.light_dirs.len() * r.view_dirs.len() * 3;
    check_len("residual_mean", r.mean.len(), clusters * table)?;
    check_len(
        "residual_components",
        r.components.len(),
        clusters * r.npca * table,
    )?;
    check_len(
        "residual_coefficients",
        r.coefficients.len(),
        texels * r.npca,
    )?;
    check_finite("residual_mean", &r.mean)?;
    check_finite("residual_components", &r.components)?;
    check_finite("residual_coefficients", &r.coefficients)?;
    Ok(())
}

impl SpmmMaterial {
    /// Checks every invariant: grid size, one cluster id per texel and in range, CSR
    /// offsets starting at 0, non-decreasing and ending at the entry count, basis
    /// indices within the texel's cluster dictionary and not repeated, finite weights,
    /// and a residual whose tables match the cluster, direction and texel counts.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        name: String,
        provenance: String,
        width: u32,
        height: u32,
        clusters: Vec<Cluster>,
        texel_cluster: Vec<u32>,
        weights: SparseWeights,
        residual: Option<Residual>,
    ) -> Result<Self, SpmmError> {
        check_mixture(width, height, &clusters, &texel_cluster, &weights)?;
        if let Some(r) = &residual {
            check_residual(r, clusters.len(), width as usize * height as usize)?;
        }
        let table = |part, dirs: &[DVec3]| {
            DirectionTable::new(dirs).map_err(|source| SpmmError::DirectionSet { part, source })
        };
        let residual_tables = match &residual {
            Some(r) => Some((
                table("light_dirs", &r.light_dirs)?,
                table("view_dirs", &r.view_dirs)?,
            )),
            None => None,
        };
        Ok(Self {
            name,
            provenance,
            edited: false,
            edited_clusters: vec![false; clusters.len()],
            width,
            height,
            clusters,
            texel_cluster,
            weights,
            residual_half: residual.as_ref().is_some_and(|r| {
                let exact = |v: &[f32]| v.iter().all(|&x| half::f16::from_f32(x).to_f32() == x);
                exact(&r.mean) && exact(&r.components)
            }),
            residual: residual.map(Arc::new),
            residual_tables,
            view: BasisView::default(),
        })
    }

    /// What a pack stores beside the mixture and the residual (`delta.rs` records it).
    pub(super) fn header(&self) -> Header {
        Header {
            name: self.name.clone(),
            provenance: self.provenance.clone(),
            edited: self.edited,
            edited_clusters: self.edited_clusters.clone(),
        }
    }

    /// This material with its header, dictionary, weights, residual and view replaced
    /// (same grid and cluster map), checked as `new` checks them. A residual shared with
    /// this one is not copied, and its direction tables are reused.
    pub(super) fn with_parts(
        &self,
        header: Header,
        clusters: Vec<Cluster>,
        weights: SparseWeights,
        residual: Option<Arc<Residual>>,
        view: BasisView,
    ) -> Result<Self, SpmmError> {
        check_mixture(
            self.width,
            self.height,
            &clusters,
            &self.texel_cluster,
            &weights,
        )?;
        check_len(
            "edited_clusters",
            header.edited_clusters.len(),
            clusters.len(),
        )?;
        let same = match (&residual, &self.residual) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            (None, None) => true,
            _ => false,
        };
        let (residual_tables, residual_half) = if same {
            (self.residual_tables.clone(), self.residual_half)
        } else {
            let fresh = Self::new(
                String::new(),
                String::new(),
                self.width,
                self.height,
                clusters.clone(),
                self.texel_cluster.clone(),
                weights.clone(),
                residual.as_deref().cloned(),
            )?;
            (fresh.residual_tables, fresh.residual_half)
        };
        Ok(Self {
            name: header.name,
            provenance: header.provenance,
            edited: header.edited,
            edited_clusters: header.edited_clusters,
            width: self.width,
            height: self.height,
            clusters,
            texel_cluster: self.texel_cluster.clone(),
            weights,
            residual,
            residual_tables,
            residual_half,
            view,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    pub fn provenance(&self) -> &str {
        &self.provenance
    }
    /// Replaces how the material was made (a tool that derives one pack from another
    /// appends what it did).
    pub fn set_provenance(&mut self, provenance: String) {
        self.provenance = provenance;
    }
    /// Whether the material was changed in the editor since it was made.
    pub fn edited(&self) -> bool {
        self.edited
    }
    /// Marks the material edited, every cluster with it (which ones changed is not
    /// known: the conservative answer for the residual notice).
    pub fn mark_edited(&mut self) {
        self.edited = true;
        self.edited_clusters.fill(true);
    }
    /// Whether an edit changed cluster `c`'s dictionary or weights since the material
    /// was made (false for a cluster that does not exist).
    pub fn cluster_edited(&self, c: usize) -> bool {
        self.edited_clusters.get(c).copied().unwrap_or(false)
    }
    /// The clusters `cluster_edited` says were changed, in order.
    pub fn edited_clusters(&self) -> Vec<usize> {
        (0..self.edited_clusters.len())
            .filter(|&c| self.edited_clusters[c])
            .collect()
    }
    /// Marks the material edited and these clusters (indices checked by the caller)
    /// changed, keeping the clusters marked before.
    pub fn mark_clusters_edited(&mut self, clusters: impl IntoIterator<Item = usize>) {
        self.edited = true;
        for c in clusters {
            self.edited_clusters[c] = true;
        }
    }
    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn clusters(&self) -> &[Cluster] {
        &self.clusters
    }
    pub fn texel_cluster(&self) -> &[u32] {
        &self.texel_cluster
    }
    pub fn weights(&self) -> &SparseWeights {
        &self.weights
    }
    pub fn residual(&self) -> Option<&Residual> {
        self.residual.as_deref()
    }
    pub(crate) fn shared_residual(&self) -> Option<&Arc<Residual>> {
        self.residual.as_ref()
    }
    pub fn residual_tables(&self) -> Option<&(DirectionTable, DirectionTable)> {
        self.residual_tables.as_ref()
    }
    /// True when the residual's tables hold only half floats (`prepare` then keeps
    /// them as such).
    pub(crate) fn residual_is_half(&self) -> bool {
        self.residual_half
    }
    /// Which bases the view shows; a pack file never holds it.
    pub fn view(&self) -> &BasisView {
        &self.view
    }
    pub(super) fn set_view(&mut self, view: BasisView) {
        self.view = view;
    }
    /// PCA terms stored per cluster (0 without a residual).
    pub fn npca(&self) -> usize {
        self.residual.as_ref().map_or(0, |r| r.npca)
    }

    /// The weight entries of texel `t` (row-major index): (basis index, RGB weight).
    pub fn texel_weights(&self, t: usize) -> impl Iterator<Item = (u16, [f32; 3])> + '_ {
        let range = self.weights.offsets[t] as usize..self.weights.offsets[t + 1] as usize;
        self.weights.basis[range.clone()]
            .iter()
            .copied()
            .zip(self.weights.rgb[range].iter().copied())
    }
}
