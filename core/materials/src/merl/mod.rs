//! Measured isotropic BRDFs in the MERL binary format (Matusik et al. 2003, "A
//! Data-Driven Reflectance Model"): a 90 x 90 x 180 RGB table over Rusinkiewicz's
//! half/difference angles, with the format's per-channel scales. Here: the table type
//! and its errors; `file.rs` reads and writes, `lookup.rs` parametrises and looks up,
//! `sample.rs` importance-samples, `tabulate.rs` tabulates analytic BRDFs.

mod file;
mod lookup;
mod sample;
mod tabulate;

#[cfg(test)]
mod tests;

use std::path::PathBuf;
use std::sync::OnceLock;

use glam::DVec3;

use crate::atomic::AtomicWriteError;

pub use file::FILE_BYTES;
pub use lookup::HalfDiff;
pub use sample::MerlSampler;
pub use tabulate::tabulate;

/// Resolution of theta_h, the half vector's angle from the normal (square-root spaced).
pub const THETA_H_RES: usize = 90;
/// Resolution of theta_d, the angle between `wi` and the half vector (uniform).
pub const THETA_D_RES: usize = 90;
/// Resolution of phi_d over [0, pi) (uniform; reciprocity folds [pi, 2 pi) onto it).
pub const PHI_D_RES: usize = 180;
/// Cells per channel: 90 * 90 * 180.
pub const CELLS: usize = THETA_H_RES * THETA_D_RES * PHI_D_RES;
/// value = stored * SCALE[channel], for red, green, blue (the reference reader's
/// `RED_SCALE`, `GREEN_SCALE`, `BLUE_SCALE`).
pub const SCALE: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];
/// Channel names in file order, for messages.
pub const CHANNELS: [&str; 3] = ["red", "green", "blue"];

/// What is wrong with a MERL table or file.
#[derive(Debug, thiserror::Error)]
pub enum MerlFault {
    #[error("cannot read: {0}")]
    Io(#[source] std::io::Error),
    #[error(
        "is {found} bytes, but a MERL BRDF file is exactly {FILE_BYTES} bytes (three int32 dimensions 90, 90, 180, then 3 x {CELLS} float64)"
    )]
    Size { found: u64 },
    #[error(
        "dimensions are {}, {}, {}; Meso reads only the MERL resolution 90, 90, 180 (theta_h, theta_d, phi_d)",
        found[0], found[1], found[2]
    )]
    Dimensions { found: [i32; 3] },
    #[error("the table has {found} cells, expected {CELLS} (90 x 90 x 180)")]
    CellCount { found: usize },
    #[error(
        "{} channel, cell {cell} (theta_h index {}, theta_d index {}, phi_d index {}; byte offset {}) holds {value}, which is not finite",
        CHANNELS[*channel], cell_indices(*cell).0, cell_indices(*cell).1, cell_indices(*cell).2,
        file::value_offset(*channel, *cell)
    )]
    NonFinite {
        channel: usize,
        cell: usize,
        value: f64,
    },
    #[error(
        "the {} channel holds no data: all {CELLS} of its values are negative (negative marks a cell without a measurement)",
        CHANNELS[*channel]
    )]
    NoData { channel: usize },
    #[error("albedo {albedo:?}: every component must be finite and at least 0")]
    Albedo { albedo: [f64; 3] },
    #[error("cannot write: {0}")]
    Write(#[source] AtomicWriteError),
}

/// A `MerlFault`, with the file it was found in when there is one.
#[derive(Debug, thiserror::Error)]
#[error("{}{fault}", path.as_ref().map(|p| format!("`{}`: ", p.display())).unwrap_or_default())]
pub struct MerlError {
    pub path: Option<PathBuf>,
    pub fault: MerlFault,
}

impl From<MerlFault> for MerlError {
    fn from(fault: MerlFault) -> Self {
        Self { path: None, fault }
    }
}

impl MerlError {
    pub(crate) fn at(path: &std::path::Path, fault: MerlFault) -> Self {
        Self {
            path: Some(path.to_path_buf()),
            fault,
        }
    }
}

/// The cell index of (theta_h, theta_d, phi_d) indices, as the reference reader
/// computes it: `phi_d + theta_d * 180 + theta_h * 180 * 90`.
#[inline]
pub fn cell_index(theta_h: usize, theta_d: usize, phi_d: usize) -> usize {
    phi_d + PHI_D_RES * (theta_d + THETA_D_RES * theta_h)
}

/// The (theta_h, theta_d, phi_d) indices of a cell; the inverse of `cell_index`.
#[inline]
pub fn cell_indices(cell: usize) -> (usize, usize, usize) {
    (
        cell / (PHI_D_RES * THETA_D_RES),
        (cell / PHI_D_RES) % THETA_D_RES,
        cell % PHI_D_RES,
    )
}

/// A measured isotropic BRDF: the MERL table, valid by construction (the right cell
/// count, every value finite, every channel with some data).
///
/// Values are kept as the file stores them, `f64` and unscaled, interleaved RGB per
/// cell: a write reproduces the file bit for bit, and one lookup touches one cache
/// line instead of three. That is 35 MB per material, the size of the file; the
/// scale is applied per lookup. The importance-sampling tables are built on first use.
#[derive(Clone, Debug)]
pub struct MerlBrdf {
    stored: Vec<[f64; 3]>,
    sampler: OnceLock<MerlSampler>,
}

impl MerlBrdf {
    /// A table from stored (unscaled) values, cell-major in `cell_index` order. Checks
    /// the count, finiteness, and that every channel has at least one non-negative value.
    pub fn from_stored(stored: Vec<[f64; 3]>) -> Result<Self, MerlError> {
        if stored.len() != CELLS {
            return Err(MerlFault::CellCount {
                found: stored.len(),
            }
            .into());
        }
        // File order: the whole red block first, so the first fault named is the one a
        // reader of the file meets first.
        for channel in 0..3 {
            if let Some((cell, s)) = stored
                .iter()
                .enumerate()
                .find(|(_, s)| !s[channel].is_finite())
            {
                return Err(MerlFault::NonFinite {
                    channel,
                    cell,
                    value: s[channel],
                }
                .into());
            }
        }
        for channel in 0..3 {
            if !stored.iter().any(|s| s[channel] >= 0.0) {
                return Err(MerlFault::NoData { channel }.into());
            }
        }
        Ok(Self {
            stored,
            sampler: OnceLock::new(),
        })
    }

    /// The stored (unscaled) values of every cell, `cell_index` order; negative = no data.
    pub fn stored(&self) -> &[[f64; 3]] {
        &self.stored
    }

    /// The BRDF value of one cell in 1/sr: stored * `SCALE` per channel, 0 where the
    /// cell has no data (a negative stored value). Never negative.
    #[inline]
    pub fn cell_value(&self, cell: usize) -> DVec3 {
        let s = self.stored[cell];
        // `> 0` also turns a stored -0.0 into +0.0.
        let scaled = |c: usize| if s[c] > 0.0 { s[c] * SCALE[c] } else { 0.0 };
        DVec3::new(scaled(0), scaled(1), scaled(2))
    }

    /// Cells where at least one channel has no data.
    pub fn no_data_cells(&self) -> usize {
        self.stored
            .iter()
            .filter(|s| s.iter().any(|&v| v < 0.0))
            .count()
    }

    /// The importance-sampling tables, built on first use (about 1.5 million lookups).
    pub fn sampler(&self) -> &MerlSampler {
        self.sampler.get_or_init(|| MerlSampler::new(self))
    }

    /// The importance-sampling tables if something has built them.
    pub fn sampler_if_built(&self) -> Option<&MerlSampler> {
        self.sampler.get()
    }

    /// Directional albedo at normal view, integral of f(wi, n) cos(theta_i) over the
    /// hemisphere, per channel: with `wo` on the normal every azimuth of `wi` looks up
    /// the same cells, so a midpoint rule over 8192 rings of equal cos(theta_i) width
    /// is exact for the piecewise-constant table up to the rings a cell edge cuts.
    pub fn albedo_at_normal(&self) -> DVec3 {
        const RINGS: usize = 8192;
        let sum: DVec3 = (0..RINGS)
            .map(|k| {
                let z = (k as f64 + 0.5) / RINGS as f64;
                let wi = DVec3::new((1.0 - z * z).sqrt(), 0.0, z);
                self.eval(wi, DVec3::Z) * z
            })
            .sum();
        // Integral over z in [0, 1] of 2 pi f z dz.
        sum * (2.0 * std::f64::consts::PI / RINGS as f64)
    }
}
