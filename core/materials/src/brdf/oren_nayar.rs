//! Oren-Nayar rough diffuse BRDF, the qualitative model of Oren & Nayar 1994 (eq. 30)
//! as docs/brdf.md writes it. Sampled with the cosine-weighted hemisphere.

use std::f64::consts::FRAC_1_PI;

use glam::DVec3;

use super::{BrdfError, BrdfModel, validate};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrenNayar {
    sigma: f64,
    a: f64,
    b: f64,
}

impl OrenNayar {
    /// `sigma` in [0, pi/2] radians.
    pub fn new(sigma: f64) -> Result<Self, BrdfError> {
        let sigma = validate(BrdfModel::OrenNayar, 0, sigma)?;
        let s2 = sigma * sigma;
        Ok(Self {
            sigma,
            a: 1.0 - 0.5 * s2 / (s2 + 0.33),
            b: 0.45 * s2 / (s2 + 0.09),
        })
    }

    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    // cos(phi_i - phi_o) sin(theta_i) sin(theta_o) = wi.x wo.x + wi.y wo.y and
    // sin(alpha) tan(beta) = sin(theta_i) sin(theta_o) / max(cos_i, cos_o), so the B term
    // is B max(0, wi.x wo.x + wi.y wo.y) / max(cos_i, cos_o): no angles, no trigonometry,
    // and no singularity when either direction is the normal (the term is then 0).
    #[inline]
    pub(super) fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        let azimuthal = (wi.x * wo.x + wi.y * wo.y).max(0.0);
        FRAC_1_PI * (self.a + self.b * azimuthal / wi.z.max(wo.z))
    }
}
