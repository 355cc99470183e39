// The adaptive mode's bandwidth pass on the device (concatenated after integrator.wgsl;
// core/modes/src/adaptive/mode/pass.rs is the reference for every rule here): the
// G-buffer of the pixels' centre rays, then per pixel eq. 3-6 over n_b light
// directions per emitter with the materials', the environment's and the lights'
// rate tables, the visibility share of the guard rays and the moments of the frames'
// estimator over the same directions; then eq. 11's level with the visibility and
// radiance guards, the predicted deviation and the up-sampling guide, which the
// frames read (adaptive.wgsl's `inputs`). Eq. 9's sum, which only the CPU mode's
// overlays show, is not computed here.
//
// The integrator's bindings serve the pass (the studio's device allows 8 storage
// buffers a kernel): `frame` is bound to the pass's own buffer, which holds per pixel
// G_FLOATS (the hit's primitive as bits, its distance, shading normal and point), then
// per pixel RESULT_FLOATS (eq. 6's rate, the visible share, the estimator's mean and
// variance), then one sum of |mean| per workgroup and their total, then the pass's
// tables (core/gpu/src/adaptive_pass.rs `PassTables`: a header of the rules' constants
// and the tables' offsets, relative to the header, then the tables); `aux` is bound to
// the frames' inputs (adaptive.wgsl's `inputs`, INPUT_WORDS per pixel), which
// `pass_finish` writes.


const H_N_B: u32 = 0u;
const H_SHIFT: u32 = 1u;          // 2 floats: the strata's shift
const H_FOV: u32 = 3u;            // 2 floats: horizontal and vertical field of view
const H_FIRST: u32 = 5u;          // the first pixel of an analysis dispatch
const H_GUARD_RAYS: u32 = 6u;
const H_VISIBILITY_STEP: u32 = 7u;
const H_RADIANCE_STEP: u32 = 8u;
const H_FULL_RATE: u32 = 9u;
const H_MIN_COS: u32 = 10u;
const H_DEPTH_SIGMA: u32 = 11u;
const H_DARK_SHARE: u32 = 12u;
const H_MAP_ORDER: u32 = 13u;     // offset of n_b words
const H_LIGHT_ORDERS: u32 = 14u;  // offset of n_b words per scene light
const H_MATERIALS: u32 = 15u;     // offset of one word per material: its table or NO_TABLE
const H_ENV_RATES: u32 = 16u;     // offset of the map's rates (NO_TABLE: none)
const H_ENV_WIDTH: u32 = 17u;
const H_ENV_HEIGHT: u32 = 18u;
const H_LIGHT_RATES: u32 = 19u;   // offset of one word per scene light: its table or NO_TABLE
const H_GRID: u32 = 20u;          // fixed directions per side of a material's table
const H_LIGHT_RES: u32 = 21u;     // samples per side of a light's table
const H_REMAINDER_ORDER: u32 = 22u; // offset of n_b words: a split map's second part
const NO_TABLE: u32 = 0xffffffffu;

const G_FLOATS: u32 = 8u;
const RESULT_FLOATS: u32 = 4u;
const PASS_INPUT_WORDS: u32 = 7u;
// The most light directions per emitter (`PassTables::MAX_N_B`).
const MAX_N_B: u32 = 64u;

// Where the tables start in the pass's buffer: after the partials and their total.
fn tables_at() -> u32 {
    return partials_at() + (n_pixels() + 63u) / 64u + 1u;
}

fn tw(i: u32) -> u32 {
    return bitcast<u32>(frame[tables_at() + i]);
}

fn tf(i: u32) -> f32 {
    return frame[tables_at() + i];
}

// n_b, as the host bounds it.
fn strata_count() -> u32 {
    return clamp(tw(H_N_B), 1u, MAX_N_B);
}

fn n_pixels() -> u32 {
    return params.width * params.height;
}

fn results_at(pixel: u32) -> u32 {
    return n_pixels() * G_FLOATS + pixel * RESULT_FLOATS;
}

fn partials_at() -> u32 {
    return n_pixels() * (G_FLOATS + RESULT_FLOATS);
}

fn g_prim(pixel: u32) -> u32 {
    return bitcast<u32>(frame[pixel * G_FLOATS]);
}

fn g_depth(pixel: u32) -> f32 {
    return frame[pixel * G_FLOATS + 1u];
}

fn g_vec(pixel: u32, word: u32) -> vec3<f32> {
    let at = pixel * G_FLOATS + word;
    return vec3<f32>(frame[at], frame[at + 1u], frame[at + 2u]);
}

fn g_mesh(prim: u32) -> u32 {
    return tris[prim * TRI_WORDS + 10u];
}

// The G-buffer: one ray through each pixel's centre, no mirror followed.
@compute @workgroup_size(64)
fn pass_gbuffer(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = pixel_of_invocation(id, groups);
    if pixel >= n_pixels() {
        return;
    }
    let origin = params.cam_origin.xyz;
    let dir = camera_dir(pixel, vec2<f32>(0.5));
    let hit = traverse(make_ray(origin, dir, 0.0, FAR), false);
    let at = pixel * G_FLOATS;
    frame[at] = bitcast<f32>(hit.prim);
    if hit.prim == NO_HIT {
        frame[at + 1u] = bitcast<f32>(F32_INFINITY_BITS);
        return;
    }
    let s = shading_at(hit.prim, origin, dir, hit.t);
    frame[at + 1u] = hit.t;
    frame[at + 2u] = s.n.x;
    frame[at + 3u] = s.n.y;
    frame[at + 4u] = s.n.z;
    frame[at + 5u] = s.p.x;
    frame[at + 6u] = s.p.y;
    frame[at + 7u] = s.p.z;
}

// `GBuffer::build`'s curvature: the normal's largest change per metre towards a
// 4-neighbour on the same mesh at a close depth.
fn curvature(pixel: u32) -> f32 {
    let me = g_prim(pixel);
    let depth = g_depth(pixel);
    let n = g_vec(pixel, 2u);
    let p = g_vec(pixel, 5u);
    var c = 0.0;
    for (var i = 0u; i < 4u; i++) {
        let o = neighbour(pixel, i);
        let prim = g_prim(o);
        if o == pixel || prim == NO_HIT || g_mesh(prim) != g_mesh(me) || abs(g_depth(o) - depth) > tf(H_DEPTH_SIGMA) * depth {
            continue;
        }
        let dp = length(g_vec(o, 5u) - p);
        if dp > 0.0 {
            c = max(c, length(g_vec(o, 2u) - n) / dp);
        }
    }
    return c;
}

// `bandwidth::LobeIndex`: a local direction's cell on the fixed-direction grid and its
// pixel in a lobe image, both `grid` to a side.
fn lobe_theta(w: vec3<f32>) -> f32 {
    return atan2(length(w.xy), max(w.z, 0.0));
}

fn lobe_cell(w: vec3<f32>, grid: u32) -> u32 {
    let theta = lobe_theta(w);
    var phi = atan2(w.y, w.x);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let t = min(u32(theta / (0.5 * PI) * f32(grid)), grid - 1u);
    let p = min(u32(phi / (2.0 * PI) * f32(grid)), grid - 1u);
    return t * grid + p;
}

fn lobe_pixel(w: vec3<f32>, grid: u32) -> u32 {
    let r = lobe_theta(w) / (0.5 * PI);
    let phi = atan2(w.y, w.x);
    let u = 0.5 + 0.5 * r * cos(phi);
    let v = 0.5 + 0.5 * r * sin(phi);
    let x = min(u32(u * f32(grid)), grid - 1u);
    let y = min(u32(v * f32(grid)), grid - 1u);
    return y * grid + x;
}

// `operators::transport`.
fn transport(nu: vec2<f32>, d: f32) -> vec2<f32> {
    return vec2<f32>(nu.x, nu.y - d * nu.x);
}

// `operators::reflect` (eq. 3).
fn reflect_bandwidth(nu: vec2<f32>, cos_i: f32, cos_o: f32, curvature: f32, rho: f32) -> vec2<f32> {
    let min_cos = tf(H_MIN_COS);
    var v = vec2<f32>(nu.x * max(cos_i, min_cos), nu.y);
    v.x += curvature * v.y;
    if abs(v.y) > rho {
        v *= rho / abs(v.y);
    }
    v.y = -v.y;
    v.x -= curvature * v.y;
    v.x /= max(cos_o, min_cos);
    return v;
}

// What one pixel's paths add up to (`pass.rs` `Paths`): eq. 5's weights and weighted
// bandwidths, the guarded and visible lambdas.
struct PathSums {
    lambda: f32,
    nu: vec2<f32>,
    guarded: f32,
    visible: f32,
}

// The pixel being analysed: its surface, view, tables and sums.
struct PassPoint {
    s: Shading,
    wo: vec3<f32>,
    lo: vec3<f32>,
    lift: vec3<f32>,
    // Offset of the material's rate table.
    rates: u32,
    at_lo: u32,
    curvature: f32,
    depth: f32,
    grid: u32,
}

var<private> sums: PathSums;
// The frames' estimator's value per direction k (luminance, emissions applied).
var<private> values: array<f32, MAX_N_B>;

fn to_local(s: Shading, w: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(w, s.t), dot(w, s.b), dot(w, s.n));
}

fn lum(v: vec3<f32>) -> f32 {
    return dot(v, LUMINANCE);
}

// The centre of stratum `k` of the n_b strata, shifted (`pass.rs` `Strata`).
fn stratum(k: u32) -> vec2<f32> {
    let side = u32(ceil(sqrt(f32(strata_count()))));
    let u = vec2<f32>((f32(k % side) + 0.5) / f32(side), (f32(k / side) + 0.5) / f32(side))
        + vec2<f32>(tf(H_SHIFT), tf(H_SHIFT + 1u));
    return fract(u);
}

// `Paths::bounce` and `Paths::exact`: one path from local direction `li` of incident
// bandwidth `l_in` at `d_light` to the eye; its lambda. `guard`: 0 not a guard
// path, 1 a guard path found occluded, 2 one found open.
fn bounce(at: PassPoint, li: vec3<f32>, l_in: vec2<f32>, d_light: f32, radiance: f32, weight: f32, guard: u32) -> f32 {
    let f = lum(response(at.s, at.s.t * li.x + at.s.b * li.y + at.s.n * li.z, at.wo));
    let rho = bitcast<f32>(tw(at.rates + lobe_cell(li, at.grid) * at.grid * at.grid + at.at_lo));
    let nu = abs(transport(reflect_bandwidth(transport(l_in, d_light), li.z, at.lo.z, at.curvature, rho), at.depth));
    let lambda = radiance * f * weight;
    sums.lambda += lambda;
    sums.nu += lambda * nu;
    if guard > 0u {
        sums.guarded += lambda;
        if guard == 2u {
            sums.visible += lambda;
        }
    }
    return lambda;
}

fn guard_of(k: u32, open: bool) -> u32 {
    if k >= tw(H_GUARD_RAYS) {
        return 0u;
    }
    return select(1u, 2u, open);
}

// A direction drawn by the material's sampling for stratum `u`, a cosine one where it
// draws none (`pass.rs` `drawn`): world direction and pdf (w = 0: none).
fn drawn_direction(at: PassPoint, u: vec2<f32>) -> vec4<f32> {
    var m = material_sample(at.s, at.wo, u);
    if !(m.w > 0.0 && m.w < F32_MAX) {
        let c = cosine_hemisphere(u);
        m = vec4<f32>(at.s.t * c.x + at.s.b * c.y + at.s.n * c.z, c.z * INV_PI);
    }
    if !(m.w > 0.0) || dot(m.xyz, at.s.n) <= 0.0 {
        return vec4<f32>(0.0);
    }
    return m;
}

// The map's rate seen in world direction `d` (`EnvironmentBandwidth::rate`).
fn env_rate(d: vec3<f32>) -> f32 {
    let m = rotate_about_y(d, env_f(ENV_COS), -env_f(ENV_SIN));
    return tf(tw(H_ENV_RATES) + latlong_pixel(tw(H_ENV_WIDTH), tw(H_ENV_HEIGHT), m));
}

// `environment_paths`: the material's directions with the map's rates, and the
// strategy of each part of the map at its own order of the strata, its first
// directions guarded too.
fn environment_paths(at: PassPoint) {
    if tw(H_ENV_RATES) == NO_TABLE || env[ENV_LIGHTS] == 0u {
        return;
    }
    let n_b = strata_count();
    let mis = env[ENV_MIS] != 0u;
    let strength = params.weights[LAYER_ENVIRONMENT].xyz;
    let parts = env_parts();
    for (var k = 0u; k < n_b; k++) {
        let m = drawn_direction(at, stratum(k));
        if !(m.w > 0.0) {
            continue;
        }
        // One pixel lookup for the whole map's radiance and each part's.
        let p = env_pixel(m.xyz);
        let full = lum(env_rgb(env[ENV_RGB] + p * 3u) * strength);
        var open = true;
        if k < tw(H_GUARD_RAYS) {
            open = !occluded(at.lift, m.xyz, FAR);
        }
        let lambda = bounce(at, to_local(at.s, m.xyz), vec2<f32>(0.0, env_rate(m.xyz)), 0.0, full, 1.0 / m.w, guard_of(k, open));
        if mis && full > 0.0 {
            // Each part's share of lambda, weighted against its own strategy.
            for (var j = 0u; j < parts; j++) {
                let a = env_part_at(env_part(j), p);
                values[k] += lambda * (lum(a.xyz * strength) / full) * power_heuristic(m.w, a.w);
            }
        }
    }
    for (var j = 0u; j < parts; j++) {
        let order = select(tw(H_MAP_ORDER), tw(H_REMAINDER_ORDER), j == 1u);
        for (var k = 0u; k < n_b; k++) {
            let e = env_sample_part(env_part(j), stratum(tw(order + k)));
            if dot(e.dir, at.s.n) <= 0.0 || !(e.pdf > 0.0) {
                continue;
            }
            var weight = 1.0;
            if mis {
                weight = power_heuristic(e.pdf, material_pdf(at.s, e.dir, at.wo));
            }
            let f = lum(response(at.s, e.dir, at.wo));
            let lambda = f * lum(e.radiance * strength) * weight / e.pdf;
            values[k] += lambda;
            // Guards along the map's own directions: they find the sun where the
            // frames' map samples find it (`pass.rs`).
            if k < tw(H_GUARD_RAYS) {
                sums.guarded += lambda;
                if !occluded(at.lift, e.dir, FAR) {
                    sums.visible += lambda;
                }
            }
        }
    }
}

// `light_paths` and `point_light_paths`: points on each area light at its order of
// the strata with its rates (and, at MERL surfaces, the material's directions that
// meet it), one exact direction to each point light.
fn light_paths(at: PassPoint) {
    let n_b = strata_count();
    let merl = material_kind(at.s.material) == MATERIAL_MERL;
    let res = tw(H_LIGHT_RES);
    for (var l = 0u; l < params.lights; l++) {
        let rec = params.light_table + l * LIGHT_WORDS;
        let emitted = lum(light_vec(rec + LIGHT_FACTOR) * params.weights[min(data[rec + LIGHT_LAYER], MAX_LAYERS - 1u)].xyz);
        let corner = light_vec(rec + 1u);
        if data[rec] == LIGHT_POINT {
            let to = corner - at.s.p;
            let d2 = dot(to, to);
            let wi = to / sqrt(d2);
            let li = to_local(at.s, wi);
            if li.z <= 0.0 {
                continue;
            }
            let open = !occluded(at.lift, wi, length(corner - at.lift) * (1.0 - 1e-6));
            let lambda = bounce(at, li, vec2<f32>(0.0), sqrt(d2), emitted, 1.0 / d2, select(1u, 2u, open));
            if open {
                for (var k = 0u; k < n_b; k++) {
                    values[k] += lambda;
                }
            }
            continue;
        }
        let rates = tw(tw(H_LIGHT_RATES) + l);
        if rates == NO_TABLE {
            continue;
        }
        let edge_u = light_vec(rec + 4u);
        let edge_v = light_vec(rec + 7u);
        let c = cross(edge_u, edge_v);
        let area = length(c);
        let order = tw(H_LIGHT_ORDERS) + l * n_b;
        for (var k = 0u; k < n_b; k++) {
            let u = stratum(tw(order + k));
            let q = corner + edge_u * u.x + edge_v * u.y;
            let to = q - at.s.p;
            let d2 = dot(to, to);
            let d = sqrt(d2);
            let wi = to / d;
            let cos_l = -dot(wi, c / area);
            let li = to_local(at.s, wi);
            if cos_l <= 0.0 || li.z <= 0.0 {
                continue;
            }
            let falloff = cos_l * area / d2;
            var open = true;
            if k < tw(H_GUARD_RAYS) {
                open = !occluded(at.lift, wi, length(q - at.lift) * (1.0 - 1e-6));
            }
            let cell = min(u32(u.y * f32(res)), res - 1u) * res + min(u32(u.x * f32(res)), res - 1u);
            let lambda = bounce(at, li, vec2<f32>(tf(rates + cell), 0.0), d, emitted, falloff, guard_of(k, open));
            var weight = 1.0;
            if merl {
                weight = power_heuristic(1.0 / falloff, material_pdf(at.s, wi, at.wo));
            }
            values[k] += lambda * weight;
        }
        if !merl {
            continue;
        }
        for (var k = 0u; k < n_b; k++) {
            let m = drawn_direction(at, stratum(k));
            if !(m.w > 0.0) {
                continue;
            }
            let hit = hit_parallelogram(at.s.p, m.xyz, corner, edge_u, edge_v);
            if hit.x > 0.0 {
                let f = lum(response(at.s, m.xyz, at.wo));
                values[k] += emitted * f / m.w * power_heuristic(m.w, 1.0 / hit.y);
            }
        }
    }
}

// `ambient_paths`: the frames' ambient directions at the strata, each occluded or not
// within the radius.
fn ambient_paths(at: PassPoint) {
    if params.ambient_radius < 0.0 {
        return;
    }
    let radiance = lum(params.weights[LAYER_AMBIENT].xyz);
    for (var k = 0u; k < strata_count(); k++) {
        let a = ambient_direction(at.s, at.wo, stratum(k));
        if !(a.w > 0.0) {
            continue;
        }
        let open = !occluded(at.lift, a.xyz, params.ambient_radius);
        let lambda = bounce(at, to_local(at.s, a.xyz), vec2<f32>(0.0), 0.0, radiance, a.w, guard_of(k, open));
        if open {
            values[k] += lambda;
        }
    }
}

// Writes a pixel's results: eq. 6's rate of angular bandwidth `nu_a`, the visible
// share, the estimator's mean and variance.
fn write_results(pixel: u32, nu_a: f32, visible: f32, mean: f32, variance: f32) {
    let fov = vec2<f32>(tf(H_FOV), tf(H_FOV + 1u));
    let at = results_at(pixel);
    frame[at] = nu_a * max(fov.x / f32(params.width), fov.y / f32(params.height));
    frame[at + 1u] = visible;
    frame[at + 2u] = mean;
    frame[at + 3u] = variance;
}

// Per pixel of the dispatch's rows (from H_FIRST): eq. 5's bandwidth at the eye, the
// visible share and the moments of the estimator over the n_b directions
// (`pixel_bandwidth`).
@compute @workgroup_size(64)
fn pass_analyse(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = tw(H_FIRST) + pixel_of_invocation(id, groups);
    if pixel >= n_pixels() {
        return;
    }
    let prim = g_prim(pixel);
    let origin = params.cam_origin.xyz;
    let dir = camera_dir(pixel, vec2<f32>(0.5));
    let full = tf(H_FULL_RATE);
    if prim == NO_HIT {
        // `escaped`: what the ray sees (one value); the environment seen directly is
        // shaded at every pixel, a constant background up-sampled.
        for (var l = 0u; l < MAX_LAYERS; l++) {
            acc[l] = vec3<f32>(0.0);
        }
        add_escape(pixel, vec3<f32>(1.0), dir);
        var value = 0.0;
        for (var l = 0u; l < min(params.layers, MAX_LAYERS); l++) {
            value += lum(acc[l] * params.weights[l].xyz);
        }
        write_results(pixel, select(0.0, full, params.background == ESCAPE_ENVIRONMENT), 1.0, value, 0.0);
        return;
    }
    let s = shading_at(prim, origin, dir, g_depth(pixel));
    let kind = material_kind(s.material);
    if kind == MATERIAL_MIRROR {
        // A mirror shows what it reflects, at any frequency.
        write_results(pixel, full, 1.0, 0.0, 0.0);
        return;
    }
    let rates = tw(tw(H_MATERIALS) + s.material);
    let lo = to_local(s, -dir);
    if rates == NO_TABLE || lo.z <= 0.0 {
        write_results(pixel, 0.0, 1.0, 0.0, 0.0);
        return;
    }
    let grid = tw(H_GRID);
    let at = PassPoint(s, -dir, lo, lifted(s), rates, lobe_pixel(lo, grid), curvature(pixel), g_depth(pixel), grid);
    sums = PathSums(0.0, vec2<f32>(0.0), 0.0, 0.0);
    let n_b = strata_count();
    for (var k = 0u; k < MAX_N_B; k++) {
        values[k] = 0.0;
    }
    environment_paths(at);
    light_paths(at);
    ambient_paths(at);
    var mean = 0.0;
    for (var k = 0u; k < n_b; k++) {
        mean += values[k];
    }
    mean /= f32(n_b);
    var variance = 0.0;
    if n_b > 1u {
        for (var k = 0u; k < n_b; k++) {
            variance += (values[k] - mean) * (values[k] - mean);
        }
        variance /= f32(n_b - 1u);
    }
    var nu_a = 0.0;
    if sums.lambda > 0.0 {
        nu_a = sums.nu.y / sums.lambda;
    }
    var visible = 1.0;
    if sums.guarded > 0.0 {
        visible = sums.visible / sums.guarded;
    }
    write_results(pixel, nu_a, visible, mean, variance);
}

var<workgroup> wg_dark: array<f32, 64>;

// The sum of the workgroup's `v`s (every invocation calls it: it holds barriers).
fn workgroup_sum(li: u32, v: f32) -> f32 {
    wg_dark[li] = v;
    workgroupBarrier();
    for (var stride = 32u; stride > 0u; stride /= 2u) {
        if li < stride {
            wg_dark[li] += wg_dark[li + stride];
        }
        workgroupBarrier();
    }
    return wg_dark[0];
}

// Per workgroup of pixels, the sum of |mean| (the dark floor of the radiance guard).
@compute @workgroup_size(64)
fn pass_partials(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) li: u32, @builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = pixel_of_invocation(id, groups);
    var v = 0.0;
    if pixel < n_pixels() {
        v = abs(frame[results_at(pixel) + 2u]);
    }
    let total = workgroup_sum(li, v);
    // A 2D dispatch's last row may hold workgroups past the pixels: no partial.
    let group = wg.x + wg.y * groups.x;
    if li == 0u && group < (n_pixels() + 63u) / 64u {
        frame[partials_at() + group] = total;
    }
}

// The partials' total, by one workgroup, after them.
@compute @workgroup_size(64)
fn pass_total(@builtin(local_invocation_index) li: u32) {
    let count = (n_pixels() + 63u) / 64u;
    var v = 0.0;
    for (var i = li; i < count; i += 64u) {
        v += frame[partials_at() + i];
    }
    let total = workgroup_sum(li, v);
    if li == 0u {
        frame[partials_at() + count] = total;
    }
}

fn result(pixel: u32, word: u32) -> f32 {
    return frame[results_at(pixel) + word];
}

// The neighbour of `pixel` in direction `i` (right, down, left, up), or the pixel itself
// past the image's edge.
fn neighbour(pixel: u32, i: u32) -> u32 {
    let x = pixel % params.width;
    let y = pixel / params.width;
    switch i {
        case 0u: { if x + 1u < params.width { return pixel + 1u; } }
        case 1u: { if y + 1u < params.height { return pixel + params.width; } }
        case 2u: { if x > 0u { return pixel - 1u; } }
        default: { if y > 0u { return pixel - params.width; } }
    }
    return pixel;
}

// `operators::level` (eq. 11).
fn pass_level(b_p: f32) -> u32 {
    let top = firstLeadingBit(max(min(params.width, params.height), 1u));
    if !(b_p > 0.0) {
        return top;
    }
    let l = floor(log2(1.0 / b_p));
    if l <= 0.0 {
        return 0u;
    }
    return min(u32(l), top);
}

// `finish_pass` per pixel: the guards, eq. 11's level, the predicted deviation (the
// estimator's and the footprint's variance) and the up-sampling guide.
@compute @workgroup_size(64)
fn pass_finish(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = pixel_of_invocation(id, groups);
    if pixel >= n_pixels() {
        return;
    }
    let count = (n_pixels() + 63u) / 64u;
    let dark = tf(H_DARK_SHARE) * frame[partials_at() + count] / f32(n_pixels());
    let visible = result(pixel, 1u);
    let mean = result(pixel, 2u);
    var edge = false;
    var step = vec2<f32>(0.0);
    for (var i = 0u; i < 4u; i++) {
        let o = neighbour(pixel, i);
        let m = result(o, 2u);
        edge = edge || abs(result(o, 1u) - visible) > tf(H_VISIBILITY_STEP)
            || abs(m - mean) > tf(H_RADIANCE_STEP) * max(max(abs(m), abs(mean)), dark);
        // `footprint_variance`: the larger one-sided step along each axis.
        if i % 2u == 0u {
            step.x = max(step.x, abs(m - mean));
        } else {
            step.y = max(step.y, abs(m - mean));
        }
    }
    var level = 0u;
    if !edge {
        level = pass_level(result(pixel, 0u));
    }
    let sigma = sqrt(max(result(pixel, 3u), 0.0) + dot(step, step) / 12.0);
    var depth = bitcast<f32>(F32_INFINITY_BITS);
    var normal_dir = vec2<f32>(0.0);
    var cos_x = 1.0;
    if g_prim(pixel) != NO_HIT {
        let n = g_vec(pixel, 2u);
        depth = g_depth(pixel);
        let d = vec2<f32>(dot(n, params.cam_right.xyz), -dot(n, params.cam_up.xyz));
        let l2 = dot(d, d);
        if l2 > 0.0 && l2 < F32_MAX {
            normal_dir = d * inverseSqrt(l2);
        }
        cos_x = abs(dot(n, camera_dir(pixel, vec2<f32>(0.5))));
    }
    let out = pixel * PASS_INPUT_WORDS;
    aux[out] = level;
    aux[out + 1u] = bitcast<u32>(sigma);
    aux[out + 2u] = bitcast<u32>(depth);
    aux[out + 3u] = bitcast<u32>(normal_dir.x);
    aux[out + 4u] = bitcast<u32>(normal_dir.y);
    aux[out + 5u] = bitcast<u32>(cos_x);
    aux[out + 6u] = bitcast<u32>(mean);
}
