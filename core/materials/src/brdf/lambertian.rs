//! Lambertian BRDF, f = 1/pi (docs/brdf.md). The colour lives in the SPMM weights or
//! the material's albedo, not here. Sampled with the cosine-weighted hemisphere.

use std::f64::consts::FRAC_1_PI;

use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Lambertian;

impl Lambertian {
    /// Callers guarantee both directions lie above the horizon.
    #[inline]
    pub(super) fn eval(&self, _wi: DVec3, _wo: DVec3) -> f64 {
        FRAC_1_PI
    }
}
