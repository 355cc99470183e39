//! Fitting SPMM materials to BTFs, the pipeline of Wu et al. 2011 as Silva & Santos
//! 2013 (section 3) describe it: k-means of the texels' apparent BRDFs into clusters
//! (`kmeans.rs`), sub-clusters whose means are representatives, a dictionary per
//! cluster fitted to them by nonlinear least squares over each analytic model's
//! parameters and normal (`dictionary.rs`), sparse non-negative RGB weights per texel
//! on the lasso path (`lasso.rs`), and a per-cluster mean + PCA residual
//! (`residual.rs`). `report.rs` measures the result. Deterministic for a seed.

pub mod dictionary;
pub mod kmeans;
pub mod lasso;
pub mod residual;
