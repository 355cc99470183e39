//! A slice of a BRDF in the plane of incidence, for polar plots (the app's lobe view
//! and `meso brdf plot`): f(wi, wo) as wo sweeps the plane from the incident side
//! (theta_o = -90 deg) through the normal to the mirror side (+90 deg).

use glam::DVec3;

use super::AnalyticBrdf;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LobePoint {
    /// Signed angle of wo from the normal: negative on the side of wi.
    pub theta_o_rad: f64,
    /// f(wi, wo) in 1/sr.
    pub value: f64,
}

/// `steps` points at the centres of equal angular intervals (the grazing endpoints,
/// where every model is 0, are excluded). `phi_plane_rad` is the azimuth of the plane
/// of incidence in the tangent frame; wi lies at -theta_i in that plane.
pub fn incidence_plane_lobe(
    brdf: &AnalyticBrdf,
    theta_i_rad: f64,
    phi_plane_rad: f64,
    steps: usize,
) -> Vec<LobePoint> {
    let d = DVec3::new(phi_plane_rad.cos(), phi_plane_rad.sin(), 0.0);
    let in_plane = |theta: f64| d * theta.sin() + DVec3::Z * theta.cos();
    let wi = in_plane(-theta_i_rad);
    (0..steps)
        .map(|k| {
            let theta_o = -std::f64::consts::FRAC_PI_2
                + std::f64::consts::PI * (k as f64 + 0.5) / steps as f64;
            LobePoint {
                theta_o_rad: theta_o,
                value: brdf.eval(wi, in_plane(theta_o)),
            }
        })
        .collect()
}
