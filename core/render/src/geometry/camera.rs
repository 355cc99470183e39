//! The pinhole camera of a scene (position, look-at point, up vector, vertical field
//! of view; no depth of field): primary rays through jittered points of a pixel.

use glam::{DVec2, DVec3};

use crate::scene::Camera;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    /// Unit length.
    pub dir: DVec3,
}

/// Camera basis and image-plane extents for one image size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PinholeCamera {
    origin: DVec3,
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    /// Half extents of the image plane at distance 1.
    half_w: f64,
    half_h: f64,
    width: u32,
    height: u32,
}

impl PinholeCamera {
    /// The scene validated that `look_at != position` and `up` is not parallel to the
    /// view direction.
    pub fn new(camera: &Camera, width: u32, height: u32) -> Self {
        let forward = (camera.look_at - camera.position).normalize();
        let right = forward.cross(camera.up).normalize();
        let up = right.cross(forward);
        let half_h = (camera.fov_y_deg.to_radians() * 0.5).tan();
        let half_w = half_h * width as f64 / height as f64;
        Self {
            origin: camera.position,
            forward,
            right,
            up,
            half_w,
            half_h,
            width,
            height,
        }
    }

    /// The image width in pixels the camera was made for.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// The ray through image position `(x + jitter.x, y + jitter.y)` in pixels, x to the
    /// right and y down from the top-left corner; jitter in [0, 1)^2 (0.5 = centre).
    pub fn ray(&self, x: u32, y: u32, jitter: DVec2) -> Ray {
        let sx = ((x as f64 + jitter.x) / self.width as f64) * 2.0 - 1.0;
        let sy = 1.0 - ((y as f64 + jitter.y) / self.height as f64) * 2.0;
        let dir = (self.forward + self.right * (sx * self.half_w) + self.up * (sy * self.half_h))
            .normalize();
        Ray {
            origin: self.origin,
            dir,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(fov: f64) -> Camera {
        Camera {
            position: DVec3::new(0.0, 1.0, 5.0),
            look_at: DVec3::new(0.0, 1.0, 0.0),
            up: DVec3::Y,
            fov_y_deg: fov,
        }
    }

    #[test]
    fn centre_ray_looks_at_the_target_and_edges_span_the_field_of_view() {
        let c = PinholeCamera::new(&cam(60.0), 200, 100);
        // Pixel corner (100, 50) with zero jitter is the image centre.
        let r = c.ray(100, 50, DVec2::ZERO);
        assert!((r.dir - DVec3::NEG_Z).length() < 1e-12, "{}", r.dir);
        // The top edge is fov/2 above the axis; the right edge uses the aspect ratio.
        let top = c.ray(100, 0, DVec2::ZERO).dir;
        assert!((top.y.atan2(-top.z).to_degrees() - 30.0).abs() < 1e-9);
        let right = c.ray(200, 50, DVec2::ZERO).dir;
        let expected = (2.0 * (30f64.to_radians()).tan()).atan().to_degrees();
        assert!((right.x.atan2(-right.z).to_degrees() - expected).abs() < 1e-9);
        // Right-handed: +x is to the right when looking down -z with +y up.
        assert!(right.x > 0.0 && top.y > 0.0);
    }
}
