//! Cook-Torrance microfacet BRDF with the Beckmann distribution, Schlick's Fresnel and
//! the V-cavity masking term (Cook & Torrance 1982; docs/brdf.md). Sampled by drawing
//! h from D(h) cos_h (Walter et al. 2007, eq. 28-29 for Beckmann).

use std::f64::consts::PI;

use glam::{DVec2, DVec3};

use super::{BrdfError, BrdfModel, validate, warp};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CookTorrance {
    m: f64,
    f0: f64,
}

impl CookTorrance {
    /// Beckmann roughness `m` in [1e-4, 1], Fresnel `f0` in [0, 1].
    pub fn new(m: f64, f0: f64) -> Result<Self, BrdfError> {
        Ok(Self {
            m: validate(BrdfModel::CookTorrance, 0, m)?,
            f0: validate(BrdfModel::CookTorrance, 1, f0)?,
        })
    }

    pub fn m(&self) -> f64 {
        self.m
    }

    pub fn f0(&self) -> f64 {
        self.f0
    }

    // tan^2 theta_h is computed as (s.x^2 + s.y^2)/s.z^2 from s = wi + wo rather than
    // (1 - cos_h^2)/cos_h^2, which cancels catastrophically for sharp lobes (m = 1e-4).
    /// Beckmann D(h) = exp(-tan^2 / m^2) / (pi m^2 cos_h^4), for any positive multiple s of h.
    #[inline]
    fn beckmann(&self, s: DVec3) -> f64 {
        let m2 = self.m * self.m;
        let e = (-(s.x * s.x + s.y * s.y) / (s.z * s.z * m2)).exp();
        if e == 0.0 {
            return 0.0;
        }
        let cos_h = s.z / s.length();
        let c2 = cos_h * cos_h;
        e / (PI * m2 * c2 * c2)
    }

    #[inline]
    pub(super) fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        let s = wi + wo;
        let d = self.beckmann(s);
        if d == 0.0 {
            return 0.0;
        }
        // wo.h = wi.h = |wi + wo|/2: symmetric and free of cancellation (warp.rs).
        let half = warp::HalfVector::new(wi, wo);
        let g = 1.0f64
            .min(2.0 * half.h.z * wo.z / half.cos_d)
            .min(2.0 * half.h.z * wi.z / half.cos_d);
        d * warp::schlick(self.f0, half.one_minus_cos_d) * g / (4.0 * wi.z * wo.z)
    }

    /// tan^2 theta_h = -m^2 ln(1 - u), phi_h uniform.
    #[inline]
    pub(super) fn sample_half(&self, u: DVec2) -> DVec3 {
        let tan2 = -self.m * self.m * (-u.x).ln_1p();
        let cos_t = 1.0 / (1.0 + tan2).sqrt();
        warp::spherical(cos_t, 2.0 * PI * u.y)
    }

    #[inline]
    pub(super) fn pdf_half(&self, h: DVec3) -> f64 {
        self.beckmann(h) * h.z
    }
}
