//! Lafortune's generalised cosine lobe, f = s^n with s = cx wi.x wo.x + cy wi.y wo.y +
//! cz wi.z wo.z, 0 where s <= 0 (Lafortune et al. 1997; docs/brdf.md). Sampled as a
//! Phong lobe around the axis (cx wo.x, cy wo.y, cz wo.z), since s = wi . axis. Where
//! s^n exceeds f64's range (|c| ~ 1e3 with n ~ 1e4) it saturates at f64::MAX.

use glam::{DVec2, DVec3};

use super::{BrdfError, BrdfModel, validate, warp};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lafortune {
    c: DVec3,
    n: f64,
}

impl Lafortune {
    /// Weights `cx`, `cy`, `cz` in [-1e3, 1e3], exponent `n` in [0, 1e4].
    pub fn new(cx: f64, cy: f64, cz: f64, n: f64) -> Result<Self, BrdfError> {
        let m = BrdfModel::Lafortune;
        Ok(Self {
            c: DVec3::new(
                validate(m, 0, cx)?,
                validate(m, 1, cy)?,
                validate(m, 2, cz)?,
            ),
            n: validate(m, 3, n)?,
        })
    }

    pub fn cx(&self) -> f64 {
        self.c.x
    }
    pub fn cy(&self) -> f64 {
        self.c.y
    }
    pub fn cz(&self) -> f64 {
        self.c.z
    }
    pub fn n(&self) -> f64 {
        self.n
    }

    #[inline]
    pub(super) fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        // The mean of wi.(c wo) and wo.(c wi) is exactly symmetric in (wi, wo), so
        // reciprocity holds bit for bit even where the three terms cancel. (c.(wi wo)
        // is symmetric too, but measured 2.4x slower in the criterion bench, for
        // code-generation reasons we did not chase.)
        let s = 0.5 * (wi.dot(self.c * wo) + wo.dot(self.c * wi));
        if s <= 0.0 {
            return 0.0;
        }
        let v = s.powf(self.n);
        if v.is_finite() { v } else { f64::MAX }
    }

    /// The lobe axis for a given `wo`, or `None` when it vanishes (then f = 0 and the
    /// sampler falls back to the cosine hemisphere).
    #[inline]
    fn axis(&self, wo: DVec3) -> Option<DVec3> {
        (self.c * wo).try_normalize()
    }

    #[inline]
    pub(super) fn sample(&self, wo: DVec3, u: DVec2) -> DVec3 {
        match self.axis(wo) {
            Some(axis) => warp::phong_lobe(axis, self.n, u),
            None => warp::cosine_hemisphere(u),
        }
    }

    #[inline]
    pub(super) fn pdf(&self, wo: DVec3, wi: DVec3) -> f64 {
        match self.axis(wo) {
            Some(axis) => warp::phong_lobe_pdf(axis, self.n, wi),
            None => warp::cosine_hemisphere_pdf(wi),
        }
    }
}
