//! SPMM materials (Silva & Santos 2013 eq. 1-3, after Wu et al. 2011): per-texel
//! sparse RGB weights over a per-cluster dictionary of analytic basis functions, plus
//! a per-cluster PCA residual tabulated on the BTF's direction sets. `material.rs`
//! holds the model with its invariants; `pack.rs` the `.spmm` file (docs/formats/spmm.md).

mod change;
pub mod components;
mod delta;
pub mod directions;
mod edit;
mod eval;
pub mod lobe_bound;
mod material;
pub mod pack;
mod prepared;
pub mod recipe;
mod texel_mask;
mod view;

#[cfg(any(test, feature = "testing"))]
pub mod testing;
#[cfg(test)]
pub(crate) mod tests;

pub use delta::{DeltaError, PackDelta, Step};
pub use edit::{Contributions, WeightTarget};
pub use eval::TexelGrid;
pub use eval::{EvalSettings, MOVING_NPCA, TexelFilter};
pub use material::{Cluster, Residual, SparseWeights, SpmmError, SpmmMaterial};
pub use prepared::{
    DEFENSIVE_SHARE, PrepareRequest, PreparedBytes, PreparedParts, PreparedResidualParts,
    PreparedSpmm, ResidualCells, defensive_pdf, defensive_sample,
};
pub use texel_mask::{Falloff, TexelMask};
pub use view::BasisView;
