//! The bandwidth transport of Bagher et al. 2013 (Fig. 4, eq. 3-6, 9-11) as pure
//! functions: free-space transport T_d, the reflection operator R = P_x C_-c S B C_c
//! P_i, the weighted per-pixel bandwidth (eq. 5), the screen-space rate (eq. 6), the
//! variance bound's sum (eq. 9, eq. 10 pre-convolved) and the pyramid level (eq. 11).
//!
//! A bandwidth is a vector (spatial, angular) of Nyquist rates (per metre, per radian).
//! Without textures every spectrum here is a segment through the origin (a distant
//! light's lies on the angular axis, an area light's on the spatial axis, and every
//! operator is linear), so a vector is its end point and signs matter through the
//! shears. B band-limits it: Fig. 4 writes the bounding-box min(rho, nu_a); on a
//! segment we clip the segment itself (both components scale by rho / |nu_a|), which
//! is the exact support and keeps a curved diffuse surface under a sharp environment
//! from claiming the environment's frequencies in space. Magnitudes are taken last.

use glam::DVec2;

/// A bandwidth vector: `x` spatial (1/m), `y` angular (1/rad).
pub type Bandwidth = DVec2;

/// Fig. 4: T_d, free-space transport over `d` metres (an angular shear).
pub fn transport(nu: Bandwidth, d: f64) -> Bandwidth {
    DVec2::new(nu.x, nu.y - d * nu.x)
}

/// The cosines below this are taken as this (grazing re-parametrisations would
/// otherwise scale by infinity).
pub const MIN_COS: f64 = 0.05;

/// What eq. 3 needs of one bounce: incident and outgoing cosines, the surface's
/// curvature (1/m) and the material's angular bandwidth for this pair (1/rad).
#[derive(Clone, Copy, Debug)]
pub struct Bounce {
    pub cos_i: f64,
    pub cos_o: f64,
    pub curvature: f64,
    pub rho: f64,
}

/// Eq. 3: R nu = P_x C_-c S B_rho C_c P_i nu, with B clipping the segment (header).
pub fn reflect(nu: Bandwidth, b: &Bounce) -> Bandwidth {
    let cos_i = b.cos_i.max(MIN_COS);
    let cos_o = b.cos_o.max(MIN_COS);
    // P_i: spatial scale by cos(theta_i).
    let mut v = DVec2::new(nu.x * cos_i, nu.y);
    // C_c: spatial shear by the curvature.
    v.x += b.curvature * v.y;
    // B_rho (t = 0): band-limit the angular frequencies.
    if v.y.abs() > b.rho {
        v *= if v.y != 0.0 { b.rho / v.y.abs() } else { 0.0 };
    }
    // S: mirror.
    v.y = -v.y;
    // C_-c.
    v.x -= b.curvature * v.y;
    // P_x: spatial scale by 1 / cos(theta_x).
    v.x /= cos_o;
    v
}

/// Eq. 4: nu^i = T_d' R T_d nu_l, as magnitudes.
pub fn one_bounce(light: Bandwidth, d_light: f64, b: &Bounce, d_eye: f64) -> Bandwidth {
    transport(reflect(transport(light, d_light), b), d_eye).abs()
}

/// Eq. 5: the bandwidths of the sampled paths averaged with weights lambda_i (their
/// energy); zero when no path carries any.
pub fn weighted(paths: &[(f64, Bandwidth)]) -> Bandwidth {
    let total: f64 = paths.iter().map(|p| p.0).sum();
    if total > 0.0 {
        paths.iter().map(|(l, nu)| *l * *nu).sum::<DVec2>() / total
    } else {
        DVec2::ZERO
    }
}

/// Eq. 6: the screen-space rate b_p (samples per pixel) of angular rate `nu_a`, for
/// horizontal and vertical fields of view (radians) over a `width` x `height` image.
pub fn screen_rate(nu_a: f64, fov_x: f64, fov_y: f64, width: u32, height: u32) -> f64 {
    nu_a * (fov_x / width as f64).max(fov_y / height as f64)
}

/// Eq. 11: the pyramid level at which a pixel of rate `b_p` is shaded,
/// min(floor(log2(1 / b_p)), min(log2 W, log2 H)), never below 0 (no sub-pixel level).
pub fn level(b_p: f64, width: u32, height: u32) -> u32 {
    let top = width.min(height).max(1).ilog2();
    // NaN and non-positive rates alike: nothing varies, the coarsest level.
    if b_p.is_nan() || b_p <= 0.0 {
        return top;
    }
    let l = (1.0 / b_p).log2().floor();
    if l <= 0.0 { 0 } else { (l as u32).min(top) }
}

/// One term of eq. 9's sum: (nu_a^i + nu_rho^i) chi_i^2; eq. 10 (pre-convolved
/// illumination) replaces the illumination's rate by the material's: 2 nu_rho chi^2.
pub fn variance_term(nu_light_a: f64, nu_rho: f64, chi: f64, preconvolved: bool) -> f64 {
    let rates = if preconvolved {
        2.0 * nu_rho
    } else {
        nu_light_a + nu_rho
    };
    rates * chi * chi
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn transport_shears_the_angle_by_distance_times_space() {
        let v = transport(DVec2::new(3.0, 1.0), 2.0);
        assert_eq!(v, DVec2::new(3.0, -5.0));
    }

    #[test]
    fn a_flat_mirror_like_bounce_passes_the_angle_up_to_rho() {
        // Distant light of angular rate 10, flat surface, rho 4: the angle is clipped to
        // 4, nothing spatial appears; the eye at 2 m sees angular 4.
        let b = Bounce {
            cos_i: 0.8,
            cos_o: 0.5,
            curvature: 0.0,
            rho: 4.0,
        };
        let nu = one_bounce(DVec2::new(0.0, 10.0), 1e9, &b, 2.0);
        assert!(close(nu.x, 0.0) && close(nu.y, 4.0), "{nu}");
    }

    #[test]
    fn curvature_turns_angle_into_space_and_the_eye_distance_back_into_angle() {
        // Hand computed: nu_l = (0, 2), c = 0.5, rho = 8 (no clipping), cos_o = 0.5,
        // d' = 3. C_c: (1, 2); S: (1, -2); C_-c: (1 + 1, -2) = (2, -2); P_x: (4, -2);
        // T_3: (4, -2 - 12) = (4, -14).
        let b = Bounce {
            cos_i: 1.0,
            cos_o: 0.5,
            curvature: 0.5,
            rho: 8.0,
        };
        let nu = one_bounce(DVec2::new(0.0, 2.0), 0.0, &b, 3.0);
        assert!(close(nu.x, 4.0) && close(nu.y, 14.0), "{nu}");
    }

    #[test]
    fn an_area_light_seen_by_a_diffuse_surface_is_band_limited_in_space_too() {
        // nu_l = (5, 0) at d = 2: (5, -10); P_i 0.5: (2.5, -10); rho = 1 clips the
        // segment by 1/10: (0.25, -1); S (0.25, 1); P_x 1: (0.25, 1); T_4: (0.25, 0).
        let b = Bounce {
            cos_i: 0.5,
            cos_o: 1.0,
            curvature: 0.0,
            rho: 1.0,
        };
        let nu = one_bounce(DVec2::new(5.0, 0.0), 2.0, &b, 4.0);
        assert!(close(nu.x, 0.25) && close(nu.y, 0.0), "{nu}");
        // A Lambertian (rho = 0) reflects no frequency at all.
        let flat = one_bounce(DVec2::new(5.0, 0.0), 2.0, &Bounce { rho: 0.0, ..b }, 4.0);
        assert_eq!(flat, DVec2::ZERO);
    }

    #[test]
    fn eq5_weights_by_energy() {
        let nu = weighted(&[(1.0, DVec2::new(0.0, 2.0)), (3.0, DVec2::new(4.0, 6.0))]);
        assert_eq!(nu, DVec2::new(3.0, 5.0));
        assert_eq!(weighted(&[(0.0, DVec2::ONE)]), DVec2::ZERO);
    }

    #[test]
    fn eq6_and_eq11_on_hand_computed_cases() {
        // 512 x 256, fov 1.0 x 0.5 rad: both 1/512 rad per pixel. nu_a = 64 per rad:
        // b_p = 1/8 -> level 3.
        let b = screen_rate(64.0, 1.0, 0.5, 512, 256);
        assert!(close(b, 0.125), "{b}");
        assert_eq!(level(b, 512, 256), 3);
        // Just above 1/8 the floor drops to level 2 (Nyquist is kept).
        assert_eq!(level(0.13, 512, 256), 2);
        // The larger of the two per-pixel angles counts.
        assert!(close(screen_rate(10.0, 1.0, 1.0, 100, 50), 0.2));
        // Rate 0: the top level min(log2 512, log2 256) = 8; rate >= 1: level 0.
        assert_eq!(level(0.0, 512, 256), 8);
        assert_eq!(level(1e-9, 512, 256), 8);
        assert_eq!(level(1.0, 512, 256), 0);
        assert_eq!(level(7.0, 512, 256), 0);
        // Non-powers of two: min(floor(log2 300), floor(log2 200)) = 7.
        assert_eq!(level(0.0, 300, 200), 7);
    }

    #[test]
    fn eq9_and_eq10_terms() {
        assert_eq!(variance_term(3.0, 1.0, 2.0, false), 16.0);
        assert_eq!(variance_term(3.0, 1.0, 2.0, true), 8.0);
    }
}
