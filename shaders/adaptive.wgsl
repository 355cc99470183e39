// The adaptive mode's frames on the device (core/modes/src/adaptive/ is the reference
// for every rule here): the bandwidth buffer's min/max pyramids, each frame's plan
// (which pixels are shaded, with how many samples: `frame.rs` `plan_frame`,
// `allocation.rs`), the pixels' own sample counts and luminance moments after the
// frame, and the coarse-to-fine up-sampling of the image (`upsample.rs`). The
// samples themselves are `adaptive_render.wgsl`'s, in the integrator's module.
// One invocation per pixel (or block); every loop is bounded.

struct AdaptiveParams {
    width: u32,
    height: u32,
    // The coarsest pyramid level: min(floor(log2 W), floor(log2 H)).
    top: u32,
    // The frame being planned or committed (frames since the last restart).
    frame: u32,
    // Levels dropped so far: frame / refine_frames.
    drop: u32,
    // The level a `mip_level` or `upsample` dispatch works on.
    level: u32,
    // Words per pixel of the film's `aux` buffer.
    aux_words: u32,
    pad0: u32,
    // Samples per shaded pixel per frame on average, the most and the fewest (all
    // times samples per frame).
    mean_samples: f32,
    max_samples: f32,
    floor_samples: f32,
    pad1: f32,
}

@group(0) @binding(0) var<uniform> ap: AdaptiveParams;
// Per pixel (INPUT_WORDS): eq. 11's level, the predicted deviation sigma, the guide:
// depth (f32 infinity on a miss), the projected normal's direction, |cos|, and the
// pass's mean of the estimator.
@group(0) @binding(1) var<storage, read> inputs: array<u32>;
// Per level k and block of 2^k pixels (MIP_WORDS): min level, max sigma.
@group(0) @binding(2) var<storage, read_write> mips: array<u32>;
// Per pixel (STATE_WORDS): own samples, added after the first frame (0/1), and the
// luminance moments of its own samples: count, mean, M2 (Welford, as f32 bits).
@group(0) @binding(3) var<storage, read_write> state: array<u32>;
// The film's per-pixel `aux` words (integrator.wgsl): AUX_PLANNED is the frame's
// samples, AUX_FIRST the index of its first, AUX_SAMPLES and AUX_MOMENTS the count and
// moments of the last dispatch's, AUX_SIGMA the plan's block deviation (negative: not a
// site).
@group(0) @binding(4) var<storage, read_write> aux: array<u32>;
// [0], [1]: the sites' summed sigma and count, then the most samples a pixel takes
// (`most`); from 2 on, per workgroup of `plan` (of `counts`).
@group(0) @binding(5) var<storage, read_write> partials: array<f32>;
// The resolved image (vec4 per pixel), up-sampled in place.
@group(0) @binding(6) var<storage, read_write> image: array<vec4<f32>>;

const INPUT_WORDS: u32 = 7u;
const MIP_WORDS: u32 = 2u;
const STATE_WORDS: u32 = 5u;
const AUX_SAMPLES: u32 = 6u;
const AUX_FIRST: u32 = 7u;
const AUX_MOMENTS: u32 = 8u;
const AUX_SIGMA: u32 = 11u;
const AUX_PLANNED: u32 = 12u;
// allocation::PREDICTION_WEIGHT.
const PREDICTION_WEIGHT: f32 = 16.0;
// upsample::DEPTH_SIGMA, MIN_WEIGHT, MATURE_SAMPLES.
const DEPTH_SIGMA: f32 = 0.05;
const MIN_WEIGHT: f32 = 1e-3;
const MATURE_SAMPLES: u32 = 32u;
const POS_INF: u32 = 0x7f800000u;

var<workgroup> wg_sum: array<f32, 64>;
var<workgroup> wg_count: array<f32, 64>;

fn pixels() -> u32 {
    return ap.width * ap.height;
}

fn index_of(id: vec3<u32>) -> u32 {
    // 2D dispatch of 64-wide groups (kernel.rs `groups`).
    return id.x + id.y * 65535u * 64u;
}

fn is_infinite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) == POS_INF;
}

// Blocks of 2^k pixels across and down.
fn blocks(k: u32) -> vec2<u32> {
    let s = 1u << k;
    return vec2<u32>((ap.width + s - 1u) / s, (ap.height + s - 1u) / s);
}

// Where level k's blocks start in `mips`.
fn mip_offset(k: u32) -> u32 {
    var at = 0u;
    for (var j = 0u; j < min(k, 31u); j++) {
        let b = blocks(j);
        at += b.x * b.y;
    }
    return at;
}

fn mip_block(k: u32, x: u32, y: u32) -> u32 {
    return (mip_offset(k) + (y >> k) * blocks(k).x + (x >> k)) * MIP_WORDS;
}

fn depth_of(i: u32) -> f32 {
    return bitcast<f32>(inputs[i * INPUT_WORDS + 2u]);
}

// g_z: 1 for equal depths (two misses are equal), 0 between a surface and a miss.
fn depth_weight(z: f32, zi: f32) -> f32 {
    let a = is_infinite(z);
    let b = is_infinite(zi);
    if a || b {
        return select(0.0, 1.0, a && b);
    }
    let rel = (z - zi) / (DEPTH_SIGMA * max(abs(z), 1e-12));
    return exp(-rel * rel);
}

// g_a: the anisotropic screen-space Gaussian of the projected normal.
fn screen_weight(v: vec2<f32>, normal_dir: vec2<f32>, cos_x: f32) -> f32 {
    let along = dot(v, normal_dir);
    let across2 = dot(v, v) - along * along;
    let c = max(cos_x, 0.05);
    return exp(-(across2 + along * along / (c * c)));
}

// The finest level pixel (x, y) lies on, capped at `top`.
fn level_of_pixel(x: u32, y: u32) -> u32 {
    return min(countTrailingZeros(x | y), ap.top);
}

struct Parents {
    index: array<u32, 4>,
    // alpha g_z (has_parents) and the full weight (upsample).
    alpha_gz: array<f32, 4>,
    weight: array<f32, 4>,
    n: u32,
}

// Along one axis (`upsample::far_parent`): the far parent's coordinate, the fraction
// of the way to it, and whether the image's last column (row) stands in for a grid
// point past the image.
struct FarParent {
    at: u32,
    t: f32,
    edge: bool,
}

// The far parent of `c` whose near parent is `c0` on a grid of spacing `s`, along an
// axis of `size` pixels.
fn far_parent(c: u32, c0: u32, s: u32, size: u32) -> FarParent {
    let last = size - 1u;
    if c0 + s > last && c < last && c > c0 {
        return FarParent(last, f32(c - c0) / f32(last - c0), true);
    }
    return FarParent(c0 + s, f32(c - c0) / f32(s), false);
}

// `upsample::is_edge`: the last column and row, shaded at every frame.
fn is_edge(x: u32, y: u32) -> bool {
    return x + 1u == ap.width || y + 1u == ap.height;
}

// The level-(k+1) parents of pixel (x, y) (`upsample::parents`); with `check_edges`,
// an edge pixel standing in for a parent past the image counts only once it has
// samples of its own (the frames shade the edges from the first frame, so it is
// trusted then, as the CPU's `has_value`).
fn parents(x: u32, y: u32, k: u32, check_edges: bool) -> Parents {
    var out: Parents;
    out.n = 0u;
    let s = 1u << (k + 1u);
    let x0 = x / s * s;
    let y0 = y / s * s;
    let fx_far = far_parent(x, x0, s, ap.width);
    let fy_far = far_parent(y, y0, s, ap.height);
    let fx = fx_far.t;
    let fy = fy_far.t;
    let i = y * ap.width + x;
    let at = i * INPUT_WORDS;
    let nd = vec2<f32>(bitcast<f32>(inputs[at + 3u]), bitcast<f32>(inputs[at + 4u]));
    let cos_x = bitcast<f32>(inputs[at + 5u]);
    for (var c = 0u; c < 4u; c++) {
        let far_x = (c & 1u) != 0u;
        let far_y = (c >> 1u) != 0u;
        let alpha = select(1.0 - fx, fx, far_x) * select(1.0 - fy, fy, far_y);
        let px = select(x0, fx_far.at, far_x);
        let py = select(y0, fy_far.at, far_y);
        if alpha == 0.0 || px >= ap.width || py >= ap.height {
            continue;
        }
        let j = py * ap.width + px;
        let edge = (far_x && fx_far.edge) || (far_y && fy_far.edge);
        if check_edges && edge && state[j * STATE_WORDS] == 0u {
            continue;
        }
        let gz = depth_weight(depth_of(i), depth_of(j));
        let v = vec2<f32>(f32(px) - f32(x), f32(py) - f32(y)) / f32(s);
        let ga = screen_weight(v, nd, cos_x);
        out.index[out.n] = j;
        out.alpha_gz[out.n] = alpha * gz;
        out.weight[out.n] = alpha * gz * ga;
        out.n += 1u;
    }
    return out;
}

fn has_parents(x: u32, y: u32, k: u32) -> bool {
    let p = parents(x, y, k, false);
    var sum = 0.0;
    for (var c = 0u; c < p.n; c++) {
        sum += p.alpha_gz[c];
    }
    return sum >= MIN_WEIGHT;
}

// Level 0 of the pyramids: each pixel's level and sigma.
@compute @workgroup_size(64)
fn mip_base(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = index_of(id);
    if i >= pixels() {
        return;
    }
    mips[i * MIP_WORDS] = inputs[i * INPUT_WORDS];
    mips[i * MIP_WORDS + 1u] = inputs[i * INPUT_WORDS + 1u];
}

// Level `ap.level` of the pyramids from the level below: the min of the levels and
// the max of the sigmas of a block's (up to four) children.
@compute @workgroup_size(64)
fn mip_level(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = ap.level;
    let b = blocks(k);
    let i = index_of(id);
    if i >= b.x * b.y || k == 0u {
        return;
    }
    let x = i % b.x;
    let y = i / b.x;
    let below = blocks(k - 1u);
    let first = mip_offset(k - 1u);
    var level = 0xffffffffu;
    var sigma = 0.0;
    for (var c = 0u; c < 4u; c++) {
        let sx = 2u * x + (c & 1u);
        let sy = 2u * y + (c >> 1u);
        if sx < below.x && sy < below.y {
            let at = (first + sy * below.x + sx) * MIP_WORDS;
            level = min(level, mips[at]);
            sigma = max(sigma, bitcast<f32>(mips[at + 1u]));
        }
    }
    let at = (mip_offset(k) + i) * MIP_WORDS;
    mips[at] = level;
    mips[at + 1u] = bitcast<u32>(sigma);
}

// `allocation::corrected_sigma`: the prediction pooled with the pixel's own samples'
// variance, the prediction counted as PREDICTION_WEIGHT samples; a single sample
// measures its squared distance from the pass's mean on one degree of freedom.
fn corrected_sigma(predicted: f32, i: u32) -> f32 {
    let n = state[i * STATE_WORDS + 2u];
    if n == 0u {
        return predicted;
    }
    var m2 = bitcast<f32>(state[i * STATE_WORDS + 4u]);
    var dof = f32(n - 1u);
    if n == 1u {
        let d = bitcast<f32>(state[i * STATE_WORDS + 3u]) - bitcast<f32>(inputs[i * INPUT_WORDS + 6u]);
        m2 = d * d;
        dof = 1.0;
    }
    return sqrt(max((PREDICTION_WEIGHT * predicted * predicted + m2) / (PREDICTION_WEIGHT + dof), 0.0));
}

// The frame's sites (`plan_frame`): per pixel the leaf block it heads (the largest k
// whose 2^k block's min level, less the levels dropped, is at least k) or, off a
// leaf's corner, whether it must be shaded for want of parents at its depth; a site's
// block deviation goes to AUX_SIGMA (-1 for the others) and into the workgroup's sums.
@compute @workgroup_size(64)
fn plan(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) local: u32, @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = index_of(id);
    var sigma = -1.0;
    if i < pixels() {
        let x = i % ap.width;
        let y = i / ap.width;
        var leaf = 0u;
        for (var j = 0u; j <= min(ap.top, 31u); j++) {
            let k = ap.top - j;
            let m = mips[mip_block(k, x, y)];
            if m >= k + ap.drop {
                leaf = k;
                break;
            }
        }
        let corner = (1u << leaf) - 1u;
        var site = -1;
        if (x & corner) == 0u && (y & corner) == 0u {
            site = i32(leaf);
        } else if is_edge(x, y) || !has_parents(x, y, level_of_pixel(x, y)) {
            site = 0;
        }
        if site >= 0 {
            let predicted = bitcast<f32>(mips[mip_block(u32(site), x, y) + 1u]);
            sigma = corrected_sigma(predicted, i);
        }
        aux[i * ap.aux_words + AUX_SIGMA] = bitcast<u32>(sigma);
    }
    wg_sum[local] = max(sigma, 0.0);
    wg_count[local] = select(0.0, 1.0, sigma >= 0.0);
    workgroupBarrier();
    for (var half = 32u; half > 0u; half >>= 1u) {
        if local < half {
            wg_sum[local] += wg_sum[local + half];
            wg_count[local] += wg_count[local + half];
        }
        workgroupBarrier();
    }
    if local == 0u {
        let g = wid.x + wid.y * groups.x;
        partials[2u + 2u * g] = wg_sum[0];
        partials[3u + 2u * g] = wg_count[0];
    }
}

// The workgroups' partial results in `partials` summed (`plan`'s sums and counts) or
// their largest taken (`counts`' sample counts, `ap.drop` non-zero) into [0] and [1],
// by one workgroup; `ap.level` holds the number of workgroups.
@compute @workgroup_size(64)
fn reduce(@builtin(local_invocation_index) local: u32) {
    let most = ap.drop != 0u;
    var sum = 0.0;
    var count = 0.0;
    let n = ap.level;
    for (var g = local; g < n; g += 64u) {
        let a = partials[2u + 2u * g];
        let b = partials[3u + 2u * g];
        if most {
            sum = max(sum, a);
        } else {
            sum += a;
            count += b;
        }
    }
    wg_sum[local] = sum;
    wg_count[local] = count;
    workgroupBarrier();
    for (var half = 32u; half > 0u; half >>= 1u) {
        if local < half {
            if most {
                wg_sum[local] = max(wg_sum[local], wg_sum[local + half]);
            } else {
                wg_sum[local] += wg_sum[local + half];
                wg_count[local] += wg_count[local + half];
            }
        }
        workgroupBarrier();
    }
    if local == 0u {
        partials[0] = wg_sum[0];
        if !most {
            partials[1] = wg_count[0];
        }
    }
}

// `allocation::phase`: the fractional part of i times the golden ratio's, as 32-bit
// fixed point (exact modulo 2^32).
fn phase(i: u32) -> f32 {
    return f32(i * 2654435769u) * 2.3283064e-10;
}

// `allocation::dithered`: floor((f + 1) r + phase) - floor(f r + phase), written as
// floor(r) + floor(fract(f fract(r) + phase) + fract(r)) so f32 keeps the digits.
fn dithered(rate: f32, frame: u32, ph: f32) -> u32 {
    let whole = floor(rate);
    let part = rate - whole;
    let z = fract(fract(f32(frame) * part) + ph);
    return u32(whole + floor(z + part));
}

// Each site's samples this frame: in proportion to its block's sigma, the sites'
// mean at `mean_samples`, clamped to [floor, max], dithered over frames; a site
// without a sample yet takes one. AUX_FIRST: the index of its first sample. The
// workgroup's most samples go to `partials` for `reduce` (the sums `plan` left there
// are read by now: `reduce` ran between).
@compute @workgroup_size(64)
fn counts(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) local: u32, @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = index_of(id);
    var n = 0u;
    if i < pixels() {
        let a = i * ap.aux_words;
        let sigma = bitcast<f32>(aux[a + AUX_SIGMA]);
        let own = state[i * STATE_WORDS];
        if sigma >= 0.0 {
            let count = partials[1];
            let mean_sigma = select(0.0, partials[0] / max(count, 1.0), count > 0.0);
            var rate = ap.mean_samples;
            if mean_sigma > 0.0 {
                rate = clamp(ap.mean_samples * sigma / mean_sigma, ap.floor_samples, ap.max_samples);
            }
            n = dithered(rate, ap.frame, phase(i));
            if own == 0u {
                n = max(n, 1u);
            }
        }
        aux[a + AUX_PLANNED] = n;
        aux[a + AUX_FIRST] = own;
    }
    // Every invocation reaches the barriers (uniform control flow).
    wg_sum[local] = f32(n);
    workgroupBarrier();
    for (var half = 32u; half > 0u; half >>= 1u) {
        if local < half {
            wg_sum[local] = max(wg_sum[local], wg_sum[local + half]);
        }
        workgroupBarrier();
    }
    if local == 0u {
        partials[2u + 2u * (wid.x + wid.y * groups.x)] = wg_sum[0];
    }
}

// After each dispatch of the frame's samples: each pixel's own count and moments take
// the dispatch's (Chan et al.'s merge of two sets' mean and M2); a pixel first shaded
// after the first frame is marked added.
@compute @workgroup_size(64)
fn commit(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = index_of(id);
    if i >= pixels() {
        return;
    }
    let a = i * ap.aux_words;
    let shaded = aux[a + AUX_SAMPLES];
    let s = i * STATE_WORDS;
    let own = state[s];
    if own == 0u && shaded > 0u && ap.frame > 0u {
        state[s + 1u] = 1u;
    }
    state[s] = own + shaded;
    let nb = aux[a + AUX_MOMENTS];
    if nb == 0u {
        return;
    }
    let na = state[s + 2u];
    let mean_a = bitcast<f32>(state[s + 3u]);
    let m2_a = bitcast<f32>(state[s + 4u]);
    let mean_b = bitcast<f32>(aux[a + AUX_MOMENTS + 1u]);
    let m2_b = bitcast<f32>(aux[a + AUX_MOMENTS + 2u]);
    let n = na + nb;
    let delta = mean_b - mean_a;
    let mean = mean_a + delta * f32(nb) / f32(n);
    let m2 = m2_a + m2_b + delta * delta * f32(na) * f32(nb) / f32(n);
    state[s + 2u] = n;
    state[s + 3u] = bitcast<u32>(mean);
    state[s + 4u] = bitcast<u32>(m2);
}

// `upsample::trusted`: whether pixel i's own mean stands.
fn trusted(i: u32, x: u32, y: u32) -> bool {
    let own = state[i * STATE_WORDS];
    let added = state[i * STATE_WORDS + 1u] != 0u;
    if own == 0u || !added || own >= MATURE_SAMPLES || is_infinite(depth_of(i)) {
        return own > 0u;
    }
    let k = level_of_pixel(x, y);
    if k >= ap.top {
        return true;
    }
    return !has_parents(x, y, k);
}

// One level (`ap.level`) of the coarse-to-fine up-sampling: a pixel of that level
// without a value it can trust takes its parents' weighted mean (the parent nearest
// in depth where no weight is left), the parents being final from the level above.
@compute @workgroup_size(64)
fn upsample(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = index_of(id);
    if i >= pixels() {
        return;
    }
    let x = i % ap.width;
    let y = i / ap.width;
    let k = ap.level;
    if level_of_pixel(x, y) != k || k >= ap.top || trusted(i, x, y) {
        return;
    }
    let p = parents(x, y, k, true);
    var total = 0.0;
    var sum = vec3<f32>(0.0);
    for (var c = 0u; c < p.n; c++) {
        total += p.weight[c];
        sum += image[p.index[c]].xyz * p.weight[c];
    }
    if total > 0.0 {
        image[i] = vec4<f32>(sum / total, 1.0);
        return;
    }
    var nearest = 0u;
    var nearest_d = 3.4e38;
    let z = depth_of(i);
    for (var c = 0u; c < p.n; c++) {
        var d = abs(depth_of(p.index[c]) - z);
        // A miss's difference is infinite or NaN: counted as the largest.
        if !(d < 3.4e38) {
            d = 3.4e38;
        }
        if c == 0u || d < nearest_d {
            nearest_d = d;
            nearest = p.index[c];
        }
    }
    var value = vec3<f32>(0.0);
    if p.n > 0u {
        value = image[nearest].xyz;
    }
    image[i] = vec4<f32>(value, 1.0);
}

// An emission edit: the moments, of the old weights, start again (the counts stay).
@compute @workgroup_size(64)
fn forget_moments(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = index_of(id);
    if i >= pixels() {
        return;
    }
    let s = i * STATE_WORDS;
    state[s + 2u] = 0u;
    state[s + 3u] = 0u;
    state[s + 4u] = 0u;
}
