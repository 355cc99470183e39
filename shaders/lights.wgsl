// Light sampling of the spmm mode (Silva & Santos 2013 eq. 4-7), as
// core/modes/src/trace/lights.rs does it: up to 16 lights, each point light one shadow ray
// and each area light `light_samples` shadow rays to points drawn uniformly on it (A
// L_e f cos_i cos_l / r^2 each, one-sided, weighted by its share), at MERL surfaces
// each combined by MIS with a material sample towards it; above 16, `light_samples`
// lights per shading point, each kept from CANDIDATES drawn from the
// CPU's alias table by resampled importance sampling (core/render/src/light_selection.rs).
// One ambient-occlusion ray limited to the ambient radius. Each light adds to the film
// layer the CPU's `Layers::light_targets` gives it, times its factor (one, or its
// emission in a bounded film's shared layer).

// Light record in `data` (24 words): kind, position or corner, edge_u, edge_v, layer,
// factor; above 16 lights the selection table: keep probability and alias of its alias
// bin, pmf, 1 / area, the resampling weight's scale, the emitting normal; padding.
const LIGHT_WORDS: u32 = 24u;
const LIGHT_POINT: u32 = 0u;
const LIGHT_LAYER: u32 = 10u;
const LIGHT_FACTOR: u32 = 11u;
const LIGHT_KEEP: u32 = 14u;
const LIGHT_ALIAS: u32 = 15u;
const LIGHT_PMF: u32 = 16u;
const LIGHT_INV_AREA: u32 = 17u;
const LIGHT_W_SCALE: u32 = 18u;
const LIGHT_NORMAL: u32 = 19u;
// Candidates per light sample (`light_selection::CANDIDATES`; one light sample).
const CANDIDATES: u32 = 8u;

fn light_vec(at: u32) -> vec3<f32> {
    return vec3<f32>(f32_at(at), f32_at(at + 1u), f32_at(at + 2u));
}

// Adds `v` (unit emission) to the layer of the light whose record is at `at`.
fn add_light(pixel: u32, at: u32, v: vec3<f32>) {
    add_layer(pixel, data[at + LIGHT_LAYER], v * light_vec(at + LIGHT_FACTOR));
}

// `geometry::hit_parallelogram`: the distance to the front face of the light with
// corner `c` and edges `eu`, `ev` along `dir`, and its cos_l A / t^2 (x, y; x <= 0: none).
fn hit_parallelogram(o: vec3<f32>, dir: vec3<f32>, c: vec3<f32>, eu: vec3<f32>, ev: vec3<f32>) -> vec2<f32> {
    let normal = cross(eu, ev);
    let facing = -dot(dir, normal);
    if !(facing > 0.0) {
        return vec2<f32>(0.0);
    }
    let t = dot(o - c, normal) / facing;
    if !(t > 0.0 && t < F32_MAX) {
        return vec2<f32>(0.0);
    }
    let rel = o + dir * t - c;
    let n2 = dot(normal, normal);
    let a = dot(cross(rel, ev), normal) / n2;
    let b = dot(cross(eu, rel), normal) / n2;
    if !(a >= 0.0 && a <= 1.0 && b >= 0.0 && b <= 1.0) {
        return vec2<f32>(0.0);
    }
    return vec2<f32>(t, facing / (t * t));
}

// The material's strategy for area light `k` (`sample_area_light_by_material`): a
// direction drawn from the material, kept if it meets the light's front face
// unshadowed, weighted by the power heuristic against the light's solid-angle pdf.
fn sample_area_light_by_material(k: u32, s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, u: vec2<f32>) {
    let at = params.light_table + k * LIGHT_WORDS;
    let m = material_sample(s, wo, u);
    if !(m.w > 0.0) || dot(m.xyz, s.n) <= 0.0 {
        return;
    }
    let hit = hit_parallelogram(s.p, m.xyz, light_vec(at + 1u), light_vec(at + 4u), light_vec(at + 7u));
    if !(hit.x > 0.0) {
        return;
    }
    counts.shadow += 1u;
    if occluded(lift, m.xyz, hit.x * (1.0 - 1e-6)) {
        return;
    }
    let weight = power_heuristic(m.w, 1.0 / hit.y);
    add_light(pixel, at, throughput * response(s, m.xyz, wo) * (weight / m.w));
}

fn sample_lights(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    if params.stochastic != 0u {
        sample_chosen_lights(s, wo, lift, throughput, pixel, rng);
        return;
    }
    // Every light: up to 16 in the spmm and biscale modes (above, they choose), any
    // number in the adaptive mode, which takes each once per sample as its CPU mode.
    let count = params.lights;
    // Area lights meet a material sample by MIS at MERL surfaces, whose measured lobes
    // can be far narrower than a light (`SpmmMode::area_light_mis`).
    let mis = material_kind(s.material) == MATERIAL_MERL;
    let n = clamp(params.light_samples, 1u, 64u);
    let share = throughput / f32(n);
    for (var k = 0u; k < count; k++) {
        let at = params.light_table + k * LIGHT_WORDS;
        // Both kinds draw a set of points (and area lights under MIS a set of material
        // directions), as the CPU's: the layout does not depend on the lights' kinds.
        let points = rand2_set(rng, n);
        if data[at] == LIGHT_POINT {
            // One exact sample.
            sample_light_point(at, set_draw(rng, points, 0u), false, s, wo, lift, throughput, pixel);
            continue;
        }
        var directions = PairSet(0u, 0u);
        if mis {
            directions = rand2_set(rng, n);
        }
        for (var r = 0u; r < n; r++) {
            if mis {
                sample_area_light_by_material(k, s, wo, lift, share, pixel, set_draw(rng, directions, r));
            }
            sample_light_point(at, set_draw(rng, points, r), mis, s, wo, lift, share, pixel);
        }
    }
}

// One shadow ray to the light whose record is at `at`: its position, or the point `u`
// on its area (`SpmmMode::sample_light_point`).
fn sample_light_point(at: u32, u: vec2<f32>, mis: bool, s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32) {
    let kind = data[at];
    var q = light_vec(at + 1u);
    var falloff = 0.0;
    var to = q - s.p;
    if kind == LIGHT_POINT {
        let d2 = dot(to, to);
        falloff = 1.0 / d2;
    } else {
        let edge_u = light_vec(at + 4u);
        let edge_v = light_vec(at + 7u);
        q = q + edge_u * u.x + edge_v * u.y;
        to = q - s.p;
        let d2 = dot(to, to);
        let c = cross(edge_u, edge_v);
        let area = length(c);
        let cos_l = -dot(to / sqrt(d2), c / area);
        if cos_l <= 0.0 {
            return;
        }
        falloff = cos_l * area / d2;
    }
    let wi = normalize(to);
    let cos_i = dot(wi, s.n);
    if !(cos_i > 0.0) {
        return;
    }
    counts.shadow += 1u;
    if !occluded(lift, wi, length(q - lift) * (1.0 - 1e-6)) {
        var weight = 1.0;
        if mis {
            weight = power_heuristic(1.0 / falloff, material_pdf(s, wi, wo));
        }
        add_light(pixel, at, throughput * response(s, wi, wo) * (falloff * weight));
    }
}

// `sample_chosen_lights`: per selection, CANDIDATES lights drawn from the alias table by power (a
// point on an area light with each), one kept in proportion to its unshadowed
// `emission x falloff` (weighted reservoir: the CPU's choice in distribution), one
// shadow ray to it, weighted `total / (CANDIDATES x target)`. Zero below the surface
// and behind a one-sided area light, where the contribution is zero too.
fn sample_chosen_lights(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    // `light_samples` selections, each weighted by its share.
    let selections = clamp(params.light_samples, 1u, 64u);
    let share = throughput / f32(selections);
    for (var i = 0u; i < selections; i++) {
        sample_chosen_light(s, wo, lift, share, pixel, rng);
    }
}

fn sample_chosen_light(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    let n = params.lights;
    if n == 0u {
        return;
    }
    var total = 0.0;
    var chosen = 0u;
    var chosen_q = vec3<f32>(0.0);
    var chosen_falloff = 0.0;
    var chosen_w = 0.0;
    for (var c = 0u; c < CANDIDATES; c++) {
        // One dimension's independent numbers per candidate, as the CPU's
        // `next_32_16_16`: Walker's alias table (a bin, then keep it or take its
        // alias), and a point on the light from 16 bits a side.
        let bits = rand_bits(rng);
        let bin = min(u32(unit_f32(bits) * f32(n)), n - 1u);
        let bin_at = params.light_table + bin * LIGHT_WORDS;
        var k = bin;
        if !(unit_f32(pcg(bits)) < f32_at(bin_at + LIGHT_KEEP)) {
            k = min(data[bin_at + LIGHT_ALIAS], n - 1u);
        }
        let at = params.light_table + k * LIGHT_WORDS;
        let point_bits = pcg(bits ^ 0x9e3779b9u);
        let u = (vec2<f32>(f32(point_bits >> 16u), f32(point_bits & 0xffffu)) + 0.5) * (1.0 / 65536.0);
        let q = light_vec(at + 1u) + light_vec(at + 4u) * u.x + light_vec(at + 7u) * u.y;
        let to = q - s.p;
        let d2 = dot(to, to);
        var cos_l = 1.0;
        if data[at] != LIGHT_POINT {
            cos_l = -dot(to, light_vec(at + LIGHT_NORMAL)) / sqrt(d2);
        }
        var falloff = 0.0;
        if dot(to, s.n) > 0.0 && cos_l > 0.0 {
            falloff = cos_l / d2;
        }
        let w = f32_at(at + LIGHT_W_SCALE) * falloff;
        let pick = rand(rng);
        if w > 0.0 && w < F32_MAX {
            total += w;
            if pick * total < w {
                chosen = k;
                chosen_q = q;
                chosen_falloff = falloff;
                chosen_w = w;
            }
        }
    }
    if !(total > 0.0 && total < F32_MAX) {
        return;
    }
    let at = params.light_table + chosen * LIGHT_WORDS;
    // target(y) = w(y) p_src(y), p_src per light or per unit area.
    let p_target = chosen_w * f32_at(at + LIGHT_PMF) * f32_at(at + LIGHT_INV_AREA);
    let wi = normalize(chosen_q - s.p);
    counts.shadow += 1u;
    if occluded(lift, wi, length(chosen_q - lift) * (1.0 - 1e-6)) {
        return;
    }
    let weight = total / (f32(CANDIDATES) * p_target);
    add_light(pixel, at, throughput * response(s, wi, wo) * (chosen_falloff * weight));
}

fn cosine_hemisphere(u: vec2<f32>) -> vec3<f32> {
    let r = sqrt(u.x);
    let phi = 2.0 * PI * u.y;
    return vec3<f32>(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u.x, 0.0)));
}

// The share of ambient directions drawn from a glossy material's lobe
// (`shading::AMBIENT_LOBE_SHARE`).
const AMBIENT_LOBE_SHARE: f32 = 0.5;

// Whether material record `at` is a glossy analytic BRDF or a MERL table, whose lobe
// cosine directions sample poorly (`ShadedMaterial::glossy`).
fn glossy_material(at: u32) -> bool {
    let kind = data[at];
    if kind == MATERIAL_MERL {
        return true;
    }
    if kind != MATERIAL_BRDF {
        return false;
    }
    let model = data[data[at + 1u]];
    return model != LAMBERTIAN && model != OREN_NAYAR;
}

// The ambient term's direction for `u` (world) and its weight, f cos / pdf's 1 / pdf
// (w <= 0: none), as the CPU's `ambient_sample`: a pack draws from its texel's bases
// (and a defensive share), a table from its lobe (and a defensive share); a glossy BRDF or MERL
// table one sample of the even mixture of its lobe and cosine directions (the first
// number picks the strategy and, rescaled, drives it); other materials a cosine
// direction.
fn ambient_direction(s: Shading, wo: vec3<f32>, u: vec2<f32>) -> vec4<f32> {
    let kind = material_kind(s.material);
    if kind == MATERIAL_SPMM || kind == MATERIAL_BTF {
        let m = material_sample(s, wo, u);
        if !(m.w > 0.0) || dot(m.xyz, s.n) <= 0.0 {
            return vec4<f32>(0.0);
        }
        return vec4<f32>(m.xyz, 1.0 / m.w);
    }
    if glossy_material(params.material_table + s.material * MATERIAL_WORDS) {
        var wi: vec3<f32>;
        if u.x < AMBIENT_LOBE_SHARE {
            let m = material_sample(s, wo, vec2<f32>(u.x / AMBIENT_LOBE_SHARE, u.y));
            if !(m.w > 0.0) {
                return vec4<f32>(0.0);
            }
            wi = m.xyz;
        } else {
            let c = cosine_hemisphere(vec2<f32>((u.x - AMBIENT_LOBE_SHARE) / (1.0 - AMBIENT_LOBE_SHARE), u.y));
            wi = s.t * c.x + s.b * c.y + s.n * c.z;
        }
        let cos_i = dot(wi, s.n);
        if cos_i <= 0.0 {
            return vec4<f32>(0.0);
        }
        let pdf = AMBIENT_LOBE_SHARE * material_pdf(s, wi, wo) + (1.0 - AMBIENT_LOBE_SHARE) * cos_i * INV_PI;
        if !(pdf > 0.0 && pdf < F32_MAX) {
            return vec4<f32>(0.0);
        }
        return vec4<f32>(wi, 1.0 / pdf);
    }
    let local = cosine_hemisphere(u);
    if local.z <= 0.0 {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(s.t * local.x + s.b * local.y + s.n * local.z, PI / local.z);
}

fn sample_ambient(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    let u = rand2(rng);
    if params.ambient_radius < 0.0 {
        return;
    }
    let a = ambient_direction(s, wo, u);
    if !(a.w > 0.0) {
        return;
    }
    counts.ambient += 1u;
    if !occluded(lift, a.xyz, params.ambient_radius) {
        add_layer(pixel, LAYER_AMBIENT, throughput * response(s, a.xyz, wo) * a.w);
    }
}
