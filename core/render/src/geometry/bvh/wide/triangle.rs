//! The leaves' triangles: their structure-of-arrays layout (v0 and two edges per
//! triangle, precomputed) and the intersection test on it, scalar or 8 at a time, by
//! obvhs's Moller-Trumbore arithmetic operation for operation.

use obvhs::triangle::Triangle;

use super::{LEAF_ROWS, Query};

/// A triangle as the intersection test reads it: obvhs's v0, e1 = v0 - v1 and
/// e2 = v2 - v0, computed once instead of per ray. Its normal e1 x e2 is not stored:
/// 36 bytes instead of 48 miss the caches less often than 6 products cost.
#[derive(Clone, Copy)]
pub(super) struct LeafTriangle {
    v0: [f32; 3],
    e1: [f32; 3],
    e2: [f32; 3],
}

/// The barycentric weights of `t`'s vertices 1 and 2 where the query's ray meets its
/// plane, by the traversal's own arithmetic.
pub(in crate::geometry::bvh) fn barycentrics(t: &Triangle, q: &Query) -> (f32, f32) {
    let (u, v, ..) = solve(&leaf_triangle(t), q);
    (u, v)
}

/// Writes the triangles `sources` of `triangles` as the leaf from slot `start`.
pub(super) fn write_leaf(
    leaves: &mut [f32],
    start: usize,
    sources: &[u32],
    triangles: &[Triangle],
) {
    let count = sources.len();
    let leaf = &mut leaves[LEAF_ROWS * start..LEAF_ROWS * (start + count)];
    for (lane, &source) in sources.iter().enumerate() {
        let t = leaf_triangle(&triangles[source as usize]);
        for (row, value) in t.v0.into_iter().chain(t.e1).chain(t.e2).enumerate() {
            leaf[row * count + lane] = value;
        }
    }
}

/// Triangle `lane` of the leaf of `count` triangles whose rows start `rows`.
#[inline(always)]
pub(super) fn leaf_lane(rows: &[f32], count: usize, lane: usize) -> LeafTriangle {
    let at = |row: usize| rows[row * count + lane];
    LeafTriangle {
        v0: [at(0), at(1), at(2)],
        e1: [at(3), at(4), at(5)],
        e2: [at(6), at(7), at(8)],
    }
}

/// `t` with its edges precomputed, as a leaf holds it.
fn leaf_triangle(t: &Triangle) -> LeafTriangle {
    LeafTriangle {
        v0: t.v0.to_array(),
        e1: (t.v0 - t.v1).to_array(),
        e2: (t.v2 - t.v0).to_array(),
    }
}

/// The dot product, summed in x, y, z order.
#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The Moller-Trumbore terms of obvhs's `Triangle::intersect` on precomputed edges:
/// the barycentric weights u (of v1) and v (of v2), 1 / det, and the normal and
/// origin offset whose dot product is the distance's numerator (left to the caller,
/// so a miss does not pay for it).
#[inline(always)]
fn solve(tri: &LeafTriangle, q: &Query) -> (f32, f32, f32, [f32; 3], [f32; 3]) {
    let (e1, e2) = (tri.e1, tri.e2);
    // Component by component as glam's cross product rounds it.
    let n = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let c = [tri.v0[0] - q.o[0], tri.v0[1] - q.o[1], tri.v0[2] - q.o[2]];
    let d = q.d;
    let r = [
        d[1] * c[2] - d[2] * c[1],
        d[2] * c[0] - d[0] * c[2],
        d[0] * c[1] - d[1] * c[0],
    ];
    let inv_det = 1.0 / dot(n, d);
    let u = dot(r, tri.e2) * inv_det;
    let v = dot(r, tri.e1) * inv_det;
    (u, v, inv_det, n, c)
}

/// obvhs's `Triangle::intersect` on precomputed edges: the distance (infinity when
/// the ray misses or the distance is outside [tmin, tmax]) and the weights u, v.
#[inline(always)]
pub(super) fn intersect(tri: &LeafTriangle, q: &Query, tmax: f32) -> (f32, f32, f32) {
    let (u, v, inv_det, n, c) = solve(tri, q);
    let w = 1.0 - u - v;
    // A negative barycentric (including -0.0) misses, as in obvhs.
    let signs = u.to_bits() | v.to_bits() | w.to_bits();
    if inv_det != 0.0 && signs & 0x8000_0000 == 0 {
        let t = dot(n, c) * inv_det;
        if t >= q.tmin && t <= tmax {
            return (t, u, v);
        }
    }
    (f32::INFINITY, u, v)
}

/// `intersect` on every triangle of a leaf at once, operation for operation in the
/// same order (so every lane's distance is the scalar test's, bit for bit): the lanes
/// that hit within [tmin, tmax) as a bit mask (below `count`), and per lane the
/// distance and u, v. `rows` is the leaf's first float; each row is read with one
/// unaligned 8-lane load, lanes at and past `count` reading whatever follows.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) unsafe fn leaf_hits_avx2(
    rows: *const f32,
    count: usize,
    q: &Query,
    tmax: f32,
) -> (u32, [f32; 8], [f32; 8], [f32; 8]) {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees AVX2 and that 8 floats from every row start are
    // readable (the leaf's rows, then the next leaf's or the padding).
    unsafe {
        let row = |r: usize| _mm256_loadu_ps(rows.add(r * count));
        let (mul, sub, add) = (_mm256_mul_ps, _mm256_sub_ps, _mm256_add_ps);
        let (e1x, e1y, e1z) = (row(3), row(4), row(5));
        let (e2x, e2y, e2z) = (row(6), row(7), row(8));
        let nx = sub(mul(e1y, e2z), mul(e1z, e2y));
        let ny = sub(mul(e1z, e2x), mul(e1x, e2z));
        let nz = sub(mul(e1x, e2y), mul(e1y, e2x));
        let cx = sub(row(0), _mm256_set1_ps(q.o[0]));
        let cy = sub(row(1), _mm256_set1_ps(q.o[1]));
        let cz = sub(row(2), _mm256_set1_ps(q.o[2]));
        let [dx, dy, dz] = q.d.map(|x| _mm256_set1_ps(x));
        let rx = sub(mul(dy, cz), mul(dz, cy));
        let ry = sub(mul(dz, cx), mul(dx, cz));
        let rz = sub(mul(dx, cy), mul(dy, cx));
        let dot3 = |ax, ay, az, bx, by, bz| add(add(mul(ax, bx), mul(ay, by)), mul(az, bz));
        let one = _mm256_set1_ps(1.0);
        let inv_det = _mm256_div_ps(one, dot3(nx, ny, nz, dx, dy, dz));
        let u = mul(dot3(rx, ry, rz, e2x, e2y, e2z), inv_det);
        let v = mul(dot3(rx, ry, rz, e1x, e1y, e1z), inv_det);
        let w = sub(sub(one, u), v);
        let t = mul(dot3(nx, ny, nz, cx, cy, cz), inv_det);
        // Sign bits of u, v, w (a negative one, -0.0 included, misses); inv_det != 0
        // (true for NaN, as the scalar `!=`); tmin <= t < tmax.
        let negative = _mm256_movemask_ps(_mm256_or_ps(_mm256_or_ps(u, v), w)) as u32;
        let nonzero = _mm256_cmp_ps::<_CMP_NEQ_UQ>(inv_det, _mm256_setzero_ps());
        let within = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(t, _mm256_set1_ps(q.tmin)),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, _mm256_set1_ps(tmax)),
        );
        let mask = _mm256_movemask_ps(_mm256_and_ps(nonzero, within)) as u32
            & !negative
            & ((1u32 << count) - 1);
        let (mut ts, mut us, mut vs) = ([0f32; 8], [0f32; 8], [0f32; 8]);
        if mask != 0 {
            _mm256_storeu_ps(ts.as_mut_ptr(), t);
            _mm256_storeu_ps(us.as_mut_ptr(), u);
            _mm256_storeu_ps(vs.as_mut_ptr(), v);
        }
        (mask, ts, us, vs)
    }
}
