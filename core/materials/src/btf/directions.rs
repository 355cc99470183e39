//! Direction sets of a BTF: the Bonn/UBO 81-direction layout of the University of
//! Bonn BTF database (Sattler, Sarlette and Klein 2003; the "UBO2003" samples that
//! Wu et al. 2011 fitted and Silva & Santos 2013 rendered: 81 x 81 directions) and
//! custom ring layouts. A ring layout puts `count` directions at polar angle
//! `theta_deg`, azimuths `360 k / count` degrees, k = 0 .. count - 1. Also the
//! 151-direction layout of Bonn's later dome (the UBO2014 files), whose rings are
//! rotated by an azimuth offset, and `Layout`, the named layouts recipes refer to.

use glam::DVec3;

use crate::brdf::warp;

/// The Bonn/UBO layout: rings at theta = 0, 15, 30, 45, 60, 75 degrees holding
/// 1, 6, 12, 18, 20, 24 directions (azimuth steps 360, 60, 30, 20, 18, 15 degrees),
/// 81 in all, the same set for light and view.
pub const BONN_RINGS: [(f64, u32); 6] = [
    (0.0, 1),
    (15.0, 6),
    (30.0, 12),
    (45.0, 18),
    (60.0, 20),
    (75.0, 24),
];

/// The UBO2014 layout (Bonn's dome 1, as btflib's `create_ubo_dome1_sampling`
/// describes it): rings (theta deg, count, azimuth offset deg) at 0, 11, 23.5, 30,
/// 37.5, 45, 52.5, 60, 67.5, 75 degrees holding 1, 6, 12, 12, 12, 18, 18, 24, 24, 24
/// directions, 151 in all; ring k's azimuths are `offset + 360 j / count`.
pub const UBO151_RINGS: [(f64, u32, f64); 10] = [
    (0.0, 1, 0.0),
    (11.0, 6, 15.0),
    (23.5, 12, 0.0),
    (30.0, 12, 15.0),
    (37.5, 12, 0.0),
    (45.0, 18, 0.0),
    (52.5, 18, 7.5),
    (60.0, 24, 0.0),
    (67.5, 24, 7.5),
    (75.0, 24, 0.0),
];

/// A direction layout known by name (BTF recipes' `directions`, docs/formats/btf.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// UBO2003/ATRIUM: 81 directions (`bonn81`).
    Bonn81,
    /// UBO2014: 151 directions (`ubo151`).
    Ubo151,
}

impl Layout {
    pub const ALL: [Layout; 2] = [Layout::Bonn81, Layout::Ubo151];

    pub fn name(self) -> &'static str {
        match self {
            Layout::Bonn81 => "bonn81",
            Layout::Ubo151 => "ubo151",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// The layout's directions, in the database's order.
    pub fn directions(self) -> Vec<DVec3> {
        match self {
            Layout::Bonn81 => bonn81(),
            Layout::Ubo151 => ubo151(),
        }
    }
}

/// Unit direction (tangent frame, z up) of polar angle `theta_deg` and azimuth
/// `phi_deg`, both in degrees.
pub fn from_angles_deg(theta_deg: f64, phi_deg: f64) -> DVec3 {
    let d = warp::spherical(theta_deg.to_radians().cos(), phi_deg.to_radians());
    // The pole is exact (0, 0, 1) whatever the azimuth.
    if theta_deg == 0.0 { DVec3::Z } else { d }
}

/// Directions of a ring layout, ring by ring, azimuth increasing.
pub fn rings(layout: &[(f64, u32)]) -> Vec<DVec3> {
    let mut dirs = Vec::new();
    for &(theta, count) in layout {
        for k in 0..count {
            dirs.push(from_angles_deg(theta, 360.0 * k as f64 / count as f64));
        }
    }
    dirs
}

/// The 81 Bonn/UBO directions in the database's order (ring by ring, azimuth increasing).
pub fn bonn81() -> Vec<DVec3> {
    rings(&BONN_RINGS)
}

/// The 151 UBO2014 directions, ring by ring, azimuth increasing from the ring's offset.
pub fn ubo151() -> Vec<DVec3> {
    let mut dirs = Vec::with_capacity(151);
    for (theta, count, offset) in UBO151_RINGS {
        for k in 0..count {
            dirs.push(from_angles_deg(
                theta,
                offset + 360.0 * k as f64 / count as f64,
            ));
        }
    }
    dirs
}

/// (theta, phi) in degrees of a unit direction, phi in [0, 360).
pub fn to_angles_deg(d: DVec3) -> (f64, f64) {
    let theta = d.z.clamp(-1.0, 1.0).acos().to_degrees();
    let phi = d.y.atan2(d.x).to_degrees().rem_euclid(360.0);
    (theta, phi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bonn_layout_has_81_distinct_upper_directions() {
        let d = bonn81();
        assert_eq!(d.len(), 81);
        assert_eq!(d[0], DVec3::Z);
        for (i, a) in d.iter().enumerate() {
            assert!((a.length() - 1.0).abs() < 1e-12 && a.z > 0.2);
            for b in &d[..i] {
                assert!(a.distance(*b) > 0.05);
            }
        }
        // Ring 45 deg, k = 3: phi = 60 deg.
        let (t, p) = to_angles_deg(d[1 + 6 + 12 + 3]);
        assert!((t - 45.0).abs() < 1e-9 && (p - 60.0).abs() < 1e-9);
    }

    #[test]
    fn ubo_layout_has_151_distinct_upper_directions() {
        let d = ubo151();
        assert_eq!(d.len(), 151);
        assert_eq!(Layout::Ubo151.directions(), d);
        assert_eq!(Layout::from_name("ubo151"), Some(Layout::Ubo151));
        assert_eq!(Layout::from_name("bonn81"), Some(Layout::Bonn81));
        assert_eq!(Layout::from_name("ubo"), None);
        for (i, a) in d.iter().enumerate() {
            assert!((a.length() - 1.0).abs() < 1e-12 && a.z > 0.25);
            for b in &d[..i] {
                assert!(a.distance(*b) > 0.05, "{i}");
            }
        }
        // Ring 52.5 deg (offset 7.5, step 20), k = 2: phi = 47.5 deg.
        let (t, p) = to_angles_deg(d[1 + 6 + 12 + 12 + 12 + 18 + 2]);
        assert!(
            (t - 52.5).abs() < 1e-9 && (p - 47.5).abs() < 1e-9,
            "{t} {p}"
        );
    }
}
