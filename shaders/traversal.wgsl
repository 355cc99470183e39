// Closest-hit and any-hit traversal of obvhs's compressed wide BVH (Ylitie et al.
// 2017), following obvhs 0.4's CPU traversal (`traverse!`, `CwBvhNode::intersect_ray`,
// `Triangle::intersect`) step for step, so hits equal the CPU's. The nodes are
// obvhs's 80-byte records as they are (20 words); triangles are f32 in leaf order
// (12 words: v0, v1, v2, material, mesh, triangle), not obvhs's f16-edge
// `RtCompressedTriangle`, whose rounded edges would not reproduce the CPU's hits.
// Bounded: a traversal stack of 32 entries (obvhs's depth bound) and MAX_STEPS node
// visits; anything past either bound is counted in `counters`, never silent.
// Needs bindings `nodes`, `tris` (array<u32>) and `counters` (array<atomic<u32>>).

const NODE_WORDS: u32 = 20u;
const TRI_WORDS: u32 = 12u;
const STACK_SIZE: u32 = 32u;
const MAX_STEPS: u32 = 8192u;
const NO_HIT: u32 = 0xffffffffu;
const NODE_EPSILON: f32 = 0.0001;
const F32_EPSILON: f32 = 1.1920929e-7;
// The farthest distance a ray reaches ("infinity"), and the distance of a miss.
const FAR: f32 = 3.0e38;
const FAR_MISS: f32 = 3.4e38;
// Counter slots: stack overflows, step-bound exhaustions.
const COUNT_STACK_OVERFLOW: u32 = 0u;
const COUNT_STEP_OVERFLOW: u32 = 1u;

struct Ray {
    o: vec3<f32>,
    d: vec3<f32>,
    inv: vec3<f32>,
    tmin: f32,
    tmax: f32,
}

struct TraceHit {
    t: f32,
    // Leaf-order primitive, NO_HIT on a miss.
    prim: u32,
}

fn safe_inverse(x: f32) -> f32 {
    if abs(x) <= F32_EPSILON {
        // Rust's signum: +0 is positive, -0 negative.
        let s = select(1.0, -1.0, (bitcast<u32>(x) & 0x80000000u) != 0u);
        return s / F32_EPSILON;
    }
    return 1.0 / x;
}

// `tmax` at most FAR: WGSL may assume no infinities, and a miss is FAR_MISS > FAR.
fn make_ray(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> Ray {
    return Ray(o, d, vec3<f32>(safe_inverse(d.x), safe_inverse(d.y), safe_inverse(d.z)), tmin, min(tmax, FAR));
}

fn octant_inv4(d: vec3<f32>) -> u32 {
    return select(0x04040404u, 0u, d.x < 0.0) | select(0x02020202u, 0u, d.y < 0.0)
        | select(0x01010101u, 0u, d.z < 0.0);
}

fn node_byte(node: u32, word: u32, i: u32) -> u32 {
    return (nodes[node * NODE_WORDS + word + i / 4u] >> ((i % 4u) * 8u)) & 0xffu;
}

fn tri_vertex(prim: u32, v: u32) -> vec3<f32> {
    let at = prim * TRI_WORDS + 3u * v;
    return vec3<f32>(bitcast<f32>(tris[at]), bitcast<f32>(tris[at + 1u]), bitcast<f32>(tris[at + 2u]));
}

// `Triangle::intersect` (Moeller-Trumbore, both faces); FAR_MISS on a miss.
fn intersect_triangle(prim: u32, ray: Ray) -> f32 {
    let v0 = tri_vertex(prim, 0u);
    let v1 = tri_vertex(prim, 1u);
    let v2 = tri_vertex(prim, 2u);
    let e1 = v0 - v1;
    let e2 = v2 - v0;
    let n = cross(e1, e2);
    let c = v0 - ray.o;
    let r = cross(ray.d, c);
    let inv_det = 1.0 / dot(n, ray.d);
    let u = dot(r, e2) * inv_det;
    let v = dot(r, e1) * inv_det;
    let w = 1.0 - u - v;
    let signs = bitcast<u32>(u) | bitcast<u32>(v) | bitcast<u32>(w);
    if inv_det != 0.0 && (signs & 0x80000000u) == 0u {
        let t = dot(n, c) * inv_det;
        if t >= ray.tmin && t <= ray.tmax {
            return t;
        }
    }
    return FAR_MISS;
}

// `CwBvhNode::intersect_ray`: the hit mask of a node's children (inner children in
// the high byte by traversal priority, leaf primitives in the low 24 bits).
fn intersect_node(node: u32, ray: Ray, oct_inv4: u32) -> u32 {
    let at = node * NODE_WORDS;
    let p = vec3<f32>(bitcast<f32>(nodes[at]), bitcast<f32>(nodes[at + 1u]), bitcast<f32>(nodes[at + 2u]));
    let ew = nodes[at + 3u];
    let extent = vec3<f32>(
        bitcast<f32>((ew & 0xffu) << 23u),
        bitcast<f32>(((ew >> 8u) & 0xffu) << 23u),
        bitcast<f32>(((ew >> 16u) & 0xffu) << 23u));
    let adj_inv = extent * ray.inv;
    let adj_o = (p - ray.o) * ray.inv;
    let neg = ray.d < vec3<f32>(0.0);
    let oct = oct_inv4 & 0xffu;
    var hit_mask = 0u;
    for (var child = 0u; child < 8u; child++) {
        let child_meta = node_byte(node, 6u, child);
        let lo = vec3<f32>(f32(node_byte(node, 8u, child)), f32(node_byte(node, 12u, child)), f32(node_byte(node, 16u, child)));
        let hi = vec3<f32>(f32(node_byte(node, 10u, child)), f32(node_byte(node, 14u, child)), f32(node_byte(node, 18u, child)));
        let qmin = select(lo, hi, neg);
        let qmax = select(hi, lo, neg);
        let tmin3 = qmin * adj_inv + adj_o;
        let tmax3 = qmax * adj_inv + adj_o;
        let tmin = max(max(max(tmin3.x, tmin3.y), tmin3.z), NODE_EPSILON);
        let tmax = min(min(min(tmax3.x, tmax3.y), tmax3.z), ray.tmax);
        if tmin <= tmax {
            let inner = ((child_meta & (child_meta << 1u)) & 0x10u) != 0u;
            let bit_index = (child_meta ^ select(0u, oct, inner)) & 0x1fu;
            let child_bits = (child_meta >> 5u) & 0x7u;
            hit_mask |= child_bits << bit_index;
        }
    }
    return hit_mask;
}

// The closest hit in [tmin, tmax] (`any_hit`: the first found, for shadow rays).
fn traverse(ray_in: Ray, any_hit: bool) -> TraceHit {
    var ray = ray_in;
    var hit = TraceHit(ray.tmax, NO_HIT);
    // A scene without triangles (the buffer holds only its 16-byte minimum).
    if arrayLength(&tris) < TRI_WORDS {
        return hit;
    }
    let oct_inv4 = octant_inv4(ray.d);
    var stack: array<vec2<u32>, STACK_SIZE>;
    var sp = 0u;
    var current = vec2<u32>(0u, 0x80000000u);
    var prims = vec2<u32>(0u, 0u);
    for (var step = 0u; step < MAX_STEPS; step++) {
        for (var k = 0u; k < 24u; k++) {
            if prims.y == 0u {
                break;
            }
            let local = firstLeadingBit(prims.y);
            prims.y &= ~(1u << local);
            let id = prims.x + local;
            let t = intersect_triangle(id, ray);
            if t < ray.tmax {
                hit = TraceHit(t, id);
                if any_hit {
                    return hit;
                }
                ray.tmax = t;
            }
        }
        prims = vec2<u32>(0u, 0u);
        if (current.y & 0xff000000u) != 0u {
            let hits_imask = current.y;
            let offset = firstLeadingBit(hits_imask);
            current.y &= ~(1u << offset);
            if (current.y & 0xff000000u) != 0u {
                if sp < STACK_SIZE {
                    stack[sp] = current;
                    sp += 1u;
                } else {
                    atomicAdd(&counters[COUNT_STACK_OVERFLOW], 1u);
                }
            }
            let slot = (offset - 24u) ^ (oct_inv4 & 0xffu);
            let relative = countOneBits(hits_imask & ~(0xffffffffu << slot));
            let node = current.x + relative;
            let mask = intersect_node(node, ray, oct_inv4);
            let at = node * NODE_WORDS;
            current = vec2<u32>(nodes[at + 4u], (mask & 0xff000000u) | (nodes[at + 3u] >> 24u));
            prims = vec2<u32>(nodes[at + 5u], mask & 0x00ffffffu);
        } else {
            current = vec2<u32>(0u, 0u);
        }
        if prims.y == 0u && (current.y & 0xff000000u) == 0u {
            if sp == 0u {
                return hit;
            }
            sp -= 1u;
            current = stack[sp];
        }
    }
    atomicAdd(&counters[COUNT_STEP_OVERFLOW], 1u);
    return hit;
}

fn occluded(o: vec3<f32>, d: vec3<f32>, tmax: f32) -> bool {
    return traverse(make_ray(o, d, 0.0, tmax), true).prim != NO_HIT;
}
