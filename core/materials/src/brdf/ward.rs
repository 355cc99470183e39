//! Anisotropic Ward BRDF in its original normalisation (Ward 1992, eq. 5 as docs/brdf.md
//! writes it; its albedo exceeds 1 at grazing angles, see docs/brdf.md). Sampled with
//! the half-vector warp of Walter 2005 ("Notes on the Ward BRDF", eq. 6-9).

use std::f64::consts::PI;

use glam::{DVec2, DVec3};

use super::{BrdfError, BrdfModel, validate, warp};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ward {
    ax: f64,
    ay: f64,
}

impl Ward {
    /// Roughnesses `ax`, `ay` in [1e-4, 1].
    pub fn new(ax: f64, ay: f64) -> Result<Self, BrdfError> {
        Ok(Self {
            ax: validate(BrdfModel::Ward, 0, ax)?,
            ay: validate(BrdfModel::Ward, 1, ay)?,
        })
    }

    pub fn ax(&self) -> f64 {
        self.ax
    }

    pub fn ay(&self) -> f64 {
        self.ay
    }

    // The exponent uses the unnormalised sum s = wi + wo: (h.x/ax)^2 + (h.y/ay)^2 over
    // cos_h^2 equals ((s.x/ax)^2 + (s.y/ay)^2) / s.z^2, with no normalisation to round.
    /// ((h.x/ax)^2 + (h.y/ay)^2) / h.z^2 for any positive multiple of h.
    #[inline]
    fn exponent(&self, s: DVec3) -> f64 {
        // Divided through by s.z first: s.z^2 underflows for cosines below 1e-154.
        let r = 1.0 / s.z;
        let (x, y) = (s.x * r / self.ax, s.y * r / self.ay);
        x * x + y * y
    }

    #[inline]
    pub(super) fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        let s = wi + wo;
        // sqrt(cos_i) sqrt(cos_o): the product cos_i cos_o underflows below 1e-154.
        (-self.exponent(s)).exp() / (4.0 * PI * self.ax * self.ay * wi.z.sqrt() * wo.z.sqrt())
    }

    /// phi_h = atan2(ay sin 2 pi u, ax cos 2 pi u), tan^2 theta_h = -ln(1 - u') / A(phi)
    /// with A = cos^2 phi / ax^2 + sin^2 phi / ay^2.
    #[inline]
    pub(super) fn sample_half(&self, u: DVec2) -> DVec3 {
        let psi = 2.0 * PI * u.y;
        let phi = (self.ay * psi.sin()).atan2(self.ax * psi.cos());
        let (sin_p, cos_p) = phi.sin_cos();
        let a = cos_p * cos_p / (self.ax * self.ax) + sin_p * sin_p / (self.ay * self.ay);
        let tan2 = -(-u.x).ln_1p() / a;
        let cos_t = 1.0 / (1.0 + tan2).sqrt();
        warp::spherical(cos_t, phi)
    }

    /// p(h) = exp(-exponent) / (pi ax ay cos_h^3).
    #[inline]
    pub(super) fn pdf_half(&self, h: DVec3) -> f64 {
        let e = (-self.exponent(h)).exp();
        if e == 0.0 {
            return 0.0;
        }
        e / (PI * self.ax * self.ay * h.z * h.z * h.z)
    }
}
