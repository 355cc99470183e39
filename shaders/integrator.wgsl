// The spmm mode's integrator on the GPU, one invocation per pixel and one sample per
// dispatch (core/modes/src/trace/integrator.rs is the reference): a jittered primary ray,
// perfect mirrors up to the scene's depth, then at the first other surface the
// lights, ambient occlusion (lights.wgsl) with the materials' response (brdf.wgsl,
// spmm.wgsl). Each emitter's contribution goes to its own layer for unit emission;
// the CPU adds the layers to its f64 film, so film semantics are the CPU's.
// Random numbers: the CPU's sampler and dimension layout (sampler.wgsl).

struct Params {
    width: u32,
    height: u32,
    layers: u32,
    seed: u32,
    sample_lo: u32,
    sample_hi: u32,
    max_depth: u32,
    moving: u32,
    lights: u32,
    light_table: u32,
    material_table: u32,
    // What rays that leave the scene add (environment.wgsl, ESCAPE_*).
    background: u32,
    // Negative: no ambient term.
    ambient_radius: f32,
    materials: u32,
    // 1: more lights than the exact path's 16, chosen stochastically (lights.wgsl).
    stochastic: u32,
    // Points per area light per shading point (`[render] light_samples`, 1..=64);
    // above 16 lights, that many chosen lights.
    light_samples: u32,
    // `[render] sampler` (SAMPLER_*), then padding to the vectors' alignment.
    sampler: u32,
    // Where the biscale words start in `env` (biscale.wgsl); 0 for the spmm mode.
    biscale: u32,
    // Words per pixel of `aux` (the film's, core/gpu/src/film.rs).
    aux_words: u32,
    pad2: u32,
    cam_origin: vec4<f32>,
    // w: half the image plane's width at distance 1.
    cam_forward: vec4<f32>,
    // w: half its height.
    cam_right: vec4<f32>,
    cam_up: vec4<f32>,
    // Each layer's weight (its emission, RGB): the adaptive mode's luminance moments.
    weights: array<vec4<f32>, 19>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> nodes: array<u32>;
@group(0) @binding(2) var<storage, read> tris: array<u32>;
@group(0) @binding(3) var<storage, read> shade: array<f32>;
@group(0) @binding(4) var<storage, read> data: array<u32>;
// Per pixel, per layer, RGB of this dispatch's sample.
@group(0) @binding(5) var<storage, read_write> frame: array<f32>;
// Per pixel (`params.aux_words` apart): the materials shaded (two words of the 64-bit
// mask), the box of the SPMM texture coordinates shaded (min u, min v, max u, max v as
// f32 bits) and the samples the dispatch added (AUX_SAMPLES); the adaptive mode keeps
// its plan's words after them (adaptive.wgsl).
@group(0) @binding(6) var<storage, read_write> aux: array<u32>;
@group(0) @binding(7) var<storage, read_write> counters: array<atomic<u32>>;
// The environment map, its sampling tables and the background image (environment.wgsl).
@group(0) @binding(8) var<storage, read> env: array<u32>;

const MAX_LAYERS: u32 = 19u;
const LAYER_BACKGROUND: u32 = 0u;
const LAYER_AMBIENT: u32 = 1u;
const AUX_SAMPLES: u32 = 6u;
const SHADE_FLOATS: u32 = 16u;
const MATERIAL_WORDS: u32 = 8u;
const MATERIAL_BRDF: u32 = 0u;
const MATERIAL_SPMM: u32 = 1u;
const MATERIAL_MIRROR: u32 = 2u;
const MATERIAL_MERL: u32 = 3u;
const MATERIAL_BTF: u32 = 4u;
// Counter slots after the traversal's two.
const COUNT_PRIMARY: u32 = 2u;
const COUNT_SHADOW: u32 = 3u;
const COUNT_AMBIENT: u32 = 4u;
const COUNT_SPECULAR: u32 = 5u;
const COUNT_SHADING: u32 = 6u;
const EPSILON_REL: f32 = 1e-5;
// Rec. 709 luminance (the adaptive mode's moments and bandwidth pass).
const LUMINANCE: vec3<f32> = vec3<f32>(0.2126, 0.7152, 0.0722);
// f32 infinity as bits (WGSL has no infinity literal): a ray's depth where it missed.
const F32_INFINITY_BITS: u32 = 0x7f800000u;

struct Counts {
    shadow: u32,
    ambient: u32,
    specular: u32,
    shading: u32,
    environment: u32,
}

var<private> acc: array<vec3<f32>, MAX_LAYERS>;
var<private> counts: Counts;
var<private> mask: vec2<u32>;
var<private> uv_box: vec4<f32>;

fn add_layer(pixel: u32, layer: u32, v: vec3<f32>) {
    if layer < MAX_LAYERS {
        acc[layer] += v;
    }
}

struct Shading {
    p: vec3<f32>,
    t: vec3<f32>,
    b: vec3<f32>,
    n: vec3<f32>,
    uv: vec2<f32>,
    material: u32,
}

fn material_kind(m: u32) -> u32 {
    return data[params.material_table + m * MATERIAL_WORDS];
}

fn normalize_or(v: vec3<f32>, fallback: vec3<f32>) -> vec3<f32> {
    let l2 = dot(v, v);
    if l2 > 1e-36 && l2 < 3.0e38 {
        return v * inverseSqrt(l2);
    }
    return fallback;
}

fn shade_vec(at: u32) -> vec3<f32> {
    return vec3<f32>(shade[at], shade[at + 1u], shade[at + 2u]);
}

// The barycentric coordinates (of vertices 1 and 2) of point `p` on primitive `prim`,
// clamped into the triangle.
fn barycentrics(prim: u32, p: vec3<f32>) -> vec2<f32> {
    let p0 = tri_vertex(prim, 0u);
    let e1 = tri_vertex(prim, 1u) - p0;
    let e2 = tri_vertex(prim, 2u) - p0;
    let ep = p - p0;
    let d11 = dot(e1, e1);
    let d12 = dot(e1, e2);
    let d22 = dot(e2, e2);
    let dp1 = dot(ep, e1);
    let dp2 = dot(ep, e2);
    let denom = d11 * d22 - d12 * d12;
    var b1 = 0.0;
    var b2 = 0.0;
    if denom > 0.0 {
        b1 = (d22 * dp1 - d12 * dp2) / denom;
        b2 = (d11 * dp2 - d12 * dp1) / denom;
    }
    b1 = clamp(b1, 0.0, 1.0);
    return vec2<f32>(b1, clamp(b2, 0.0, 1.0 - b1));
}

// `trace::shading::shading_at`: interpolated normal turned to the viewer, tangent
// along +u, for a hit at distance `t` on leaf primitive `prim`.
fn shading_at(prim: u32, o: vec3<f32>, dir: vec3<f32>, t: f32) -> Shading {
    let p0 = tri_vertex(prim, 0u);
    let p1 = tri_vertex(prim, 1u);
    let p2 = tri_vertex(prim, 2u);
    let e1 = p1 - p0;
    let e2 = p2 - p0;
    let b = barycentrics(prim, o + dir * t);
    let b1 = b.x;
    let b2 = b.y;
    let w0 = 1.0 - b1 - b2;
    let sp = p0 * w0 + p1 * b1 + p2 * b2;
    var ng = normalize_or(cross(e1, e2), vec3<f32>(0.0, 1.0, 0.0));
    if dot(ng, dir) > 0.0 {
        ng = -ng;
    }
    let sh = prim * SHADE_FLOATS;
    var n = normalize_or(shade_vec(sh) * w0 + shade_vec(sh + 3u) * b1 + shade_vec(sh + 6u) * b2, ng);
    if dot(n, ng) < 0.0 {
        n = -n;
    }
    let uv0 = vec2<f32>(shade[sh + 9u], shade[sh + 10u]);
    let uv1 = vec2<f32>(shade[sh + 11u], shade[sh + 12u]);
    let uv2 = vec2<f32>(shade[sh + 13u], shade[sh + 14u]);
    let uv = uv0 * w0 + uv1 * b1 + uv2 * b2;
    let d1 = uv1 - uv0;
    let d2 = uv2 - uv0;
    let det = d1.x * d2.y - d2.x * d1.y;
    var dpdu = vec3<f32>(0.0);
    if abs(det) > 1e-20 {
        dpdu = (e1 * d2.y - e2 * d1.y) / det;
    }
    let tangent = normalize_or(dpdu - n * dot(n, dpdu), orthonormal_tangent(n));
    return Shading(sp, tangent, cross(n, tangent), n, uv, tris[prim * TRI_WORDS + 9u]);
}

// The first vector of `warp::orthonormal_basis` (Duff et al. 2017).
fn orthonormal_tangent(n: vec3<f32>) -> vec3<f32> {
    let sign = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    return vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
}

// The material's response to light from `wi` seen from `wo` (world, unit), cosine
// included: albedo f cos_i for BRDFs, the BTF for SPMM packs.
fn response(s: Shading, wi: vec3<f32>, wo: vec3<f32>) -> vec3<f32> {
    let li = vec3<f32>(dot(wi, s.t), dot(wi, s.b), dot(wi, s.n));
    let lo = vec3<f32>(dot(wo, s.t), dot(wo, s.b), dot(wo, s.n));
    let at = params.material_table + s.material * MATERIAL_WORDS;
    let kind = data[at];
    if kind == MATERIAL_BRDF {
        return rgb_at(at + 4u) * (brdf_eval(load_brdf(data[at + 1u]), li, lo) * max(li.z, 0.0));
    }
    if kind == MATERIAL_SPMM {
        let m = data[at + 1u];
        // A moving camera keeps the residual's mean and first MOVING_NPCA components.
        let components = select(ALL_COMPONENTS, MOVING_NPCA, params.moving != 0u);
        return spmm_eval_texel(m, spmm_texel_at(m, s.uv), li, lo, data[at + 2u] != 0u, components);
    }
    if kind == MATERIAL_MERL {
        return rgb_at(at + 4u) * merl_eval(data[at + 1u], li, lo) * max(li.z, 0.0);
    }
    if kind == MATERIAL_BTF {
        let m = data[at + 1u];
        return btf_eval_texel(m, btf_texel_at(m, s.uv), li, lo);
    }
    return vec3<f32>(0.0);
}

// The invocation's pixel: rows of workgroups beyond 65,535 (core/gpu/src/kernel.rs,
// `groups`).
fn pixel_of_invocation(id: vec3<u32>, groups: vec3<u32>) -> u32 {
    return id.x + id.y * groups.x * 64u;
}

// The direction of the camera ray through `pixel` at `jitter` within it (0.5, 0.5: its
// centre).
fn camera_dir(pixel: u32, jitter: vec2<f32>) -> vec3<f32> {
    let x = pixel % params.width;
    let y = pixel / params.width;
    let sx = ((f32(x) + jitter.x) / f32(params.width)) * 2.0 - 1.0;
    let sy = 1.0 - ((f32(y) + jitter.y) / f32(params.height)) * 2.0;
    return normalize(params.cam_forward.xyz + params.cam_right.xyz * (sx * params.cam_forward.w)
        + params.cam_up.xyz * (sy * params.cam_right.w));
}

// A sample's state cleared (layers, counts, material mask, texture box) and its
// random numbers.
fn start_sample(pixel: u32) -> Rng {
    for (var l = 0u; l < MAX_LAYERS; l++) {
        acc[l] = vec3<f32>(0.0);
    }
    counts = Counts(0u, 0u, 0u, 0u, 0u);
    mask = vec2<u32>(0u);
    uv_box = vec4<f32>(3.4e38, 3.4e38, -3.4e38, -3.4e38);
    return rng_for_sample(params.sampler, params.seed, params.sample_lo, params.sample_hi, pixel);
}

// What a ray along `dir` that leaves the scene adds (ESCAPE_*).
fn add_escape(pixel: u32, throughput: vec3<f32>, dir: vec3<f32>) {
    switch params.background {
        case ESCAPE_COLOR: {
            add_layer(pixel, LAYER_BACKGROUND, throughput);
        }
        case ESCAPE_IMAGE: {
            add_layer(pixel, LAYER_BACKGROUND, throughput * background_radiance(dir));
        }
        case ESCAPE_ENVIRONMENT: {
            add_layer(pixel, LAYER_ENVIRONMENT, throughput * env_radiance(dir));
        }
        default: {}
    }
}

// Marks material `m` as shaded by this sample (the film's per-pixel mask).
fn mark_material(m: u32) {
    let bit = m % 64u;
    if bit < 32u {
        mask.x |= 1u << bit;
    } else {
        mask.y |= 1u << (bit - 32u);
    }
}

// The hit point moved off the surface along its normal, where secondary rays start.
fn lifted(s: Shading) -> vec3<f32> {
    let ap = abs(s.p);
    return s.p + s.n * (EPSILON_REL * max(max(max(ap.x, ap.y), ap.z), 1.0));
}

// Writes the dispatch's layers (the sum of its `samples` samples), marks and counts.
fn finish_sample(pixel: u32, samples: u32) {
    let layers = min(params.layers, MAX_LAYERS);
    for (var l = 0u; l < layers; l++) {
        let at = (pixel * params.layers + l) * 3u;
        frame[at] = acc[l].x;
        frame[at + 1u] = acc[l].y;
        frame[at + 2u] = acc[l].z;
    }
    let a = pixel * params.aux_words;
    aux[a] = mask.x;
    aux[a + 1u] = mask.y;
    aux[a + 2u] = bitcast<u32>(uv_box.x);
    aux[a + 3u] = bitcast<u32>(uv_box.y);
    aux[a + 4u] = bitcast<u32>(uv_box.z);
    aux[a + 5u] = bitcast<u32>(uv_box.w);
    aux[a + AUX_SAMPLES] = samples;
    atomicAdd(&counters[COUNT_PRIMARY], samples);
    atomicAdd(&counters[COUNT_SHADOW], counts.shadow);
    atomicAdd(&counters[COUNT_AMBIENT], counts.ambient);
    atomicAdd(&counters[COUNT_SPECULAR], counts.specular);
    atomicAdd(&counters[COUNT_SHADING], counts.shading);
    atomicAdd(&counters[COUNT_ENVIRONMENT], counts.environment);
}

// What a camera ray found past the mirrors: the first other surface, with the ray
// that reached it and the mirrors' reflectance along the way.
struct Reached {
    found: bool,
    s: Shading,
    prim: u32,
    t: f32,
    origin: vec3<f32>,
    dir: vec3<f32>,
    throughput: vec3<f32>,
}

// The jittered camera ray through `pixel`, followed through perfect mirrors up to the
// scene's depth to the first other surface (marked, its texture coordinate boxed); a
// ray that leaves the scene adds what it sees there.
fn first_surface(pixel: u32, rng: ptr<function, Rng>) -> Reached {
    var origin = params.cam_origin.xyz;
    var dir = camera_dir(pixel, rand2(rng));
    var throughput = vec3<f32>(1.0);
    let max_depth = min(params.max_depth, 64u);
    for (var depth = 0u; depth <= max_depth; depth++) {
        let hit = traverse(make_ray(origin, dir, 0.0, FAR), false);
        if hit.prim == NO_HIT {
            add_escape(pixel, throughput, dir);
            break;
        }
        let s = shading_at(hit.prim, origin, dir, hit.t);
        mark_material(s.material);
        let kind = material_kind(s.material);
        if kind == MATERIAL_SPMM {
            uv_box = vec4<f32>(min(uv_box.xy, s.uv), max(uv_box.zw, s.uv));
        }
        if kind == MATERIAL_MIRROR {
            if depth >= params.max_depth {
                break;
            }
            counts.specular += 1u;
            throughput *= rgb_at(params.material_table + s.material * MATERIAL_WORDS + 4u);
            dir = dir - 2.0 * dot(dir, s.n) * s.n;
            origin = lifted(s);
            continue;
        }
        counts.shading += 1u;
        return Reached(true, s, hit.prim, hit.t, origin, dir, throughput);
    }
    return Reached(false, Shading(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec2<f32>(0.0), 0u), NO_HIT, 0.0, origin, dir, throughput);
}

// One sample of the spmm estimator at `pixel`: the lights, the ambient term and the
// environment at the first surface past the mirrors, into `acc`.
fn spmm_sample(pixel: u32, rng: ptr<function, Rng>) {
    let r = first_surface(pixel, rng);
    if !r.found {
        return;
    }
    let wo = -r.dir;
    let lift = lifted(r.s);
    sample_lights(r.s, wo, lift, r.throughput, pixel, rng);
    sample_ambient(r.s, wo, lift, r.throughput, pixel, rng);
    sample_environment(r.s, wo, lift, r.throughput, pixel, rng);
}

@compute @workgroup_size(64)
fn render(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = pixel_of_invocation(id, groups);
    if pixel >= params.width * params.height {
        return;
    }
    var rng = start_sample(pixel);
    spmm_sample(pixel, &rng);
    finish_sample(pixel, 1u);
}
