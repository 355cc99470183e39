// Light sampling of the spmm mode (Silva & Santos 2013 eq. 4-7), as
// core/src/trace/lights.rs does it on the exact per-light path (up to 16 lights):
// each point light one shadow ray, each area light one shadow ray to a point drawn
// uniformly on it (A L_e f cos_i cos_l / r^2, one-sided), at MERL surfaces combined by
// MIS with a material sample towards it, and one ambient-occlusion ray limited to the
// ambient radius. Each adds to its own film layer for unit emission.

const LIGHT_WORDS: u32 = 12u;
const LIGHT_POINT: u32 = 0u;

// Light record in `data` (12 words): kind, position or corner, edge_u, edge_v, pad x2.
fn light_vec(at: u32) -> vec3<f32> {
    return vec3<f32>(f32_at(at), f32_at(at + 1u), f32_at(at + 2u));
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
fn sample_area_light_by_material(k: u32, s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    let u = rand2(rng);
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
    add_layer(pixel, LAYER_FIRST_LIGHT + k, throughput * response(s, m.xyz, wo) * (weight / m.w));
}

fn sample_lights(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    let count = min(params.lights, 16u);
    // Area lights meet a material sample by MIS at MERL surfaces, whose measured lobes
    // can be far narrower than a light (`SpmmMode::area_light_mis`).
    let mis = material_kind(s.material) == MATERIAL_MERL;
    for (var k = 0u; k < count; k++) {
        let u = rand2(rng);
        let at = params.light_table + k * LIGHT_WORDS;
        let kind = data[at];
        if mis && kind != LIGHT_POINT {
            sample_area_light_by_material(k, s, wo, lift, throughput, pixel, rng);
        }
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
                continue;
            }
            falloff = cos_l * area / d2;
        }
        let wi = normalize(to);
        let cos_i = dot(wi, s.n);
        if !(cos_i > 0.0) {
            continue;
        }
        counts.shadow += 1u;
        if !occluded(lift, wi, length(q - lift) * (1.0 - 1e-6)) {
            var weight = 1.0;
            if mis && kind != LIGHT_POINT {
                weight = power_heuristic(1.0 / falloff, material_pdf(s, wi, wo));
            }
            add_layer(pixel, LAYER_FIRST_LIGHT + k, throughput * response(s, wi, wo) * (falloff * weight));
        }
    }
}

fn cosine_hemisphere(u: vec2<f32>) -> vec3<f32> {
    let r = sqrt(u.x);
    let phi = 2.0 * PI * u.y;
    return vec3<f32>(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u.x, 0.0)));
}

fn sample_ambient(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    let u = rand2(rng);
    if params.ambient_radius < 0.0 {
        return;
    }
    var wi: vec3<f32>;
    var weight: f32;
    if material_kind(s.material) == MATERIAL_SPMM {
        // A pack draws from its texel's bases (and a defensive share), as the CPU.
        let m = material_sample(s, wo, u);
        if !(m.w > 0.0) || dot(m.xyz, s.n) <= 0.0 {
            return;
        }
        wi = m.xyz;
        weight = 1.0 / m.w;
    } else {
        let local = cosine_hemisphere(u);
        if local.z <= 0.0 {
            return;
        }
        wi = s.t * local.x + s.b * local.y + s.n * local.z;
        weight = PI / local.z;
    }
    counts.ambient += 1u;
    if !occluded(lift, wi, params.ambient_radius) {
        add_layer(pixel, LAYER_AMBIENT, throughput * response(s, wi, wo) * weight);
    }
}
