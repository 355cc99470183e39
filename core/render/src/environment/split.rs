//! The environment split in two: its brightest pixels (the sun, a studio's lamps) and
//! the rest. The biscale mode traces the peaks per pixel like a light and lets its
//! precomputed transfer carry the smoother remainder (docs/rendering.md); the adaptive
//! mode samples each part with its own sampler, so a shading point sees the sun in
//! every sample instead of in about half of them.
//!
//! The rule: the pixels of highest luminance covering `share` of the sphere's solid
//! angle set a threshold tau; a pixel brighter than tau keeps tau (its colour kept) in
//! the remainder and gives the excess to the traced part. Both parts are non-negative
//! and add up to the map exactly. On the shipped maps at 1%: the traced part holds 75%
//! of the studio map's power and 54% of the sky's.

use std::sync::Arc;

use super::{EnvironmentSampler, pixel_solid_angle};
use meso_materials::image::{Image, luminance};

/// Share of the sphere's solid angle traced by default.
pub const DEFAULT_TRACED_SHARE: f64 = 0.01;

/// A map split into the part the transfer carries and the part traced per pixel.
pub struct EnvironmentSplit {
    /// The map it was made from (to tell whether a new map needs a new split).
    pub source: Arc<Image>,
    /// What the precomputed transfer carries: the map with its peaks cut to `threshold`.
    pub remainder: Arc<Image>,
    /// The excess above the threshold, and its importance sampler (`None`: nothing
    /// above it, as in a constant map).
    pub peaks: Image,
    pub sampler: Option<EnvironmentSampler>,
    /// Luminance above which pixels are traced.
    pub threshold: f64,
    /// Share of the map's power (luminance x solid angle) that is traced.
    pub traced_power: f64,
}

impl EnvironmentSplit {
    /// Splits `map`, tracing the brightest pixels that cover `share` of the sphere
    /// (0: nothing traced, the transfer carries the whole map).
    pub fn new(map: &Arc<Image>, share: f64) -> Self {
        let (w, h) = (map.width(), map.height());
        let lum: Vec<f64> = map
            .pixels()
            .iter()
            .map(|p| f64::from(luminance(*p)).max(0.0))
            .collect();
        let area = |i: usize| pixel_solid_angle(w, h, i as u32 / w);
        let threshold = if share > 0.0 {
            let mut order: Vec<usize> = (0..lum.len()).collect();
            order.sort_by(|&a, &b| lum[b].total_cmp(&lum[a]));
            let budget = share * 4.0 * std::f64::consts::PI;
            let mut covered = 0.0;
            let mut tau = f64::INFINITY;
            for i in order {
                tau = lum[i];
                covered += area(i);
                if covered >= budget {
                    break;
                }
            }
            tau
        } else {
            f64::INFINITY
        };
        let mut remainder = Image::new(w, h);
        let mut peaks = Image::new(w, h);
        let (mut traced, mut total) = (0.0, 0.0);
        for (i, p) in map.pixels().iter().enumerate() {
            let keep = if lum[i] > threshold {
                threshold / lum[i]
            } else {
                1.0
            };
            let low = p.map(|c| (f64::from(c) * keep) as f32);
            // The excess as a difference, so the two parts add up to the map's value.
            let high = [p[0] - low[0], p[1] - low[1], p[2] - low[2]].map(|c| c.max(0.0));
            remainder.pixels_mut()[i] = [p[0] - high[0], p[1] - high[1], p[2] - high[2]];
            peaks.pixels_mut()[i] = high;
            traced += f64::from(luminance(high)) * area(i);
            total += lum[i] * area(i);
        }
        Self {
            source: Arc::clone(map),
            remainder: Arc::new(remainder),
            sampler: EnvironmentSampler::new(&peaks),
            peaks,
            threshold,
            traced_power: if total > 0.0 { traced / total } else { 0.0 },
        }
    }
}

/// A map's peaks and its remainder (`EnvironmentSplit` at `DEFAULT_TRACED_SHARE`),
/// each with an importance sampler of its own: an estimator that draws one direction
/// from each sees a small bright source in every sample, not only in the share of
/// samples its power earns (the adaptive mode's frames, on the CPU and the device).
/// `None` when either part is black: a map without peaks stays whole.
pub fn sampled_parts(map: &Arc<Image>) -> Option<[(EnvironmentSampler, Arc<Image>); 2]> {
    let split = EnvironmentSplit::new(map, DEFAULT_TRACED_SHARE);
    let remainder = EnvironmentSampler::new(&split.remainder)?;
    Some([
        (split.sampler?, Arc::new(split.peaks)),
        (remainder, split.remainder),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spot_map() -> Arc<Image> {
        let (w, h) = (64, 32);
        let mut map = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let bright = (30..32).contains(&x) && (10..12).contains(&y);
                let p = if bright {
                    [500.0, 400.0, 300.0]
                } else {
                    [0.2 + x as f32 / 64.0, 0.3, 0.1 + y as f32 / 32.0]
                };
                map.pixels_mut()[(y * w + x) as usize] = p;
            }
        }
        Arc::new(map)
    }

    #[test]
    fn the_parts_add_up_to_the_map_and_the_remainder_stays_below_the_threshold() {
        let map = spot_map();
        let split = EnvironmentSplit::new(&map, 0.01);
        assert!(split.threshold.is_finite() && split.threshold > 0.3);
        for ((m, r), p) in map
            .pixels()
            .iter()
            .zip(split.remainder.pixels())
            .zip(split.peaks.pixels())
        {
            for c in 0..3 {
                assert!(r[c] >= 0.0 && p[c] >= 0.0);
                assert_eq!(r[c] + p[c], m[c], "{m:?} = {r:?} + {p:?}");
            }
            assert!(f64::from(luminance(*r)) <= split.threshold * (1.0 + 1e-6));
        }
        // The four spot pixels are far brighter than the rest: their power less the
        // threshold's plateau is traced, at most their whole power and what the other
        // pixels above the threshold add (they are below 0.7, so about 0.1 of the
        // share's 0.126 sr at most 0.7).
        let area = |y: u32| pixel_solid_angle(64, 32, y);
        let total: f64 = map
            .pixels()
            .iter()
            .enumerate()
            .map(|(i, p)| f64::from(luminance(*p)) * area(i as u32 / 64))
            .sum();
        let spot_area = 2.0 * (area(10) + area(11));
        let spot = f64::from(luminance([500.0, 400.0, 300.0])) * spot_area;
        let low = (spot - split.threshold * spot_area) / total;
        let high = (spot + 0.7 * 0.126) / total;
        assert!(
            (low..=high).contains(&split.traced_power),
            "{low} <= {} <= {high}",
            split.traced_power
        );
        let traced_area: f64 = split
            .peaks
            .pixels()
            .iter()
            .enumerate()
            .filter(|(_, p)| p.iter().any(|&c| c > 0.0))
            .map(|(i, _)| pixel_solid_angle(64, 32, i as u32 / 64))
            .sum();
        assert!(traced_area <= 0.01 * 4.0 * std::f64::consts::PI + 0.01);
        assert!(split.sampler.is_some());
    }

    #[test]
    fn the_sampled_parts_add_up_to_the_map_and_each_samples_only_its_own_pixels() {
        let map = spot_map();
        let [(peaks, peak_map), (rest, rest_map)] = sampled_parts(&map).expect("a spot to split");
        let (w, h) = (map.width(), map.height());
        let mut spot_mass = 0.0;
        for y in 0..h {
            for x in 0..w {
                let (m, p, r) = (map.get(x, y), peak_map.get(x, y), rest_map.get(x, y));
                (0..3).for_each(|c| assert_eq!(p[c] + r[c], m[c], "({x}, {y})"));
                // The pixel's centre: each part's sampler draws only where its own map
                // is bright.
                let u = (x as f64 + 0.5) / w as f64;
                let v = (y as f64 + 0.5) / h as f64;
                let dir = super::super::direction_at(u, v);
                let bright = |q: [f32; 3]| q.iter().any(|&c| c > 0.0);
                assert_eq!(peaks.pdf(dir) > 0.0, bright(p), "({x}, {y})");
                assert_eq!(rest.pdf(dir) > 0.0, bright(r), "({x}, {y})");
                if (30..32).contains(&x) && (10..12).contains(&y) {
                    spot_mass += peaks.pdf(dir) * pixel_solid_angle(w, h, y);
                }
            }
        }
        // The spot's excess is most of the peaks' power: the peaks' sampler draws it
        // almost always.
        assert!(spot_mass > 0.9, "{spot_mass}");
        let mut constant = Image::new(16, 8);
        constant.pixels_mut().fill([0.7, 0.7, 0.7]);
        assert!(sampled_parts(&Arc::new(constant)).is_none());
    }

    #[test]
    fn a_constant_map_or_a_zero_share_traces_nothing() {
        let mut constant = Image::new(16, 8);
        constant.pixels_mut().fill([0.7, 0.7, 0.7]);
        let constant = Arc::new(constant);
        for (map, share) in [(constant, 0.01), (spot_map(), 0.0)] {
            let split = EnvironmentSplit::new(&map, share);
            assert!(split.sampler.is_none());
            assert_eq!(split.traced_power, 0.0);
            assert_eq!(split.remainder.pixels(), map.pixels());
        }
    }
}
