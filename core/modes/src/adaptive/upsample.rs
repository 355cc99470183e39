//! Coarse-to-fine bilateral up-sampling (Bagher et al. 2013, section 3.2, Fig. 8):
//! level k of the image is the grid of pixels whose coordinates are multiples of 2^k;
//! from the top level down, a pixel of level k that is not on level k + 1 and has no
//! value of its own takes the average of its (up to four) level-(k+1) parents with
//! weights w_i = g_z(z - z_i) g_a(p - p_i) alpha_i: a Gaussian of the relative depth
//! difference, the anisotropic screen-space Gaussian of the projected normal, and
//! bilinear weights.

use glam::{DVec2, DVec3};

/// Relative depth difference at which g_z falls to 1/e.
pub const DEPTH_SIGMA: f64 = 0.05;
/// Below this sum of alpha g_z a pixel has no parent at its depth: it must be shaded.
pub const MIN_WEIGHT: f64 = 1e-3;

/// What the weights read of each pixel (the G-buffer's share).
#[derive(Clone, Debug)]
pub struct Guide {
    pub width: u32,
    pub height: u32,
    /// Distance along the primary ray; `f64::INFINITY` where the ray left the scene.
    pub depth: Vec<f64>,
    /// Unit screen-space direction of the projected normal (x right, y down); zero
    /// where there is no surface or the normal faces the eye.
    pub normal_dir: Vec<DVec2>,
    /// |cos| of the angle between the normal and the view direction (1 off surfaces).
    pub cos_x: Vec<f64>,
}

/// g_z: 1 for equal depths (two misses count as equal), 0 between a surface and a miss.
pub fn depth_weight(z: f64, zi: f64) -> f64 {
    if z.is_infinite() || zi.is_infinite() {
        return if z == zi { 1.0 } else { 0.0 };
    }
    let rel = (z - zi) / (DEPTH_SIGMA * z.abs().max(1e-12));
    (-rel * rel).exp()
}

/// g_a(v) = exp(-v^T M v), v in units of the parent spacing, with M stretching the
/// direction of the projected normal by 1 / cos^2(theta_x) (section 3.2).
pub fn screen_weight(v: DVec2, normal_dir: DVec2, cos_x: f64) -> f64 {
    let along = v.dot(normal_dir);
    let across2 = v.length_squared() - along * along;
    let c = cos_x.max(0.05);
    (-(across2 + along * along / (c * c))).exp()
}

/// Along one axis of size `size`: the far parent of coordinate `c` whose near parent
/// is `c0` on a grid of spacing `s`, the fraction of the way from `c0` to it, and
/// whether it is the image's last column (row) standing in for a grid point past the
/// image. That edge is shaded at every frame (`is_edge`), so pixels near it are
/// interpolated between two parents instead of extrapolated from one (extrapolation
/// over up to 2^top - 1 pixels made most of the default scene's error in its first
/// frames; docs/rendering.md). A pixel on the edge itself keeps its one-sided parents.
fn far_parent(c: u32, c0: u32, s: u32, size: u32) -> (u32, f64, bool) {
    let last = size - 1;
    if c0 + s > last && c < last && c > c0 {
        (last, f64::from(c - c0) / f64::from(last - c0), true)
    } else {
        (c0 + s, f64::from(c - c0) / f64::from(s), false)
    }
}

/// True for the image's last column and row: pixels the frames shade themselves, so
/// that they can stand in for the parents past the image (`far_parent`).
pub fn is_edge(x: u32, y: u32, w: u32, h: u32) -> bool {
    x + 1 == w || y + 1 == h
}

/// The level-(k+1) parents of pixel (x, y) with their alpha g_z and full weights; an
/// edge pixel standing in for a parent past the image counts only where `edge_valued`
/// says it has a value.
fn parents(
    guide: &Guide,
    x: u32,
    y: u32,
    k: u32,
    edge_valued: impl Fn(usize) -> bool,
) -> ([(usize, f64, f64); 4], usize) {
    let s = 1u32 << (k + 1);
    let (x0, y0) = (x / s * s, y / s * s);
    let (x1, fx, x_edge) = far_parent(x, x0, s, guide.width);
    let (y1, fy, y_edge) = far_parent(y, y0, s, guide.height);
    let i = (y * guide.width + x) as usize;
    let mut out = [(0usize, 0.0, 0.0); 4];
    let mut n = 0;
    for (far_x, far_y, alpha) in [
        (false, false, (1.0 - fx) * (1.0 - fy)),
        (true, false, fx * (1.0 - fy)),
        (false, true, (1.0 - fx) * fy),
        (true, true, fx * fy),
    ] {
        let px = if far_x { x1 } else { x0 };
        let py = if far_y { y1 } else { y0 };
        if alpha == 0.0 || px >= guide.width || py >= guide.height {
            continue;
        }
        let j = (py * guide.width + px) as usize;
        if ((far_x && x_edge) || (far_y && y_edge)) && !edge_valued(j) {
            continue;
        }
        let gz = depth_weight(guide.depth[i], guide.depth[j]);
        let v =
            DVec2::new(f64::from(px) - f64::from(x), f64::from(py) - f64::from(y)) / f64::from(s);
        let ga = screen_weight(v, guide.normal_dir[i], guide.cos_x[i]);
        out[n] = (j, alpha * gz, alpha * gz * ga);
        n += 1;
    }
    (out, n)
}

/// The finest level pixel (x, y) lies on, capped at `top`.
pub fn level_of_pixel(x: u32, y: u32, top: u32) -> u32 {
    (x | y).trailing_zeros().min(top)
}

/// True if pixel (x, y), on level k < top and not on level k + 1, has parents at its
/// depth (else it must be shaded itself), counting the edge pixels the frames shade.
pub fn has_parents(guide: &Guide, x: u32, y: u32, k: u32) -> bool {
    let (p, n) = parents(guide, x, y, k, |_| true);
    p[..n].iter().map(|q| q.1).sum::<f64>() >= MIN_WEIGHT
}

/// A site that a refinement added after the first frame holds a sample or two, while
/// the up-sampled value it replaces averages parents of many: its own mean is shown,
/// and read by the finer levels, once it holds this many samples. Without the mark the
/// new sites' noise, spread by the up-sampling, made frames worse than the ones before
/// them (docs/reports/adaptive/README.md, "Sites added by a refinement").
pub const MATURE_SAMPLES: u32 = 32;

/// Per pixel, whether its own mean (of `own[i]` samples) stands: a site of the first
/// frame as soon as it has a sample (it is a site because up-sampling cannot stand for
/// it), a site added later (`added`) once mature, or at once where no parent lies at
/// its depth or its ray left the scene (the map's value carries no shading noise).
/// The others take up-sampled values (`upsample`); every count passes the maturity
/// mark, so the image still converges to the own means.
pub fn trusted(guide: &Guide, own: &[u32], added: &[bool], top: u32) -> Vec<bool> {
    let w = guide.width;
    own.iter()
        .zip(added)
        .enumerate()
        .map(|(i, (&n, &added))| {
            if n == 0 || !added || n >= MATURE_SAMPLES || guide.depth[i].is_infinite() {
                return n > 0;
            }
            let (x, y) = (i as u32 % w, i as u32 / w);
            let k = level_of_pixel(x, y, top);
            if k >= top {
                return true;
            }
            !has_parents(guide, x, y, k)
        })
        .collect()
}

/// Fills every pixel without a value (`has_value` false) from the pyramid, coarse to
/// fine. Every pixel of the top level must have a value; a pixel whose parents all
/// lie at other depths takes the parent nearest in depth (the caller shades such
/// pixels, `has_parents`, so this only happens in tests that ask for it).
pub fn upsample(guide: &Guide, has_value: &[bool], values: &mut [DVec3], top: u32) {
    let (w, h) = (guide.width, guide.height);
    for k in (0..top).rev() {
        let step = 1u32 << k;
        for y in (0..h).step_by(step as usize) {
            for x in (0..w).step_by(step as usize) {
                let i = (y * w + x) as usize;
                if level_of_pixel(x, y, top) != k || has_value[i] {
                    continue;
                }
                let (p, n) = parents(guide, x, y, k, |j| has_value[j]);
                let total: f64 = p[..n].iter().map(|q| q.2).sum();
                values[i] = if total > 0.0 {
                    p[..n].iter().map(|q| values[q.0] * q.2).sum::<DVec3>() / total
                } else {
                    let nearest = p[..n].iter().min_by(|a, b| {
                        let da = (guide.depth[a.0] - guide.depth[i]).abs();
                        let db = (guide.depth[b.0] - guide.depth[i]).abs();
                        da.total_cmp(&db)
                    });
                    nearest.map_or(DVec3::ZERO, |q| values[q.0])
                };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat_guide(w: u32, h: u32, depth: impl Fn(u32, u32) -> f64) -> Guide {
        let n = (w * h) as usize;
        Guide {
            width: w,
            height: h,
            depth: (0..n as u32).map(|i| depth(i % w, i / w)).collect(),
            normal_dir: vec![DVec2::ZERO; n],
            cos_x: vec![1.0; n],
        }
    }

    fn top_only(w: u32, h: u32, top: u32) -> Vec<bool> {
        (0..w * h)
            .map(|i| level_of_pixel(i % w, i / w, 31) >= top)
            .collect()
    }

    #[test]
    fn a_flat_shaded_plane_is_reproduced_exactly() {
        // Constant radiance on a plane seen at constant depth: every interpolated pixel
        // is a weighted mean of equal values.
        let (w, h, top) = (37, 29, 3);
        let guide = flat_guide(w, h, |_, _| 2.0);
        let has = top_only(w, h, top);
        let c = DVec3::new(0.3, 0.5, 0.7);
        let mut v: Vec<DVec3> = has
            .iter()
            .map(|&b| if b { c } else { DVec3::splat(-1.0) })
            .collect();
        upsample(&guide, &has, &mut v, top);
        for (i, p) in v.iter().enumerate() {
            assert!((*p - c).abs().max_element() < 1e-12, "pixel {i}: {p}");
        }
    }

    /// Past the last grid point, a pixel is interpolated towards the image's last
    /// column and row where they have values (the frames shade them), not held at
    /// the last grid point's value; without values there it keeps its one parent.
    #[test]
    fn pixels_past_the_last_grid_point_are_interpolated_towards_a_valued_edge() {
        let (w, h, top) = (15, 15, 2);
        let guide = flat_guide(w, h, |_, _| 1.0);
        let ramp = |i: usize| DVec3::splat((i as u32 % w) as f64 + 0.5 * (i as u32 / w) as f64);
        let run = |has: &[bool]| {
            let mut v: Vec<DVec3> = (0..(w * h) as usize)
                .map(|i| if has[i] { ramp(i) } else { DVec3::splat(-1.0) })
                .collect();
            upsample(&guide, has, &mut v, top);
            v
        };
        let with_edges: Vec<bool> = top_only(w, h, top)
            .iter()
            .enumerate()
            .map(|(i, &b)| b || is_edge(i as u32 % w, i as u32 / w, w, h))
            .collect();
        let v = run(&with_edges);
        // (13, 0) lies halfway between the grid point (12, 0) and the edge (14, 0);
        // (0, 13) between (0, 12) and (0, 14); (13, 13) amid four parents.
        for (x, y) in [(13u32, 0u32), (0, 13), (13, 13), (13, 4)] {
            let i = (y * w + x) as usize;
            assert!(
                (v[i] - ramp(i)).abs().max_element() < 1e-12,
                "({x}, {y}): {}",
                v[i]
            );
        }
        // Edges without values are not read: the one parent's value, never the -1
        // that stands for no value.
        let v = run(&top_only(w, h, top));
        assert!((v[13].x - 12.0).abs() < 1e-12, "{}", v[13]);
        assert!(v.iter().all(|p| p.x >= 0.0));
    }

    #[test]
    fn a_linear_ramp_on_the_grid_is_interpolated_linearly_where_parents_surround() {
        let (w, h, top) = (17, 17, 2);
        let guide = flat_guide(w, h, |_, _| 1.0);
        let has = top_only(w, h, top);
        let ramp = |i: usize| DVec3::splat((i as u32 % w) as f64);
        let mut v: Vec<DVec3> = (0..(w * h) as usize)
            .map(|i| if has[i] { ramp(i) } else { DVec3::ZERO })
            .collect();
        upsample(&guide, &has, &mut v, top);
        // Pixel (2, 0) lies halfway between (0, 0) and (4, 0); isotropic g_a is equal
        // for both, so the mean is exact.
        assert!((v[2].x - 2.0).abs() < 1e-12, "{}", v[2]);
        assert!((v[(2 * w + 2) as usize].x - 2.0).abs() < 1e-12);
    }

    #[test]
    fn depth_discontinuities_are_not_blurred_across() {
        // Two planes: x < 8 at depth 1 (radiance 1), x >= 8 at depth 5 (radiance 10).
        // With only the level-2 grid shaded, every pixel must take its own plane's
        // value; a plain bilinear filter would mix them next to the edge.
        let (w, h, top) = (16, 16, 2);
        let guide = flat_guide(w, h, |x, _| if x < 8 { 1.0 } else { 5.0 });
        let has = top_only(w, h, top);
        let truth = |x: u32| if x < 8 { 1.0 } else { 10.0 };
        let mut v: Vec<DVec3> = (0..w * h)
            .map(|i| {
                if has[i as usize] {
                    DVec3::splat(truth(i % w))
                } else {
                    DVec3::ZERO
                }
            })
            .collect();
        upsample(&guide, &has, &mut v, top);
        for i in 0..w * h {
            let (x, y) = (i % w, i / w);
            let got = v[i as usize].x;
            assert!(
                (got - truth(x)).abs() < 1e-6 * truth(x),
                "({x}, {y}): {got}, expected {}",
                truth(x)
            );
        }
        // And pixel (7, y) has no parent at its depth on its right: its level-0
        // parents (6, y) and (8, y) differ, yet (6, y) is kept alone.
        assert!(has_parents(&guide, 7, 0, 0));
    }

    #[test]
    fn a_site_added_later_stands_only_once_mature() {
        // An 8 x 8 plane whose level-2 grid was shaded from the first frame (64 samples
        // each, value 1), and the level-1 pixel (2, 2) added by a refinement with an
        // outlier; (3, 2) below it on level 0 reads (2, 2) and (4, 2), which has no
        // value of its own.
        let (w, h, top) = (8, 8, 2);
        let guide = flat_guide(w, h, |_, _| 1.0);
        let first = top_only(w, h, top);
        let (at, child) = ((2 * w + 2) as usize, (2 * w + 3) as usize);
        let own_with = |n: u32| -> Vec<u32> {
            (0..(w * h) as usize)
                .map(|i| {
                    if first[i] {
                        64
                    } else if i == at {
                        n
                    } else {
                        0
                    }
                })
                .collect()
        };
        let mut added = vec![false; (w * h) as usize];
        added[at] = true;
        let shown = |n: u32, added: &[bool], guide: &Guide| {
            let has = trusted(guide, &own_with(n), added, top);
            let mut v: Vec<DVec3> = (0..(w * h) as usize)
                .map(|i| DVec3::splat(if i == at { 9.0 } else { 1.0 }))
                .collect();
            upsample(guide, &has, &mut v, top);
            (has[at], v[at].x, v[child].x)
        };
        // Immature: the parents' value is shown and passed on.
        let (has, own, below) = shown(MATURE_SAMPLES - 1, &added, &guide);
        assert!(!has);
        assert!((own - 1.0).abs() < 1e-12 && (below - 1.0).abs() < 1e-12);
        // Mature, or a site since the first frame: its own mean stands and is read.
        let (has, own, below) = shown(MATURE_SAMPLES, &added, &guide);
        assert!(has && own == 9.0 && below > 4.0, "{own} {below}");
        assert_eq!(shown(1, &vec![false; added.len()], &guide).1, 9.0);
        // A miss, or a pixel with no parent at its depth, stands at once.
        let lone = flat_guide(w, h, |x, y| if (x, y) == (2, 2) { 5.0 } else { 1.0 });
        assert_eq!(shown(1, &added, &lone).1, 9.0);
        let sky = flat_guide(w, h, |_, _| f64::INFINITY);
        assert_eq!(shown(1, &added, &sky).1, 9.0);
        // No sample: nothing of its own to show.
        assert!(!trusted(&guide, &own_with(0), &added, top)[at]);
    }

    #[test]
    fn the_screen_gaussian_is_narrow_along_a_grazing_normal() {
        let n = DVec2::X;
        let along = screen_weight(DVec2::new(0.5, 0.0), n, 0.2);
        let across = screen_weight(DVec2::new(0.0, 0.5), n, 0.2);
        assert!(along < 0.01 * across, "{along} {across}");
        assert!((screen_weight(DVec2::new(0.5, 0.0), n, 1.0) - across).abs() < 1e-15);
    }

    #[test]
    fn a_surface_pixel_next_to_only_background_parents_has_none() {
        let guide = flat_guide(
            4,
            4,
            |x, y| if x == 1 && y == 1 { 1.0 } else { f64::INFINITY },
        );
        assert!(!has_parents(&guide, 1, 1, 0));
        assert!(has_parents(&guide, 3, 1, 0));
    }
}
