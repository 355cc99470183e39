//! Orthonormal shading frames. `Frame::from_normal_spmm` is the exact frame rule of
//! an SPMM basis function's own normal n_j (docs/brdf.md, "The SPMM basis function").

use glam::DVec3;

/// A right-handed orthonormal frame: `x` tangent, `y` bitangent, `z` normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub x: DVec3,
    pub y: DVec3,
    pub z: DVec3,
}

impl Frame {
    /// The frame (x', y', n) of docs/brdf.md: x' is the tangent (1,0,0) made
    /// orthogonal to n; when that is degenerate (|x - (x.n) n| < 1e-6) the bitangent
    /// (0,1,0) is used instead, with y' = n x x' and then x' = y' x n.
    pub fn from_normal_spmm(n: DVec3) -> Self {
        let x_proj = DVec3::X - n.x * n;
        if x_proj.length() >= 1e-6 {
            let x = x_proj.normalize();
            Self {
                x,
                y: n.cross(x),
                z: n,
            }
        } else {
            // The spec's fallback: build from the bitangent, then complete.
            let x0 = (DVec3::Y - n.y * n).normalize();
            let y = n.cross(x0);
            let x = y.cross(n);
            Self { x, y, z: n }
        }
    }

    /// Coordinates of the world/tangent-space vector `v` in this frame.
    #[inline]
    pub fn to_local(&self, v: DVec3) -> DVec3 {
        DVec3::new(v.dot(self.x), v.dot(self.y), v.dot(self.z))
    }

    /// The vector whose coordinates in this frame are `v`.
    #[inline]
    pub fn to_world(&self, v: DVec3) -> DVec3 {
        self.x * v.x + self.y * v.y + self.z * v.z
    }
}
