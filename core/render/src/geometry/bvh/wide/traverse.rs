//! Ray queries against the wide tree: closest hit (ordered, nearest child first,
//! farther ones stacked and skipped once a closer hit is known) and occlusion (stops
//! at the first hit), with an AVX2 or a portable node test.

use std::mem::MaybeUninit;

#[cfg(target_arch = "x86_64")]
use super::triangle::leaf_hits_avx2;
use super::triangle::{intersect, leaf_lane};
use super::{Found, Kernel, LEAF, LEAF_ROWS, Node, Query, WideBvh, leaf_range};

/// Most stack entries a traversal of any tree here can hold on the call stack; deeper
/// trees (never seen in practice: depth 36 would be needed) use a heap stack.
const INLINE_STACK: usize = 256;

/// 1 + 2 gamma_3 (gamma_n = n u / (1 - n u), u = 2^-24), rounded up: the factor that
/// makes the slab test's far distance an upper bound despite the rounding of the
/// subtraction, the product and the reciprocal (Ize, "Robust BVH ray traversal", 2013).
const ROBUST_FAR: f32 = 1.0 + 4.0 * f32::EPSILON;

/// A child left for later and the distance at which the ray enters its box.
#[derive(Clone, Copy)]
struct Entry {
    child: u32,
    tnear: f32,
}

impl WideBvh {
    /// The closest hit within the query's (tmin, tmax): (primitive slot, distance).
    #[inline]
    pub(in crate::geometry::bvh) fn closest(&self, q: &Query) -> Option<Found> {
        self.closest_with(self.kernel, q)
    }

    /// Whether any triangle lies within the query's (tmin, tmax).
    #[inline]
    pub(in crate::geometry::bvh) fn occluded(&self, q: &Query) -> bool {
        self.occluded_with(self.kernel, q)
    }

    pub(in crate::geometry::bvh) fn closest_with(
        &self,
        kernel: Kernel,
        q: &Query,
    ) -> Option<Found> {
        if self.nodes.is_empty() {
            return None;
        }
        self.with_stack(|stack| match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernel::Avx2` is only chosen where the CPU reports AVX2
            // (`Kernel::detect`, or a test that checks the same first).
            Kernel::Avx2 => unsafe { self.closest_avx2(q, stack) },
            _ => self.traverse::<false, false>(q, stack),
        })
    }

    pub(in crate::geometry::bvh) fn occluded_with(&self, kernel: Kernel, q: &Query) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        self.with_stack(|stack| match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `closest_with`.
            Kernel::Avx2 => unsafe { self.occluded_avx2(q, stack) },
            _ => self.traverse::<false, true>(q, stack),
        })
        .is_some()
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn closest_avx2(&self, q: &Query, stack: &mut [MaybeUninit<Entry>]) -> Option<Found> {
        self.traverse::<true, false>(q, stack)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn occluded_avx2(&self, q: &Query, stack: &mut [MaybeUninit<Entry>]) -> Option<Found> {
        self.traverse::<true, true>(q, stack)
    }

    fn with_stack<R>(&self, f: impl FnOnce(&mut [MaybeUninit<Entry>]) -> R) -> R {
        if self.stack_need <= INLINE_STACK {
            // Left uninitialised: clearing 2 KiB per ray would cost as much as a
            // few node tests, and only entries written are read back.
            let mut stack = [const { MaybeUninit::uninit() }; INLINE_STACK];
            f(&mut stack)
        } else {
            f(&mut vec![MaybeUninit::uninit(); self.stack_need])
        }
    }

    /// Asks for a child's node or triangles ahead of use: several children's cache
    /// misses then overlap instead of each waiting in turn when its entry is popped.
    #[inline(always)]
    fn prefetch(&self, child: u32) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            // SAFETY (all prefetches): a prefetch never faults and changes nothing but
            // the caches, whatever the address.
            if child & LEAF != 0 {
                // At most 8 x 36 bytes: the lines of the first byte, of every 64th
                // after it within the leaf, and of the last.
                let (start, count) = leaf_range(child);
                let first = self.leaves[LEAF_ROWS * start..].as_ptr().cast::<i8>();
                let bytes = count * LEAF_ROWS * size_of::<f32>();
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(first);
                    _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(64));
                    if bytes > 128 {
                        _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(128));
                        _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(192));
                    }
                    if bytes > 256 {
                        _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(256));
                    }
                    _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(bytes - 1));
                }
            } else {
                // A node is four whole lines (`Node` is 64-byte aligned).
                let n = std::ptr::from_ref(&self.nodes[child as usize]).cast::<i8>();
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(n);
                    _mm_prefetch::<_MM_HINT_T0>(n.wrapping_add(64));
                    _mm_prefetch::<_MM_HINT_T0>(n.wrapping_add(128));
                    _mm_prefetch::<_MM_HINT_T0>(n.wrapping_add(192));
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = child;
    }

    /// The traversal both queries share. `ANY`: stop at the first hit (occlusion),
    /// unordered; else the closest hit, nearest child first. `AVX2` only from a
    /// function compiled with AVX2 enabled.
    #[inline(always)]
    fn traverse<const AVX2: bool, const ANY: bool>(
        &self,
        q: &Query,
        stack: &mut [MaybeUninit<Entry>],
    ) -> Option<Found> {
        let mut best: Option<Found> = None;
        let mut tmax = q.tmax;
        let mut len = 0;
        let mut current = 0u32;
        let mut tnear = [0.0f32; 8];
        loop {
            if current & LEAF == 0 {
                let node = &self.nodes[current as usize];
                let mask = if AVX2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 is only set by the AVX2-enabled entry points.
                    unsafe {
                        node_hits_avx2(node, q, tmax, &mut tnear)
                    }
                    #[cfg(not(target_arch = "x86_64"))]
                    unreachable!()
                } else {
                    node_hits_portable(node, q, tmax, &mut tnear)
                };
                if mask != 0 {
                    if mask & (mask - 1) == 0 {
                        current = node.child[mask.trailing_zeros() as usize];
                        continue;
                    }
                    // Several children: the nearest is visited now, the others stacked
                    // farthest first so the next nearest is popped next.
                    let mut refs = [0u32; 8];
                    let mut dist = [0f32; 8];
                    let mut k = 0;
                    let mut m = mask;
                    while m != 0 {
                        let i = m.trailing_zeros() as usize;
                        m &= m - 1;
                        let (r, d) = (node.child[i], tnear[i]);
                        self.prefetch(r);
                        let mut j = k;
                        if !ANY {
                            while j > 0 && dist[j - 1] < d {
                                refs[j] = refs[j - 1];
                                dist[j] = dist[j - 1];
                                j -= 1;
                            }
                        }
                        refs[j] = r;
                        dist[j] = d;
                        k += 1;
                    }
                    for j in 0..k - 1 {
                        stack[len] = MaybeUninit::new(Entry {
                            child: refs[j],
                            tnear: dist[j],
                        });
                        len += 1;
                    }
                    current = refs[k - 1];
                    continue;
                }
            } else {
                let (start, count) = leaf_range(current);
                let rows = &self.leaves[LEAF_ROWS * start..];
                // What the 8-lane loads of the last row read (`LEAF_PAD`).
                debug_assert!(rows.len() >= (LEAF_ROWS - 1) * count + 8);
                if AVX2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 is only set by the AVX2-enabled entry points; the
                    // leaf's rows and `LEAF_PAD` after the last leaf cover every load.
                    unsafe {
                        let (mask, t, u, v) = leaf_hits_avx2(rows.as_ptr(), count, q, tmax);
                        if mask != 0 {
                            // The nearest (for occlusion, the first that hits); the
                            // first of equals, as the scalar loop.
                            let mut m = if ANY {
                                mask & mask.wrapping_neg()
                            } else {
                                mask
                            };
                            while m != 0 {
                                let i = m.trailing_zeros() as usize;
                                m &= m - 1;
                                if t[i] < tmax {
                                    tmax = t[i];
                                    best = Some(Found {
                                        slot: (start + i) as u32,
                                        t: t[i],
                                        u: u[i],
                                        v: v[i],
                                    });
                                }
                            }
                            if ANY {
                                return best;
                            }
                        }
                    }
                } else {
                    for lane in 0..count {
                        let (t, u, v) = intersect(&leaf_lane(rows, count, lane), q, tmax);
                        if t < tmax {
                            best = Some(Found {
                                slot: (start + lane) as u32,
                                t,
                                u,
                                v,
                            });
                            if ANY {
                                return best;
                            }
                            tmax = t;
                        }
                    }
                }
            }
            // Next: the nearest stacked child not beyond the closest hit so far.
            loop {
                if len == 0 {
                    return best;
                }
                len -= 1;
                // SAFETY: entries below `len` were all written by the push above.
                let e = unsafe { stack[len].assume_init() };
                if e.tnear <= tmax * ROBUST_FAR {
                    current = e.child;
                    break;
                }
            }
        }
    }
}

/// Which of the node's children the ray enters within [tmin, tmax] (bit per child),
/// and each child's entry distance in `tnear`.
#[inline(always)]
fn node_hits_portable(node: &Node, q: &Query, tmax: f32, tnear: &mut [f32; 8]) -> u32 {
    let mut mask = 0;
    for (lane, entry) in tnear.iter_mut().enumerate() {
        let (mut near, mut far) = (q.tmin, tmax);
        for axis in 0..3 {
            let lo = node.planes[2 * axis + q.neg[axis]][lane];
            let hi = node.planes[2 * axis + 1 - q.neg[axis]][lane];
            near = near.max((lo - q.o[axis]) * q.inv[axis]);
            far = far.min((hi - q.o[axis]) * q.inv[axis]);
        }
        *entry = near;
        mask |= u32::from(near <= far * ROBUST_FAR) << lane;
    }
    mask
}

/// `node_hits_portable` with one AVX2 instruction per slab and lane-wise operation.
/// Only called from functions compiled with AVX2 enabled, into which it is inlined
/// (a `target_feature` function of its own would not be, and a call per node costs).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn node_hits_avx2(node: &Node, q: &Query, tmax: f32, tnear: &mut [f32; 8]) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: rows are 32-byte aligned (`Node` is align(64) and each row 32 bytes);
    // `neg` is 0 or 1, so every row index is below 6.
    unsafe {
        let row = |r: usize| _mm256_load_ps(node.planes[r].as_ptr());
        let slab = |axis: usize, r: usize| {
            _mm256_mul_ps(
                _mm256_sub_ps(row(r), _mm256_set1_ps(q.o[axis])),
                _mm256_set1_ps(q.inv[axis]),
            )
        };
        let near_x = slab(0, q.neg[0]);
        let near_y = slab(1, 2 + q.neg[1]);
        let near_z = slab(2, 4 + q.neg[2]);
        let far_x = slab(0, 1 - q.neg[0]);
        let far_y = slab(1, 3 - q.neg[1]);
        let far_z = slab(2, 5 - q.neg[2]);
        // The slab first: where it were NaN (finite rays give none) maxps/minps return
        // the second operand, the running bound, as f32::max/min do in the portable test.
        let near = _mm256_max_ps(
            near_z,
            _mm256_max_ps(near_y, _mm256_max_ps(near_x, _mm256_set1_ps(q.tmin))),
        );
        let far = _mm256_min_ps(
            far_z,
            _mm256_min_ps(far_y, _mm256_min_ps(far_x, _mm256_set1_ps(tmax))),
        );
        let far = _mm256_mul_ps(far, _mm256_set1_ps(ROBUST_FAR));
        _mm256_storeu_ps(tnear.as_mut_ptr(), near);
        _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far)) as u32
    }
}
