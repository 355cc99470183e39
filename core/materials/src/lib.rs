//! Meso's materials layer: everything a material is, with no renderer, window, GPU or
//! command line above it. The closed dictionary of analytic BRDFs (`brdf`), measured
//! MERL tables (`merl`), SPMM packs (`spmm`), BTFs (`btf`), and what they all stand
//! on: linear images (`image`), a fast `atan2` for table lookups (`angle`), guided
//! CDF inversion (`cdf`), image metrics (`metrics`), replayable randomness
//! (`rng`), the safetensors container of `.spmm` and `.btf` (`container`), atomic
//! writes (`atomic`) and the content hash (`hash`).

pub mod angle;
pub mod atomic;
pub mod brdf;
pub mod btf;
pub mod cdf;
pub mod container;
pub mod hash;
pub mod image;
pub mod merl;
pub mod metrics;
pub mod rng;
pub mod spmm;
pub mod utc;
