//! residual (in progress)
