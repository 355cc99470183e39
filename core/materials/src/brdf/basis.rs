//! The SPMM basis function rho_j(wi, wo) = f_j(R_j wi, R_j wo) max(0, n_j . wi)
//! (Silva & Santos 2013 eq. 2; docs/brdf.md): an analytic BRDF tilted onto its own
//! normal n_j, foreshortening cosine included. Vectors are in the texel's tangent frame.

use glam::DVec3;

use super::{AnalyticBrdf, BrdfError, Frame};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BasisFunction {
    brdf: AnalyticBrdf,
    /// As given (unit within 1e-3), so a pack saves exactly what it loaded.
    normal: DVec3,
    frame: Frame,
}

impl BasisFunction {
    /// `normal` must be finite, unit within 1e-3 (it is then renormalised) and in the
    /// upper hemisphere of the tangent frame (z > 0).
    pub fn new(brdf: AnalyticBrdf, normal: DVec3) -> Result<Self, BrdfError> {
        let len = normal.length();
        if !normal.is_finite() || (len - 1.0).abs() > 1e-3 || normal.z <= 0.0 {
            return Err(BrdfError::BadNormal {
                normal: normal.to_array(),
            });
        }
        Ok(Self {
            brdf,
            normal,
            frame: Frame::from_normal_spmm(normal / len),
        })
    }

    pub fn brdf(&self) -> &AnalyticBrdf {
        &self.brdf
    }

    /// The normal as given; `frame().z` is its normalised form used for shading.
    pub fn normal(&self) -> DVec3 {
        self.normal
    }

    pub fn frame(&self) -> &Frame {
        &self.frame
    }

    /// rho_j(wi, wo) with unit `wi`, `wo` in the texel's tangent frame.
    #[inline]
    pub fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        let cos = self.frame.z.dot(wi);
        if cos <= 0.0 {
            return 0.0;
        }
        self.brdf
            .eval(self.frame.to_local(wi), self.frame.to_local(wo))
            * cos
    }
}
