//! Ashikhmin-Shirley anisotropic Phong specular BRDF (Ashikhmin & Shirley 2000, eq. 4
//! as docs/brdf.md writes it, with Schlick's Fresnel) and its half-vector sampling
//! (their eq. 9-10). The exponent e = (nu h.x^2 + nv h.y^2)/(h.x^2 + h.y^2) is taken as
//! a ratio of tangential parts; at h = n the spec's limit cos_h^e = 1 applies.

use std::f64::consts::PI;

use glam::{DVec2, DVec3};

use super::{BrdfError, BrdfModel, validate, warp};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AshikhminShirley {
    nu: f64,
    nv: f64,
    rs: f64,
}

impl AshikhminShirley {
    /// Exponents `nu`, `nv` in [1, 1e5], specular reflectance `rs` in [0, 1].
    pub fn new(nu: f64, nv: f64, rs: f64) -> Result<Self, BrdfError> {
        let m = BrdfModel::AshikhminShirley;
        Ok(Self {
            nu: validate(m, 0, nu)?,
            nv: validate(m, 1, nv)?,
            rs: validate(m, 2, rs)?,
        })
    }

    pub fn nu(&self) -> f64 {
        self.nu
    }

    pub fn nv(&self) -> f64 {
        self.nv
    }

    pub fn rs(&self) -> f64 {
        self.rs
    }

    /// cos_h^e with e = (nu hx^2 + nv hy^2)/(hx^2 + hy^2); 1 at h = n.
    #[inline]
    fn cos_h_pow_e(&self, h: DVec3) -> f64 {
        let t = h.x * h.x + h.y * h.y;
        if t == 0.0 {
            return 1.0;
        }
        let e = (self.nu * h.x * h.x + self.nv * h.y * h.y) / t;
        (e * warp::ln_cos(h)).exp()
    }

    #[inline]
    fn norm(&self) -> f64 {
        ((self.nu + 1.0) * (self.nv + 1.0)).sqrt()
    }

    #[inline]
    pub(super) fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        // wi.h = |wi + wo|/2 > 0 above the horizon: symmetric, no cancellation (warp.rs).
        let half = warp::HalfVector::new(wi, wo);
        self.norm() / (8.0 * PI) * self.cos_h_pow_e(half.h) / (half.cos_d * wi.z.max(wo.z))
            * warp::schlick(self.rs, half.one_minus_cos_d)
    }

    /// phi = atan2(sqrt(nu+1) sin 2 pi u, sqrt(nv+1) cos 2 pi u),
    /// cos theta_h = (1 - u')^(1/(e + 1)) with e = nu cos^2 phi + nv sin^2 phi.
    #[inline]
    pub(super) fn sample_half(&self, u: DVec2) -> DVec3 {
        let psi = 2.0 * PI * u.y;
        let phi = ((self.nu + 1.0).sqrt() * psi.sin()).atan2((self.nv + 1.0).sqrt() * psi.cos());
        let (sin_p, cos_p) = phi.sin_cos();
        let e = self.nu * cos_p * cos_p + self.nv * sin_p * sin_p;
        let cos_t = (1.0 - u.x).powf(1.0 / (e + 1.0));
        warp::spherical(cos_t, phi)
    }

    /// p(h) = sqrt((nu+1)(nv+1))/(2 pi) cos_h^e.
    #[inline]
    pub(super) fn pdf_half(&self, h: DVec3) -> f64 {
        self.norm() / (2.0 * PI) * self.cos_h_pow_e(h)
    }
}
