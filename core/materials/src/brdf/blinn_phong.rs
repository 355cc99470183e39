//! Normalised Blinn-Phong BRDF, f = (n + 8)/(8 pi) cos_h^n (docs/brdf.md; the
//! normalisation is the usual approximation, so albedo may slightly exceed 1, see
//! docs/brdf.md). Sampled by drawing h with density (n + 1)/(2 pi) cos_h^n.

use std::f64::consts::PI;

use glam::{DVec2, DVec3};

use super::{BrdfError, BrdfModel, validate, warp};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlinnPhong {
    n: f64,
}

impl BlinnPhong {
    /// Exponent `n` in [0, 1e5].
    pub fn new(n: f64) -> Result<Self, BrdfError> {
        Ok(Self {
            n: validate(BrdfModel::BlinnPhong, 0, n)?,
        })
    }

    pub fn n(&self) -> f64 {
        self.n
    }

    #[inline]
    pub(super) fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        let h = warp::HalfVector::new(wi, wo).h;
        (self.n + 8.0) / (8.0 * PI) * self.cos_h_pow(h)
    }

    /// cos_h^n through ln(cos_h) from h's tangential part (exact for n = 0).
    #[inline]
    fn cos_h_pow(&self, h: DVec3) -> f64 {
        if self.n == 0.0 {
            1.0
        } else {
            (self.n * warp::ln_cos(h)).exp()
        }
    }

    #[inline]
    pub(super) fn sample_half(&self, u: DVec2) -> DVec3 {
        warp::phong_lobe(DVec3::Z, self.n, u)
    }

    #[inline]
    pub(super) fn pdf_half(&self, h: DVec3) -> f64 {
        (self.n + 1.0) / (2.0 * PI) * self.cos_h_pow(h)
    }
}
