//! The environment as a cube map of 6 x n x n pixels (Sun et al. 2010, section 3: the
//! lighting vector L in a pixel basis). Faces in the order +x, -x, +y, -y, +z, -z; on
//! each, pixel (i, j) covers a, b in [-1, 1] (i along a, j along b) and the direction
//! is normalize(major + a u + b v). Resampling is area-correct: each pixel is the mean
//! of the lat-long map over the pixel's solid angle (a solid-angle-weighted
//! quadrature finer than the map's pixels). Turning the environment changes L only.

use glam::DVec3;

use rayon::prelude::*;

use meso_render::environment::pixel_of;
use meso_render::scene::Environment;

/// (major axis, u axis, v axis) of each face.
const FACES: [(DVec3, DVec3, DVec3); 6] = [
    (DVec3::X, DVec3::NEG_Z, DVec3::NEG_Y),
    (DVec3::NEG_X, DVec3::Z, DVec3::NEG_Y),
    (DVec3::Y, DVec3::X, DVec3::Z),
    (DVec3::NEG_Y, DVec3::X, DVec3::NEG_Z),
    (DVec3::Z, DVec3::X, DVec3::NEG_Y),
    (DVec3::NEG_Z, DVec3::NEG_X, DVec3::NEG_Y),
];

/// The pixel layout of an n x n x 6 cube map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CubeLayout {
    pub n: u32,
}

/// The solid angle of the face region [0, x] x [0, y] seen from the cube's centre
/// (the standard closed form; differences of it give a pixel's exact solid angle).
fn corner_solid_angle(x: f64, y: f64) -> f64 {
    (x * y).atan2((x * x + y * y + 1.0).sqrt())
}

impl CubeLayout {
    pub fn new(n: u32) -> Self {
        assert!(n > 0, "a cube map has at least one pixel per side");
        Self { n }
    }

    /// Pixels in all six faces.
    pub fn len(&self) -> usize {
        6 * (self.n * self.n) as usize
    }

    pub fn is_empty(&self) -> bool {
        false
    }

    /// Face coordinates (a, b) in [-1, 1] of fractional position (fi, fj) in pixel k.
    fn face_coords(&self, k: usize, fi: f64, fj: f64) -> (usize, f64, f64) {
        let per = (self.n * self.n) as usize;
        let (face, rest) = (k / per, k % per);
        let (i, j) = (rest % self.n as usize, rest / self.n as usize);
        let n = self.n as f64;
        (
            face,
            2.0 * (i as f64 + fi) / n - 1.0,
            2.0 * (j as f64 + fj) / n - 1.0,
        )
    }

    /// The unit direction at fractional position (fi, fj) in [0, 1]^2 of pixel k.
    pub fn direction(&self, k: usize, fi: f64, fj: f64) -> DVec3 {
        let (face, a, b) = self.face_coords(k, fi, fj);
        let (m, u, v) = FACES[face];
        (m + u * a + v * b).normalize()
    }

    /// The direction through pixel k's centre.
    pub fn centre(&self, k: usize) -> DVec3 {
        self.direction(k, 0.5, 0.5)
    }

    /// The exact solid angle of pixel k.
    pub fn solid_angle(&self, k: usize) -> f64 {
        let (_, a0, b0) = self.face_coords(k, 0.0, 0.0);
        let (_, a1, b1) = self.face_coords(k, 1.0, 1.0);
        corner_solid_angle(a1, b1) - corner_solid_angle(a0, b1) - corner_solid_angle(a1, b0)
            + corner_solid_angle(a0, b0)
    }

    /// The pixel a unit direction falls in.
    pub fn pixel_of(&self, d: DVec3) -> usize {
        let ad = d.abs();
        let face = if ad.x >= ad.y && ad.x >= ad.z {
            if d.x > 0.0 { 0 } else { 1 }
        } else if ad.y >= ad.z {
            if d.y > 0.0 { 2 } else { 3 }
        } else if d.z > 0.0 {
            4
        } else {
            5
        };
        let (m, u, v) = FACES[face];
        let q = d / d.dot(m);
        let (a, b) = (q.dot(u), q.dot(v));
        let n = self.n as f64;
        let i = (((a + 1.0) * 0.5 * n) as u32).min(self.n - 1);
        let j = (((b + 1.0) * 0.5 * n) as u32).min(self.n - 1);
        face * (self.n * self.n) as usize + (j * self.n + i) as usize
    }

    /// Every pixel's solid angle.
    pub fn solid_angles(&self) -> Vec<f64> {
        (0..self.len()).map(|k| self.solid_angle(k)).collect()
    }

    /// The lighting vector of `env` (unit strength: `strength` weights the film layer):
    /// per pixel the mean radiance of the turned map over the pixel's solid angle.
    pub fn lighting(&self, env: &Environment) -> Vec<[f32; 3]> {
        let (w, h) = (env.map.width(), env.map.height());
        // Quadrature points at least twice as fine as the map's pixels along each side
        // (a cube pixel spans about (pi / 2) / n radians, a map pixel 2 pi / w).
        let q = ((w as f64 / (2.0 * self.n as f64)).ceil() as u32).clamp(2, 32);
        // The turn's sine and cosine once, not per quadrature point (a light change is
        // interactive: this loop is most of it).
        let (sin, cos) = (-env.rotate_y_deg).to_radians().sin_cos();
        let turn = |d: DVec3| DVec3::new(cos * d.x + sin * d.z, d.y, -sin * d.x + cos * d.z);
        (0..self.len())
            .into_par_iter()
            .map(|k| {
                let (_, a0, b0) = self.face_coords(k, 0.0, 0.0);
                let step = 2.0 / (self.n as f64 * q as f64);
                let mut sum = DVec3::ZERO;
                let mut weight = 0.0;
                for s in 0..q * q {
                    let (si, sj) = ((s % q) as f64 + 0.5, (s / q) as f64 + 0.5);
                    let (a, b) = (a0 + si * step, b0 + sj * step);
                    // dOmega = da db / (1 + a^2 + b^2)^(3/2)
                    let dw = (1.0 + a * a + b * b).powf(-1.5);
                    let d = self.direction(k, si / q as f64, sj / q as f64);
                    let (x, y) = pixel_of(w, h, turn(d));
                    let p = env.map.get(x, y);
                    sum += DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) * dw;
                    weight += dw;
                }
                let mean = sum / weight;
                [mean.x as f32, mean.y as f32, mean.z as f32]
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;
    use std::sync::Arc;

    use super::*;
    use meso_materials::image::Image;
    use meso_render::environment::pixel_solid_angle;

    #[test]
    fn pixels_tile_the_sphere() {
        let cube = CubeLayout::new(7);
        let total: f64 = cube.solid_angles().iter().sum();
        assert!((total - 4.0 * PI).abs() < 1e-12, "{total}");
        for k in 0..cube.len() {
            assert_eq!(cube.pixel_of(cube.centre(k)), k);
            assert_eq!(cube.pixel_of(cube.direction(k, 0.1, 0.9)), k);
        }
    }

    fn env_of(map: Image, turn: f64) -> Environment {
        Environment {
            map: Arc::new(map),
            strength: 1.0,
            rotate_y_deg: turn,
            mis: true,
        }
    }

    #[test]
    fn resampling_is_area_correct() {
        // A map with a different value in every pixel: the integral of radiance over
        // the sphere is the same in the lat-long map and in the cube map.
        let (w, h) = (64, 32);
        let mut map = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let v = 1.0 + ((x * 7 + y * 13) % 11) as f32;
                map.set(x, y, [v, 2.0 * v, 0.5]);
            }
        }
        let exact: f64 = (0..h)
            .map(|y| {
                (0..w).map(|x| map.get(x, y)[0] as f64).sum::<f64>() * pixel_solid_angle(w, h, y)
            })
            .sum();
        for turn in [0.0, 37.0] {
            let cube = CubeLayout::new(16);
            let l = cube.lighting(&env_of(map.clone(), turn));
            let total: f64 = l
                .iter()
                .zip(cube.solid_angles())
                .map(|(p, w)| p[0] as f64 * w)
                .sum();
            assert!((total / exact - 1.0).abs() < 2e-3, "{total} vs {exact}");
        }
        // A constant map resamples to the constant.
        let mut flat = Image::new(8, 4);
        flat.pixels_mut()
            .iter_mut()
            .for_each(|p| *p = [0.25, 0.5, 2.0]);
        for p in CubeLayout::new(4).lighting(&env_of(flat, 10.0)) {
            assert!((p[0] - 0.25).abs() < 1e-6 && (p[2] - 2.0).abs() < 1e-6);
        }
    }
}
