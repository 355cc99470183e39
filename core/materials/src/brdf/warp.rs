//! Shared sampling warps and half-vector helpers for the BRDF dictionary: cosine-
//! weighted hemisphere (Malley's method), the half-vector to incident-direction change
//! of variables (Jacobian 1 / (4 wo.h), Walter et al. 2007 eq. 14), orthonormal bases.

use std::f64::consts::{FRAC_1_PI, PI};

use glam::{DVec2, DVec3};

/// Cosine-weighted direction on the upper hemisphere (Malley: uniform disk, lifted).
#[inline]
pub fn cosine_hemisphere(u: DVec2) -> DVec3 {
    let r = u.x.sqrt();
    let phi = 2.0 * PI * u.y;
    DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt())
}

#[inline]
pub fn cosine_hemisphere_pdf(wi: DVec3) -> f64 {
    wi.z.max(0.0) * FRAC_1_PI
}

/// A unit direction from its polar cosine and azimuth about +z.
#[inline]
pub fn spherical(cos_theta: f64, phi: f64) -> DVec3 {
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    DVec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
}

/// Mirror `wo` about the half vector `h`; `None` when `wo` lies behind `h`, where the
/// half-vector warp is not one-to-one.
#[inline]
pub fn reflect(wo: DVec3, h: DVec3) -> Option<DVec3> {
    let d = wo.dot(h);
    (d > 0.0).then(|| 2.0 * d * h - wo)
}

/// The half vector of two unit directions above the horizon, with the two cosines
/// the models need. For unit vectors wi.h = wo.h = |wi + wo| / 2 and 1 - wi.h =
/// |wi - wo|^2 / (2 (2 + |wi + wo|)) (from |wi + wo|^2 + |wi - wo|^2 = 4). These forms
/// are exactly symmetric in (wi, wo), so reciprocity holds bit for bit, and neither
/// cancels: the dot product wi.(wi + wo) loses its digits when wi ~ -wo at grazing
/// (1 + wi.wo is tiny), and 1 - wi.h loses them when wi ~ wo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfVector {
    /// normalize(wi + wo); summing first keeps it exact where wi + wo is tiny.
    pub h: DVec3,
    /// wi.h = wo.h.
    pub cos_d: f64,
    /// 1 - wi.h, for Schlick's Fresnel.
    pub one_minus_cos_d: f64,
}

impl HalfVector {
    /// `wi`, `wo` unit with wi + wo != 0 (true whenever both lie above the horizon).
    #[inline]
    pub fn new(wi: DVec3, wo: DVec3) -> Self {
        let s = wi + wo;
        let len = s.length();
        Self {
            h: s / len,
            cos_d: 0.5 * len,
            one_minus_cos_d: (wi - wo).length_squared() / (2.0 * (2.0 + len)),
        }
    }
}

/// Density of `wi` when `h` is drawn with density `pdf_half(h)` and `wi` is `wo`
/// reflected about it: p(wi) = p(h) / (4 wo.h) (Walter et al. 2007, eq. 14).
#[inline]
pub fn half_to_wi_pdf(wo: DVec3, wi: DVec3, pdf_half: impl FnOnce(DVec3) -> f64) -> f64 {
    let half = HalfVector::new(wi, wo);
    if half.h.z <= 0.0 {
        return 0.0;
    }
    pdf_half(half.h) / (4.0 * half.cos_d)
}

/// ln(cos_h) of a unit half vector, accurate everywhere: near the normal it comes
/// from the tangential part, ln cos = ln(1 - t)/2 with t = h.x^2 + h.y^2 (cos_h itself
/// would carry a rounding error that cos_h^n amplifies n-fold, n up to 1e5); near the
/// horizon 1 - t cancels, and ln(h.z) is the accurate form.
#[inline]
pub fn ln_cos(h: DVec3) -> f64 {
    let t = h.x * h.x + h.y * h.y;
    if t < 0.5 {
        0.5 * (-t).ln_1p()
    } else {
        h.z.ln()
    }
}

/// Two unit vectors completing `n` to a right-handed orthonormal basis (Duff et al.
/// 2017, "Building an Orthonormal Basis, Revisited").
#[inline]
pub fn orthonormal_basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// A direction drawn around `axis` with density (n + 1)/(2 pi) cos^n(angle to axis),
/// the Phong lobe; n = 0 is uniform over the hemisphere around `axis`.
#[inline]
pub fn phong_lobe(axis: DVec3, n: f64, u: DVec2) -> DVec3 {
    let cos_a = (1.0 - u.x).powf(1.0 / (n + 1.0));
    let local = spherical(cos_a, 2.0 * PI * u.y);
    let (t, b) = orthonormal_basis(axis);
    t * local.x + b * local.y + axis * local.z
}

#[inline]
pub fn phong_lobe_pdf(axis: DVec3, n: f64, w: DVec3) -> f64 {
    let c = axis.dot(w);
    if c <= 0.0 {
        0.0
    } else {
        (n + 1.0) / (2.0 * PI) * c.powf(n)
    }
}

/// Schlick's Fresnel approximation F = f0 + (1 - f0)(1 - wi.h)^5, given 1 - wi.h
/// (`HalfVector::one_minus_cos_d`, exact where wi ~ h).
#[inline]
pub fn schlick(f0: f64, one_minus_cos_d: f64) -> f64 {
    let m = one_minus_cos_d.clamp(0.0, 1.0);
    let m2 = m * m;
    f0 + (1.0 - f0) * m2 * m2 * m
}
