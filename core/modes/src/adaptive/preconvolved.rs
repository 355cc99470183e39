//! Pre-convolved illumination for the ASFPCS variant (Bagher et al. 2013, section 2.5
//! and 4.3): the environment map low-passed at a ladder of widths, each level a 2 x 2
//! solid-angle-weighted average of the one below, and the level whose rate matches a
//! material's angular bandwidth. The paper convolves with Phong lobes; the box ladder
//! removes the same frequencies (above the level's Nyquist rate) more crudely. It is an
//! approximation: images converge to the filtered integral, not to the brute force.

use std::f64::consts::PI;

use glam::DVec3;

use meso_materials::image::Image;
use meso_render::environment::{EnvironmentSampler, pixel_of, rotate_y};
use meso_render::scene::Environment;

/// The slowest rate (samples per radian) a level is chosen for: the cosine factor that
/// the analysis neglects still varies over the hemisphere, so even a Lambertian keeps
/// the map's variation at about this scale.
pub const MIN_RATE: f64 = 2.0;
/// How many times finer than the lobe's Nyquist spacing the chosen level's pixels are.
pub const NARROWER: f64 = 4.0;

#[derive(Clone, Debug)]
pub struct Prefiltered {
    /// Level 0 is the map itself.
    levels: Vec<(u32, u32, Vec<DVec3>)>,
    /// Each level as a map with its importance sampler (`None`: black), so a
    /// shading point samples the level it reads.
    maps: Vec<(Image, Option<EnvironmentSampler>)>,
}

impl Prefiltered {
    pub fn new(map: &Image) -> Self {
        let (w, h) = (map.width(), map.height());
        let base: Vec<DVec3> = map
            .pixels()
            .iter()
            .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        let mut levels = vec![(w, h, base)];
        while let Some((w, h, px)) = levels.last().filter(|l| l.0 > 1 && l.1 > 1) {
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            let (w, h) = (*w, *h);
            let row_weight = |y: u32| ((y as f64 + 0.5) / h as f64 * PI).sin();
            let mut next = vec![DVec3::ZERO; (nw * nh) as usize];
            for y in 0..nh {
                for x in 0..nw {
                    let (mut sum, mut wsum) = (DVec3::ZERO, 0.0);
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = ((2 * x + dx).min(w - 1), (2 * y + dy).min(h - 1));
                        let wt = row_weight(sy);
                        sum += px[(sy * w + sx) as usize] * wt;
                        wsum += wt;
                    }
                    next[(y * nw + x) as usize] = if wsum > 0.0 { sum / wsum } else { DVec3::ZERO };
                }
            }
            levels.push((nw, nh, next));
        }
        let maps = levels
            .iter()
            .map(|(w, h, px)| {
                let mut img = Image::new(*w, *h);
                for (p, v) in img.pixels_mut().iter_mut().zip(px) {
                    *p = [v.x as f32, v.y as f32, v.z as f32];
                }
                let sampler = EnvironmentSampler::new(&img);
                (img, sampler)
            })
            .collect();
        Self { levels, maps }
    }

    /// Level `level`'s map and its sampler.
    pub fn map(&self, level: usize) -> (&Image, Option<&EnvironmentSampler>) {
        let (img, sampler) = &self.maps[level.min(self.maps.len() - 1)];
        (img, sampler.as_ref())
    }

    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// The coarsest level whose rate (samples per radian down the map) still covers
    /// `NARROWER` times `rate`: the filter's box is a fraction of the lobe's Nyquist
    /// spacing, so a sharp lobe does not see a blurred map (the bias that capped this
    /// variant on the silver teapot at a box as wide as the spacing).
    pub fn level_for(&self, rate: f64) -> usize {
        let h = f64::from(self.levels[0].1);
        let rate = NARROWER * rate.max(MIN_RATE);
        let m = (h / (PI * rate)).log2().floor();
        if m <= 0.0 {
            0
        } else {
            (m as usize).min(self.levels.len() - 1)
        }
    }

    /// The filtered radiance of level `level` in world direction `dir` (before strength).
    pub fn radiance(&self, env: &Environment, dir: DVec3, level: usize) -> DVec3 {
        let (w, h, px) = &self.levels[level.min(self.levels.len() - 1)];
        let d = rotate_y(dir, -env.rotate_y_deg);
        let (x, y) = pixel_of(*w, *h, d);
        px[(y * w + x) as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_keep_a_constant_map_and_halve_in_size() {
        let mut map = Image::new(64, 32);
        map.pixels_mut()
            .iter_mut()
            .for_each(|p| *p = [1.5, 2.0, 0.5]);
        let p = Prefiltered::new(&map);
        assert_eq!(p.levels(), 6); // 64x32 .. 2x1
        let env = Environment {
            map: std::sync::Arc::new(map),
            strength: 1.0,
            rotate_y_deg: 0.0,
            mis: true,
        };
        for l in 0..p.levels() {
            let r = p.radiance(&env, DVec3::new(0.3, 0.5, -0.8).normalize(), l);
            assert!((r - DVec3::new(1.5, 2.0, 0.5)).abs().max_element() < 1e-12);
        }
        // A sharp BRDF keeps the map; a slow one takes a coarse level.
        assert_eq!(p.level_for(1e6), 0);
        assert!(p.level_for(3.0) >= p.level_for(6.0));
        // Hand computed: 32 rows, rate 0.5 -> MIN_RATE 2 -> 8 per radian after
        // NARROWER: floor(log2(32 / (8 pi))) = floor(0.349) = 0, the map itself; the
        // pixels of level 1 (2 pi / 32 = 0.196 rad) would be wider than 1/8 rad.
        assert_eq!(p.level_for(0.5), 0);
        let big = Prefiltered::new(&Image::new(1024, 512));
        // 512 rows at rate 2 (8 after NARROWER): floor(log2(512 / (8 pi))) = 4.
        assert_eq!(big.level_for(2.0), 4);
    }
}
