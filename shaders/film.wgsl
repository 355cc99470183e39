// The GPU spmm mode's film, kept on the device (core/gpu/src/film.rs; the CPU's
// core/render/src/film.rs is the reference for every rule here): per layer and pixel
// an f32 running sum of RGB with its sample count in w, per pixel the materials its
// samples shaded and the box of their texture coordinates. Layers are laid out one
// after the other (index layer * pixels + pixel), so the host clears or copies a
// layer as one range. One invocation per pixel; every loop runs over at most
// MAX_LAYERS layers.

struct FilmParams {
    width: u32,
    height: u32,
    layers: u32,
    // Bit l: layer l takes this sample (the scene's active layers).
    active_layers: u32,
    // restart: 1 restarts every pixel, 0 only those flagged in `flags`.
    all: u32,
    // Words per pixel of `aux`.
    aux_words: u32,
    pad1: u32,
    pad2: u32,
    // resolve: the weight of each layer (its emission), rgb.
    weights: array<vec4<f32>, 32>,
}

@group(0) @binding(0) var<uniform> params: FilmParams;
// One dispatch's samples: per pixel, per layer, the RGB sum (integrator.wgsl's `frame`).
@group(0) @binding(1) var<storage, read> frame: array<f32>;
// Per pixel the material mask, texture-coordinate box and sample count of the
// dispatch (its `aux`, `params.aux_words` apart).
@group(0) @binding(2) var<storage, read> aux: array<u32>;
@group(0) @binding(3) var<storage, read_write> sums: array<vec4<f32>>;
// Per pixel: the two words of the material mask, then the box (f32 bits).
@group(0) @binding(4) var<storage, read_write> marks: array<u32>;
// 0: samples dropped for being NaN or infinite; 1: the fewest samples (min_samples).
@group(0) @binding(5) var<storage, read_write> stats: array<atomic<u32>>;
// restart: per pixel, non-zero to restart it.
@group(0) @binding(6) var<storage, read> flags: array<u32>;
// resolve: per pixel the weighted sum of the layers' means, linear RGB.
@group(0) @binding(7) var<storage, read_write> image: array<vec4<f32>>;

const MAX_LAYERS: u32 = 19u;
const MARK_WORDS: u32 = 6u;
const AUX_SAMPLES: u32 = 6u;
// f32 infinity as bits (WGSL has no infinity literal): the empty box's bounds.
const POS_INF: u32 = 0x7f800000u;
const NEG_INF: u32 = 0xff800000u;

fn pixel_of(id: vec3<u32>) -> u32 {
    // 2D dispatch of 64-wide groups (kernel.rs `groups`).
    return id.x + id.y * 65535u * 64u;
}

fn pixels() -> u32 {
    return params.width * params.height;
}

// Finite by its bits: a compiler's fast-math may fold `x != x` away.
fn finite(x: f32) -> bool {
    return (bitcast<u32>(x) & POS_INF) != POS_INF;
}

@compute @workgroup_size(64)
fn accumulate(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = pixel_of(id);
    if p >= pixels() {
        return;
    }
    let a = p * params.aux_words;
    // The adaptive mode's frames shade some pixels, each with its own count.
    let samples = aux[a + AUX_SAMPLES];
    if samples == 0u {
        return;
    }
    let n = min(params.layers, MAX_LAYERS);
    for (var l = 0u; l < n; l++) {
        if (params.active_layers & (1u << l)) == 0u {
            continue;
        }
        let at = (p * params.layers + l) * 3u;
        let v = vec3<f32>(frame[at], frame[at + 1u], frame[at + 2u]);
        if finite(v.x) && finite(v.y) && finite(v.z) {
            let i = l * pixels() + p;
            sums[i] = sums[i] + vec4<f32>(v, f32(samples));
        } else {
            atomicAdd(&stats[0], samples);
        }
    }
    let m = p * MARK_WORDS;
    marks[m] = marks[m] | aux[a];
    marks[m + 1u] = marks[m + 1u] | aux[a + 1u];
    let b = vec4<f32>(
        bitcast<f32>(aux[a + 2u]),
        bitcast<f32>(aux[a + 3u]),
        bitcast<f32>(aux[a + 4u]),
        bitcast<f32>(aux[a + 5u]),
    );
    // The sample's box is empty when it shaded no texture coordinate.
    if b.x <= b.z && b.y <= b.w {
        let old = vec4<f32>(
            bitcast<f32>(marks[m + 2u]),
            bitcast<f32>(marks[m + 3u]),
            bitcast<f32>(marks[m + 4u]),
            bitcast<f32>(marks[m + 5u]),
        );
        marks[m + 2u] = bitcast<u32>(min(old.x, b.x));
        marks[m + 3u] = bitcast<u32>(min(old.y, b.y));
        marks[m + 4u] = bitcast<u32>(max(old.z, b.z));
        marks[m + 5u] = bitcast<u32>(max(old.w, b.w));
    }
}

// Forgets every sample of the flagged pixels (all with `params.all`), with their
// material masks and boxes.
@compute @workgroup_size(64)
fn restart(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = pixel_of(id);
    if p >= pixels() || (params.all == 0u && flags[p] == 0u) {
        return;
    }
    let n = min(params.layers, MAX_LAYERS);
    for (var l = 0u; l < n; l++) {
        sums[l * pixels() + p] = vec4<f32>(0.0);
    }
    let m = p * MARK_WORDS;
    marks[m] = 0u;
    marks[m + 1u] = 0u;
    marks[m + 2u] = POS_INF;
    marks[m + 3u] = POS_INF;
    marks[m + 4u] = NEG_INF;
    marks[m + 5u] = NEG_INF;
}

// The fewest samples of any active layer at any pixel, into stats[1] (which the host
// sets to the largest u32 first).
@compute @workgroup_size(64)
fn min_samples(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = pixel_of(id);
    if p >= pixels() {
        return;
    }
    var fewest = 0xffffffffu;
    let n = min(params.layers, MAX_LAYERS);
    for (var l = 0u; l < n; l++) {
        if (params.active_layers & (1u << l)) != 0u {
            fewest = min(fewest, u32(sums[l * pixels() + p].w));
        }
    }
    atomicMin(&stats[1], fewest);
}

// Per pixel the sum over layers of weight times mean (a layer without samples, or of
// weight zero, adds nothing), as the CPU film's `resolve`.
@compute @workgroup_size(64)
fn resolve(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = pixel_of(id);
    if p >= pixels() {
        return;
    }
    var v = vec3<f32>(0.0);
    let n = min(params.layers, MAX_LAYERS);
    for (var l = 0u; l < n; l++) {
        let s = sums[l * pixels() + p];
        let w = params.weights[l].xyz;
        if s.w > 0.0 && any(w != vec3<f32>(0.0)) {
            v += w * (s.xyz / s.w);
        }
    }
    image[p] = vec4<f32>(v, 1.0);
}
