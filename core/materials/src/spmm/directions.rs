//! Interpolation over a tabulated direction set (the residual's light or view
//! directions): the directions are projected orthographically onto the unit disk
//! (x, y), Delaunay-triangulated, and a query direction gets barycentric weights on
//! the triangle containing its projection: exact at the tabulated directions,
//! continuous everywhere, at most 3 table entries. Outside the set's convex hull (near
//! the horizon) the query is moved to the nearest point of the hull boundary, which
//! keeps the weights continuous across it. A query tests the triangles listed for its
//! cell of a grid over the disk in index order and takes the first that holds it: the
//! lowest-numbered such triangle, whatever the grid. A query outside the hull tests
//! only the hull edges its cell lists as possibly nearest, in index order: the same
//! edge as a test of all of them. Light directions of values that include the
//! foreshortening cosine (a BTF's, a residual's) take `cosine_weights`: the value
//! over cos theta_l is interpolated and the query's cos theta applied.

use glam::{DVec2, DVec3};

/// Cells per side of the acceleration grid over [-1, 1]^2: cells (0.0625 wide) smaller
/// than the triangles of a measured layout (81 Bonn directions), so each lists few.
const GRID: usize = 32;

#[derive(Clone, Debug, PartialEq)]
pub struct DirectionTable {
    points: Vec<DVec2>,
    triangles: Vec<[u32; 3]>,
    /// Convex hull, counter-clockwise, as indices into `points`.
    hull: Vec<u32>,
    /// Per grid cell (row-major by the projected y), the start of its triangles in
    /// `cell_triangles`; one more entry than cells.
    cell_starts: Vec<u32>,
    /// The triangles that meet each cell, in index order per cell.
    cell_triangles: Vec<u32>,
    /// Per triangle, what `weights` tests: its corners and doubled signed area, one
    /// cache line, so a query reads one line per triangle instead of three points.
    corners: Vec<Corners>,
    /// Per grid cell, the start of its hull edges in `cell_hull_edges`; one more entry
    /// than cells.
    cell_hull_starts: Vec<u32>,
    /// The hull edges (edge `i` runs from `hull[i]` to the next) that could be the
    /// nearest to some point of each cell, in index order per cell.
    cell_hull_edges: Vec<u32>,
    /// Per direction, 1 / cos theta (`cosine_weights`; infinite on the horizon).
    inverse_cosines: Vec<f64>,
}

#[derive(Clone, Debug, PartialEq)]
#[repr(align(64))]
struct Corners {
    at: [DVec2; 3],
    /// `cross(b - a, c - a)`, exactly as a query would compute it.
    area: f64,
}

/// The largest factor cos theta_i / cos theta_l `cosine_weights` applies: a value
/// tabulated near the horizon, which measured data rarely holds and holds least
/// reliably, is not magnified more than this by a query far above it (within a
/// triangle of the Bonn layout the factor stays below 4).
const MAX_COSINE_RATIO: f64 = 20.0;

/// Barycentric weights down to this count as inside (shared edges, rounding).
const EPS: f64 = -1e-12;

/// How far a grid cell is widened when listing what may hold its points: far above
/// the rounding of a query, far below a cell's side.
const CELL_MARGIN: f64 = 1e-9;

#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum DirectionTableError {
    #[error(
        "{count} direction(s): at least 3 not on one great circle through the normal are needed"
    )]
    Degenerate { count: usize },
    #[error("directions {first} and {second} coincide")]
    Duplicate { first: usize, second: usize },
}

/// A read-only view of a table's arrays (`DirectionTable::parts`).
pub struct DirectionTableParts<'a> {
    pub points: &'a [DVec2],
    pub triangles: &'a [[u32; 3]],
    /// Per cell of the `GRID x GRID` grid (row-major by the projected y), the start of
    /// its triangles in `cell_triangles`, and the end.
    pub cell_starts: &'a [u32],
    pub cell_triangles: &'a [u32],
    /// Counter-clockwise.
    pub hull: &'a [u32],
}

fn cell_of(p: DVec2) -> (usize, usize) {
    let f =
        |v: f64| (((v + 1.0) * 0.5 * GRID as f64) as isize).clamp(0, GRID as isize - 1) as usize;
    (f(p.x), f(p.y))
}

/// cos theta of the unit direction projected to `p`.
fn cosine_of(p: DVec2) -> f64 {
    (1.0 - p.length_squared()).max(0.0).sqrt()
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Corners of grid cell (x, y), the lowest first.
fn cell_box(x: usize, y: usize) -> (DVec2, DVec2) {
    let side = 2.0 / GRID as f64;
    let lo = DVec2::new(-1.0 + side * x as f64, -1.0 + side * y as f64);
    (lo, lo + side)
}

/// Where the point of the segment from `a` to `b` nearest to `p` lies: 0 at `a`, 1 at
/// `b`.
fn nearest_on_segment(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
}

/// Distance from `p` to the segment from `a` to `b`.
fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    p.distance(a + (b - a) * nearest_on_segment(p, a, b))
}

/// Per grid cell, the hull edges that can be nearest to a point of it: those whose
/// distance from the cell's centre, less the cell's half diagonal (a lower bound over
/// the cell, distance being 1-Lipschitz), is within a margin of the smallest largest
/// distance of any edge (distance to a segment is convex, so its largest over the
/// cell is at a corner). The margin keeps every edge that the query's own arithmetic
/// could find nearest.
fn hull_edges_per_cell(points: &[DVec2], hull: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let edge = |i: usize| {
        (
            points[hull[i] as usize],
            points[hull[(i + 1) % hull.len()] as usize],
        )
    };
    let (mut starts, mut edges) = (Vec::with_capacity(GRID * GRID + 1), Vec::new());
    for y in 0..GRID {
        for x in 0..GRID {
            starts.push(edges.len() as u32);
            let (lo, hi) = cell_box(x, y);
            let (centre, half_diagonal) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
            let corners = [lo, DVec2::new(hi.x, lo.y), hi, DVec2::new(lo.x, hi.y)];
            let farthest = (0..hull.len())
                .map(|i| {
                    let (a, b) = edge(i);
                    corners
                        .iter()
                        .map(|&q| segment_distance(q, a, b))
                        .fold(0.0, f64::max)
                })
                .fold(f64::INFINITY, f64::min);
            edges.extend((0..hull.len() as u32).filter(|&i| {
                let (a, b) = edge(i as usize);
                segment_distance(centre, a, b) - half_diagonal <= farthest + CELL_MARGIN
            }));
        }
    }
    starts.push(edges.len() as u32);
    (starts, edges)
}

/// Whether triangle `t` meets grid cell (x, y), closed and widened by a margin far
/// above the query's tolerance: a triangle that could hold a point of the cell is
/// never left out. Separating axes: the cell's sides (the caller's bounding-box
/// range) and the triangle's edges.
fn triangle_meets_cell(t: [DVec2; 3], x: usize, y: usize) -> bool {
    let (lo, hi) = cell_box(x, y);
    let (lo, hi) = (lo - CELL_MARGIN, hi + CELL_MARGIN);
    let corners = [lo, DVec2::new(hi.x, lo.y), hi, DVec2::new(lo.x, hi.y)];
    let orient = cross(t[1] - t[0], t[2] - t[0]).signum();
    (0..3).all(|e| {
        let (a, b) = (t[e], t[(e + 1) % 3]);
        corners
            .iter()
            .any(|&q| orient * cross(b - a, q - a) >= -CELL_MARGIN * (b - a).length())
    })
}

impl DirectionTable {
    /// Builds the triangulation of unit directions with z > 0 (validated by the caller).
    pub fn new(dirs: &[DVec3]) -> Result<Self, DirectionTableError> {
        let points: Vec<DVec2> = dirs.iter().map(|d| DVec2::new(d.x, d.y)).collect();
        for i in 0..points.len() {
            for j in 0..i {
                if points[i].distance_squared(points[j]) < 1e-18 {
                    return Err(DirectionTableError::Duplicate {
                        first: j,
                        second: i,
                    });
                }
            }
        }
        let input: Vec<delaunator::Point> = points
            .iter()
            .map(|p| delaunator::Point { x: p.x, y: p.y })
            .collect();
        let tri = delaunator::triangulate(&input);
        // Slivers from (nearly) collinear points carry no area to interpolate over and
        // would divide by ~0 in the barycentric weights.
        let triangles: Vec<[u32; 3]> = tri
            .triangles
            .chunks_exact(3)
            .map(|t| [t[0] as u32, t[1] as u32, t[2] as u32])
            .filter(|t| {
                let [a, b, c] = t.map(|i| points[i as usize]);
                cross(b - a, c - a).abs() > 1e-12
            })
            .collect();
        if triangles.is_empty() {
            return Err(DirectionTableError::Degenerate { count: dirs.len() });
        }
        let mut hull: Vec<u32> = tri.hull.iter().map(|&i| i as u32).collect();
        // delaunator returns the hull clockwise in a y-down sense; make it counter-clockwise.
        let signed_area: f64 = (0..hull.len())
            .map(|i| {
                cross(
                    points[hull[i] as usize],
                    points[hull[(i + 1) % hull.len()] as usize],
                )
            })
            .sum();
        if signed_area < 0.0 {
            hull.reverse();
        }
        let mut cells = vec![Vec::new(); GRID * GRID];
        for (ti, t) in triangles.iter().enumerate() {
            let ps = t.map(|i| points[i as usize]);
            // Widened like the cells' test: a triangle whose side lies on a grid line
            // (to rounding) also belongs to the cell beyond it.
            let lo = ps[0].min(ps[1]).min(ps[2]) - CELL_MARGIN;
            let hi = ps[0].max(ps[1]).max(ps[2]) + CELL_MARGIN;
            let (x0, y0) = cell_of(lo);
            let (x1, y1) = cell_of(hi);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    if triangle_meets_cell(ps, x, y) {
                        cells[y * GRID + x].push(ti as u32);
                    }
                }
            }
        }
        let mut cell_starts = Vec::with_capacity(GRID * GRID + 1);
        let mut cell_triangles = Vec::new();
        for list in &cells {
            cell_starts.push(cell_triangles.len() as u32);
            cell_triangles.extend_from_slice(list);
        }
        cell_starts.push(cell_triangles.len() as u32);
        let corners = triangles
            .iter()
            .map(|index| {
                let at = index.map(|i| points[i as usize]);
                let area = cross(at[1] - at[0], at[2] - at[0]);
                Corners { at, area }
            })
            .collect();
        let (cell_hull_starts, cell_hull_edges) = hull_edges_per_cell(&points, &hull);
        let inverse_cosines = points.iter().map(|&p| 1.0 / cosine_of(p)).collect();
        Ok(Self {
            points,
            triangles,
            hull,
            cell_starts,
            cell_triangles,
            corners,
            cell_hull_starts,
            cell_hull_edges,
            inverse_cosines,
        })
    }

    /// The grid's side: `parts()` has `GRID x GRID` cells, row-major by the projected y.
    pub const GRID: usize = GRID;

    /// The directions projected on the tangent plane, the triangles over them, the
    /// triangle list of each grid cell and the hull (counter-clockwise): what a device
    /// needs to interpolate as `weights` does.
    pub fn parts(&self) -> DirectionTableParts<'_> {
        DirectionTableParts {
            points: &self.points,
            triangles: &self.triangles,
            cell_starts: &self.cell_starts,
            cell_triangles: &self.cell_triangles,
            hull: &self.hull,
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Interpolation weights of direction `d`: up to three (index, weight) pairs with
    /// weights in [0, 1] summing to 1.
    pub fn weights(&self, d: DVec3) -> [(u32, f64); 3] {
        let p = DVec2::new(d.x, d.y);
        let (cx, cy) = cell_of(p);
        let cell = cy * GRID + cx;
        let listed = self.cell_starts[cell] as usize..self.cell_starts[cell + 1] as usize;
        for &ti in &self.cell_triangles[listed] {
            let Corners {
                at: [pa, pb, pc],
                area,
            } = self.corners[ti as usize];
            let (xa, xb) = (cross(pb - p, pc - p), cross(pc - p, pa - p));
            // Most triangles of a cell are clearly not the one: skip their divisions.
            // A numerator with `x * sign < -2 |EPS| |area|` gives a weight below
            // `2 EPS` whatever the rounding: only triangles the division itself would
            // refuse are passed over, so the weights are bit for bit the plain test's.
            let (sign, reject) = (area.signum(), -2.0 * EPS * area.abs());
            if xa * sign < -reject || xb * sign < -reject {
                continue;
            }
            let wa = xa / area;
            let wb = xb / area;
            let wc = 1.0 - wa - wb;
            if wa >= EPS && wb >= EPS && wc >= EPS {
                let (wa, wb, wc) = (wa.max(0.0), wb.max(0.0), wc.max(0.0));
                let s = wa + wb + wc;
                let [a, b, c] = self.triangles[ti as usize];
                return [(a, wa / s), (b, wb / s), (c, wc / s)];
            }
        }
        // The cell's edge list holds for points inside the cell's square, which every
        // unit direction's projection is; anything else tests every edge.
        let (lo, hi) = cell_box(cx, cy);
        if p.cmpge(lo).all() && p.cmple(hi).all() {
            let listed =
                self.cell_hull_starts[cell] as usize..self.cell_hull_starts[cell + 1] as usize;
            self.nearest_on_hull(p, self.cell_hull_edges[listed].iter().map(|&i| i as usize))
        } else {
            self.nearest_on_hull(p, 0..self.hull.len())
        }
    }

    /// Weights of light direction `d` (unit, above the surface) for a tabulated
    /// quantity that includes the light's foreshortening cosine, as a BTF and an SPMM
    /// residual do: the quantity divided by cos theta_l is interpolated (`weights`)
    /// and the query's own cos theta multiplies it back, so the cosine, which is
    /// known, is exact everywhere: a Lambertian table is reproduced exactly between
    /// and beyond its directions, and beyond the set's outermost ring the value fades
    /// to zero at the horizon instead of holding the ring's. Exact at the tabulated
    /// directions; zero at and below the horizon; the factor cos theta_i / cos theta_l
    /// is at most `MAX_COSINE_RATIO`. The weights no longer sum to 1.
    pub fn cosine_weights(&self, d: DVec3) -> [(u32, f64); 3] {
        let cos = d.z;
        if cos.is_nan() || cos <= 0.0 {
            return self.weights(d).map(|(i, _)| (i, 0.0));
        }
        self.weights(d).map(|(i, w)| {
            let ratio = (cos * self.inverse_cosines[i as usize]).min(MAX_COSINE_RATIO);
            (i, w * ratio)
        })
    }

    /// Linear weights at the point of the hull boundary nearest to `p`, among the
    /// hull `edges` (in index order; the first of equally near edges wins).
    fn nearest_on_hull(&self, p: DVec2, edges: impl Iterator<Item = usize>) -> [(u32, f64); 3] {
        let mut best = (f64::INFINITY, [(0u32, 1.0), (0u32, 0.0), (0u32, 0.0)]);
        for i in edges {
            let (a, b) = (self.hull[i], self.hull[(i + 1) % self.hull.len()]);
            let (pa, pb) = (self.points[a as usize], self.points[b as usize]);
            let s = nearest_on_segment(p, pa, pb);
            let dist = p.distance_squared(pa + (pb - pa) * s);
            if dist < best.0 {
                best = (dist, [(a, 1.0 - s), (b, s), (b, 0.0)]);
            }
        }
        best.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::warp::spherical;
    use crate::rng::SampleStream;

    /// Rings of directions like a measured BTF's (1 + 6 + 12 + 18 at 0, 15, 30, 45, 60, 75 deg).
    fn rings() -> Vec<DVec3> {
        let mut d = vec![DVec3::Z];
        for (ring, count) in [(15.0f64, 6), (30.0, 12), (45.0, 18), (60.0, 20), (75.0, 24)] {
            for k in 0..count {
                d.push(spherical(
                    ring.to_radians().cos(),
                    2.0 * std::f64::consts::PI * k as f64 / count as f64,
                ));
            }
        }
        d
    }

    fn interpolate(t: &DirectionTable, values: &[f64], d: DVec3) -> f64 {
        t.weights(d)
            .iter()
            .map(|&(i, w)| w * values[i as usize])
            .sum()
    }

    #[test]
    fn exact_at_the_tabulated_directions() {
        let dirs = rings();
        let t = DirectionTable::new(&dirs).expect("valid set");
        for (i, d) in dirs.iter().enumerate() {
            let w = t.weights(*d);
            let own: f64 = w
                .iter()
                .filter(|(j, _)| *j as usize == i)
                .map(|(_, w)| w)
                .sum();
            assert!((own - 1.0).abs() < 1e-12, "direction {i}: {w:?}");
        }
    }

    #[test]
    fn weights_are_a_partition_of_unity_and_reproduce_linear_functions() {
        let dirs = rings();
        let t = DirectionTable::new(&dirs).expect("valid set");
        // A function linear in (x, y) is reproduced exactly inside the hull.
        let values: Vec<f64> = dirs.iter().map(|d| 0.3 + 2.0 * d.x - 1.5 * d.y).collect();
        for k in 0..2000u64 {
            let mut s = SampleStream::new(&[17, k]);
            let d = spherical(0.3 + 0.7 * s.next(), 2.0 * std::f64::consts::PI * s.next());
            let w = t.weights(d);
            assert!(w.iter().all(|(_, w)| (0.0..=1.0).contains(w)));
            assert!((w.iter().map(|(_, w)| w).sum::<f64>() - 1.0).abs() < 1e-12);
            let got = interpolate(&t, &values, d);
            assert!(
                (got - (0.3 + 2.0 * d.x - 1.5 * d.y)).abs() < 1e-9,
                "{d}: {got}"
            );
        }
    }

    /// A tabulated linear function of (x, y) times the light's cosine, what a BTF's
    /// values are for a Lambertian or a slowly varying surface, is reproduced exactly
    /// inside the hull by `cosine_weights` (plain weights would interpolate the
    /// cosine linearly), and a pure cosine everywhere: beyond the outermost ring too,
    /// falling to zero at the horizon where the plain weights hold the ring's value.
    #[test]
    fn cosine_weights_reproduce_the_cosine_everywhere_and_fade_at_the_horizon() {
        let dirs = rings();
        let t = DirectionTable::new(&dirs).expect("valid set");
        let linear = |d: DVec3| 0.3 + 2.0 * d.x - 1.5 * d.y;
        let tabulated: Vec<f64> = dirs.iter().map(|&d| linear(d) * d.z).collect();
        let cosines: Vec<f64> = dirs.iter().map(|d| d.z).collect();
        let with = |values: &[f64], d: DVec3| -> f64 {
            t.cosine_weights(d)
                .iter()
                .map(|&(i, w)| w * values[i as usize])
                .sum()
        };
        let (mut plain_worst, mut beyond) = (0.0f64, 0);
        for k in 0..4000u64 {
            let mut s = SampleStream::new(&[23, k]);
            // Uniform in cos theta: a quarter of the queries lie beyond 75 degrees.
            let d = spherical(s.next().max(1e-9), 2.0 * std::f64::consts::PI * s.next());
            let got = with(&cosines, d);
            assert!((got - d.z).abs() <= 1e-12, "{d}: {got}");
            plain_worst = plain_worst.max((interpolate(&t, &cosines, d) - d.z).abs());
            if d.z > 0.3 {
                let got = with(&tabulated, d);
                assert!((got - linear(d) * d.z).abs() < 1e-9, "{d}: {got}");
            } else if d.z < 75f64.to_radians().cos() {
                beyond += 1;
            }
        }
        assert!(beyond > 500, "{beyond} queries beyond the outer ring");
        // The plain weights are off by up to cos 75 degrees (0.26) at the horizon.
        assert!(
            plain_worst > 0.2,
            "plain weights' worst error {plain_worst}"
        );
        for (i, d) in dirs.iter().enumerate() {
            assert!(
                (with(&tabulated, *d) - tabulated[i]).abs() < 1e-12,
                "direction {i}"
            );
        }
        assert_eq!(with(&cosines, DVec3::X), 0.0);
        assert_eq!(with(&cosines, DVec3::new(0.6, 0.0, -0.8)), 0.0);
    }

    /// A sparse set reaching 89 degrees (cos 0.017; the normal, a ring at 60 degrees
    /// and one at 89): exact at every tabulated direction, the horizon ones too; a
    /// value there that does not fall with the cosine (as measurement noise would
    /// not) is magnified at most `MAX_COSINE_RATIO` times by the queries far above it
    /// in the triangles between the two rings; elsewhere a cosine is reproduced.
    #[test]
    fn cosine_weights_stay_exact_and_bounded_near_the_horizon() {
        let tau = std::f64::consts::TAU;
        let mut dirs = vec![DVec3::Z];
        for (theta, count) in [(60f64, 6), (89.0, 8)] {
            for k in 0..count {
                let phi = tau * (k as f64 + 0.5 * (theta / 89.0).floor()) / count as f64;
                dirs.push(spherical(theta.to_radians().cos(), phi));
            }
        }
        let t = DirectionTable::new(&dirs).expect("valid set");
        for (i, d) in dirs.iter().enumerate() {
            let own: f64 = t
                .cosine_weights(*d)
                .iter()
                .filter(|(j, _)| *j as usize == i)
                .map(|(_, w)| w)
                .sum();
            assert!((own - 1.0).abs() < 1e-12, "direction {i}: {own}");
        }
        let (mut capped, mut reproduced) = (0, 0);
        for k in 0..4000u64 {
            let mut s = SampleStream::new(&[29, k]);
            let d = spherical(s.next().max(1e-9), tau * s.next());
            let (with, plain) = (t.cosine_weights(d), t.weights(d));
            for (&(i, a), &(j, b)) in with.iter().zip(&plain) {
                assert_eq!(i, j);
                assert!(a <= MAX_COSINE_RATIO * b, "{d}: {a} against {b}");
            }
            if plain
                .iter()
                .any(|&(i, b)| b > 0.0 && d.z > MAX_COSINE_RATIO * dirs[i as usize].z)
            {
                capped += 1;
            } else {
                let got: f64 = with.iter().map(|&(i, w)| w * dirs[i as usize].z).sum();
                assert!((got - d.z).abs() <= 1e-12, "{d}: {got}");
                reproduced += 1;
            }
        }
        assert!(
            capped > 100 && reproduced > 2500,
            "{capped} capped, {reproduced} not"
        );
    }

    /// The query (grid cell lists, per-triangle records, the early reject) gives the
    /// weights of the plain definition bit for bit: the first triangle in index order
    /// whose barycentric weights are all above the tolerance, each computed from its
    /// three points with two divisions, else the hull. At random directions, at the
    /// tabulated ones, on the midpoints of every triangle edge (shared by two
    /// triangles: the lower-numbered must win), and outside the hull.
    #[test]
    fn the_fast_query_equals_the_plain_one_bit_for_bit() {
        let dirs = rings();
        let t = DirectionTable::new(&dirs).expect("valid set");
        let plain = |d: DVec3| -> [(u32, f64); 3] {
            let p = DVec2::new(d.x, d.y);
            for &[a, b, c] in &t.triangles {
                let (pa, pb, pc) = (
                    t.points[a as usize],
                    t.points[b as usize],
                    t.points[c as usize],
                );
                let area = cross(pb - pa, pc - pa);
                let wa = cross(pb - p, pc - p) / area;
                let wb = cross(pc - p, pa - p) / area;
                let wc = 1.0 - wa - wb;
                if wa >= EPS && wb >= EPS && wc >= EPS {
                    let (wa, wb, wc) = (wa.max(0.0), wb.max(0.0), wc.max(0.0));
                    let s = wa + wb + wc;
                    return [(a, wa / s), (b, wb / s), (c, wc / s)];
                }
            }
            t.nearest_on_hull(p, 0..t.hull.len())
        };
        let bits = |w: [(u32, f64); 3]| w.map(|(i, w)| (i, w.to_bits()));
        let lift = |p: DVec2| DVec3::new(p.x, p.y, (1.0 - p.length_squared()).max(0.0).sqrt());
        let mut queries: Vec<DVec3> = dirs.clone();
        for tri in &t.triangles {
            for e in 0..3 {
                let (a, b) = (
                    t.points[tri[e] as usize],
                    t.points[tri[(e + 1) % 3] as usize],
                );
                queries.push(lift((a + b) * 0.5));
            }
        }
        for k in 0..20_000u64 {
            let mut s = SampleStream::new(&[23, k]);
            queries.push(spherical(s.next(), 2.0 * std::f64::consts::PI * s.next()));
        }
        // Outside the hull, where a cell's edge list replaces the test of every edge:
        // the horizon all round, the hull's corners and edge midpoints pushed outwards
        // (the places where the nearest edge changes), and the grid's lines there.
        for k in 0..20_000 {
            let phi = 2.0 * std::f64::consts::PI * k as f64 / 20_000.0;
            queries.push(DVec3::new(phi.cos(), phi.sin(), 0.0));
        }
        for i in 0..t.hull.len() {
            let (a, b) = (
                t.points[t.hull[i] as usize],
                t.points[t.hull[(i + 1) % t.hull.len()] as usize],
            );
            for q in [a, (a + b) * 0.5] {
                for push in [1e-12, 1e-6, 1e-3, 0.01, 0.02] {
                    let out = q * (1.0 + push);
                    if out.length() <= 1.0 {
                        queries.push(lift(out));
                    }
                }
            }
        }
        for line in 0..=GRID {
            let at = -1.0 + 2.0 * line as f64 / GRID as f64;
            for k in 0..=400 {
                let along = -1.0 + 2.0 * k as f64 / 400.0;
                for p in [DVec2::new(at, along), DVec2::new(along, at)] {
                    if p.length() <= 1.0 {
                        queries.push(lift(p));
                    }
                }
            }
        }
        for d in queries {
            assert_eq!(bits(t.weights(d)), bits(plain(d)), "{d}");
        }
    }

    #[test]
    fn continuous_everywhere_including_outside_the_hull() {
        // Walk across the disk and out towards the horizon in small steps: a random
        // table's interpolant never jumps by more than its Lipschitz bound allows.
        let dirs = rings();
        let t = DirectionTable::new(&dirs).expect("valid set");
        let values: Vec<f64> = (0..dirs.len())
            .map(|i| SampleStream::new(&[5, i as u64]).at(0))
            .collect();
        for phi in [0.1f64, 1.3, 2.9, 4.4] {
            let mut prev = interpolate(&t, &values, DVec3::Z);
            let steps = 20_000;
            for k in 1..=steps {
                let theta = 89.99f64.to_radians() * k as f64 / steps as f64;
                let v = interpolate(&t, &values, spherical(theta.cos(), phi));
                // Steps are 7.9e-5 rad; the finest triangle edge here is ~0.06 in the
                // disk, so a continuous interpolant moves by far less than 0.01 a step.
                assert!(
                    (v - prev).abs() < 0.01,
                    "jump {prev} -> {v} at theta {theta}, phi {phi}"
                );
                prev = v;
            }
        }
    }

    #[test]
    fn rejects_degenerate_and_duplicate_sets() {
        assert!(matches!(
            DirectionTable::new(&[DVec3::Z]),
            Err(DirectionTableError::Degenerate { .. })
        ));
        let line = [
            spherical(0.5, 0.0),
            DVec3::Z,
            spherical(0.5, std::f64::consts::PI),
        ];
        assert!(matches!(
            DirectionTable::new(&line),
            Err(DirectionTableError::Degenerate { .. })
        ));
        let dup = [
            DVec3::Z,
            spherical(0.5, 0.0),
            spherical(0.5, 1.0),
            spherical(0.5, 0.0),
        ];
        assert_eq!(
            DirectionTable::new(&dup),
            Err(DirectionTableError::Duplicate {
                first: 1,
                second: 3
            })
        );
    }
}
