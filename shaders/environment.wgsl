// Environment lighting and background images (core/render/src/environment/ and
// core/modes/src/trace/environment.rs are the reference): the lat-long map, its radiance
// seen in a direction, and the CPU's own importance-sampling tables (the row
// marginal and per-row column CDFs, the per-pixel pdf in solid angle) uploaded as
// they are, in f32. Per shading point one direction from the map and one from the
// material, combined with the power heuristic, each with a shadow ray, added to the
// environment layer for unit strength. Rays that leave the scene see the background
// colour, a background image, or the environment (params.background).

// `env` (binding 8), f32 as bits. Header words:
const ENV_LIGHTS: u32 = 0u;      // 1: the map lights the scene (not black)
const ENV_WIDTH: u32 = 1u;
const ENV_HEIGHT: u32 = 2u;
const ENV_MIS: u32 = 3u;
const ENV_COS: u32 = 4u;         // cos and sin of the rotation about +y
const ENV_SIN: u32 = 5u;
const ENV_ROW_CDF: u32 = 6u;     // height + 1 entries
const ENV_COL_CDF: u32 = 7u;     // height rows of width + 1 entries
const ENV_PDF: u32 = 8u;         // width x height, the CPU's luminance / total
const ENV_RGB: u32 = 9u;         // width x height x 3, the map (0: no environment)
const BG_WIDTH: u32 = 10u;
const BG_HEIGHT: u32 = 11u;
const BG_RGB: u32 = 12u;         // the background image, width x height x 3
// The map sampled in two parts, its peaks and its remainder, each by its own tables
// (the adaptive mode's frames, `meso_render::environment::sampled_parts`): 2 here,
// else the map is sampled whole by the tables above.
const ENV_PARTS: u32 = 13u;
const ENV_PEAKS_RGB: u32 = 14u;  // with two parts: the peaks' radiance (the first part)
const ENV_REST_ROW_CDF: u32 = 16u; // the remainder's tables and radiance, as above
const ENV_REST_COL_CDF: u32 = 17u;
const ENV_REST_PDF: u32 = 18u;
const ENV_REST_RGB: u32 = 19u;

// params.background: what rays that leave the scene add.
const ESCAPE_BLACK: u32 = 0u;
const ESCAPE_COLOR: u32 = 1u;
const ESCAPE_IMAGE: u32 = 2u;
const ESCAPE_ENVIRONMENT: u32 = 3u;

const LAYER_ENVIRONMENT: u32 = 2u;
const COUNT_ENVIRONMENT: u32 = 7u;
// At most 2^32 entries per CDF: the binary search ends within 33 steps.
const CDF_STEPS: u32 = 33u;

fn env_f(at: u32) -> f32 {
    return bitcast<f32>(env[at]);
}

fn env_rgb(at: u32) -> vec3<f32> {
    return vec3<f32>(env_f(at), env_f(at + 1u), env_f(at + 2u));
}

// `environment::rotate_y` by the angle whose cosine and sine are (c, s).
fn rotate_about_y(d: vec3<f32>, c: f32, s: f32) -> vec3<f32> {
    return vec3<f32>(c * d.x + s * d.z, d.y, -s * d.x + c * d.z);
}

// `environment::pixel_of`: the lat-long pixel seen in unit direction `d`.
fn latlong_pixel(w: u32, h: u32, d: vec3<f32>) -> u32 {
    let u = 0.5 + atan2(d.z, d.x) / (2.0 * PI);
    let v = acos(clamp(d.y, -1.0, 1.0)) / PI;
    let x = min(u32(max(u * f32(w), 0.0)), w - 1u);
    let y = min(u32(max(v * f32(h), 0.0)), h - 1u);
    return y * w + x;
}

// `Environment::radiance_unit`: the map seen in world direction `d`.
fn env_radiance(d: vec3<f32>) -> vec3<f32> {
    return env_rgb(env[ENV_RGB] + env_pixel(d) * 3u);
}

// The background image seen in direction `d` (`layers::escaped`).
fn background_radiance(d: vec3<f32>) -> vec3<f32> {
    let p = latlong_pixel(env[BG_WIDTH], env[BG_HEIGHT], d);
    return env_rgb(env[BG_RGB] + p * 3u);
}

// `sampler::pick` (cdf.wgsl).
fn pick(at: u32, n: u32, u: f32) -> CdfPick {
    return cdf_pick(CDF_IN_ENV, at, n, u, CDF_STEPS, 0.99999994);
}

struct EnvSample {
    // World direction.
    dir: vec3<f32>,
    pdf: f32,
    radiance: vec3<f32>,
}

// One part of the map as its sampler reads it: the offsets of its row CDF, column
// CDFs, per-pixel pdf and radiance.
struct EnvPart {
    row_cdf: u32,
    col_cdf: u32,
    pdf: u32,
    rgb: u32,
}

// The number of parts the map is sampled in (1: whole).
fn env_parts() -> u32 {
    return select(1u, 2u, env[ENV_PARTS] == 2u);
}

// Part `j` (0: the whole map, or its peaks; 1: its remainder).
fn env_part(j: u32) -> EnvPart {
    if j == 1u {
        return EnvPart(env[ENV_REST_ROW_CDF], env[ENV_REST_COL_CDF], env[ENV_REST_PDF], env[ENV_REST_RGB]);
    }
    let rgb = select(env[ENV_RGB], env[ENV_PEAKS_RGB], env[ENV_PARTS] == 2u);
    return EnvPart(env[ENV_ROW_CDF], env[ENV_COL_CDF], env[ENV_PDF], rgb);
}

// `EnvironmentSampler::sample` of `part`, rotated into the world.
fn env_sample_part(part: EnvPart, u: vec2<f32>) -> EnvSample {
    let w = env[ENV_WIDTH];
    let h = env[ENV_HEIGHT];
    let row = pick(part.row_cdf, h, u.x);
    let y = row.index;
    let col = pick(part.col_cdf + y * (w + 1u), w, u.y);
    let x = col.index;
    let phi = 2.0 * PI * ((f32(x) + col.t) / f32(w) - 0.5);
    let c0 = cos(PI * f32(y) / f32(h));
    let c1 = cos(PI * f32(y + 1u) / f32(h));
    let cos_t = c0 + (c1 - c0) * row.t;
    let sin_t = sqrt(max(1.0 - cos_t * cos_t, 0.0));
    let m = vec3<f32>(sin_t * cos(phi), cos_t, sin_t * sin(phi));
    let p = y * w + x;
    return EnvSample(
        rotate_about_y(m, env_f(ENV_COS), env_f(ENV_SIN)),
        env_f(part.pdf + p),
        env_rgb(part.rgb + p * 3u));
}

// The map's pixel seen in world direction `d`.
fn env_pixel(d: vec3<f32>) -> u32 {
    let m = rotate_about_y(d, env_f(ENV_COS), -env_f(ENV_SIN));
    return latlong_pixel(env[ENV_WIDTH], env[ENV_HEIGHT], m);
}

// `EnvironmentSampler::pdf_and_radiance` of `part` at map pixel `p`: (rgb, pdf).
fn env_part_at(part: EnvPart, p: u32) -> vec4<f32> {
    return vec4<f32>(env_rgb(part.rgb + p * 3u), env_f(part.pdf + p));
}

fn power_heuristic(a: f32, b: f32) -> f32 {
    // As a ratio: the squares of large pdfs (sharp lobes) would overflow f32.
    if a >= b {
        if a <= 0.0 {
            return 0.0;
        }
        let r = b / a;
        return 1.0 / (1.0 + r * r);
    }
    let r = a / b;
    return r * r / (1.0 + r * r);
}

// The material's sampling pdf of world `wi` (`SpmmMode::material_pdf`).
fn material_pdf(s: Shading, wi: vec3<f32>, wo: vec3<f32>) -> f32 {
    let li = vec3<f32>(dot(wi, s.t), dot(wi, s.b), dot(wi, s.n));
    let lo = vec3<f32>(dot(wo, s.t), dot(wo, s.b), dot(wo, s.n));
    let at = params.material_table + s.material * MATERIAL_WORDS;
    let kind = data[at];
    if kind == MATERIAL_BRDF {
        return brdf_pdf(load_brdf(data[at + 1u]), lo, li);
    }
    if kind == MATERIAL_SPMM {
        let m = data[at + 1u];
        return spmm_texel_pdf(m, spmm_texel_at(m, s.uv), li, lo);
    }
    if kind == MATERIAL_MERL {
        return merl_pdf(data[at + 1u], lo, li);
    }
    if kind == MATERIAL_BTF {
        return btf_pdf(data[at + 1u], li, lo);
    }
    return 0.0;
}

// A world direction drawn from the material for `wo`, with its pdf (w; 0: none).
fn material_sample(s: Shading, wo: vec3<f32>, u: vec2<f32>) -> vec4<f32> {
    let at = params.material_table + s.material * MATERIAL_WORDS;
    let kind = data[at];
    var local = vec4<f32>(0.0);
    if kind == MATERIAL_BRDF {
        let lo = vec3<f32>(dot(wo, s.t), dot(wo, s.b), dot(wo, s.n));
        local = brdf_sample(load_brdf(data[at + 1u]), lo, u);
    } else if kind == MATERIAL_MERL {
        let lo = vec3<f32>(dot(wo, s.t), dot(wo, s.b), dot(wo, s.n));
        local = merl_sample(data[at + 1u], lo, u);
    } else if kind == MATERIAL_SPMM {
        // From the texel's bases and a defensive share, as the CPU's `PackSampling::Bases`.
        let m = data[at + 1u];
        let lo = vec3<f32>(dot(wo, s.t), dot(wo, s.b), dot(wo, s.n));
        local = spmm_sample_texel(m, spmm_texel_at(m, s.uv), lo, u);
    } else if kind == MATERIAL_BTF {
        let lo = vec3<f32>(dot(wo, s.t), dot(wo, s.b), dot(wo, s.n));
        local = btf_sample(data[at + 1u], lo, u);
    }
    return vec4<f32>(s.t * local.x + s.b * local.y + s.n * local.z, local.w);
}

// `SpmmMode::sample_environment`: always draws four numbers; a map sampled in two
// parts (the adaptive mode's `sample_environment`) draws two more after them.
fn sample_environment(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    let u_map = rand2(rng);
    let u_material = rand2(rng);
    if env[ENV_LIGHTS] == 0u {
        return;
    }
    let mis = env[ENV_MIS] != 0u;
    let parts = env_parts();
    // Strategy 1: the map, one direction from each part.
    for (var j = 0u; j < parts; j++) {
        var u = u_map;
        if j > 0u {
            u = rand2(rng);
        }
        let e = env_sample_part(env_part(j), u);
        if dot(e.dir, s.n) > 0.0 && e.pdf > 0.0 {
            counts.environment += 1u;
            if !occluded(lift, e.dir, FAR) {
                var weight = 1.0;
                if mis {
                    weight = power_heuristic(e.pdf, material_pdf(s, e.dir, wo));
                }
                add_layer(pixel, LAYER_ENVIRONMENT, throughput * response(s, e.dir, wo) * e.radiance * (weight / e.pdf));
            }
        }
    }
    if !mis {
        return;
    }
    // Strategy 2: the material, weighted against each part's own strategy.
    let m = material_sample(s, wo, u_material);
    if !(m.w > 0.0) || dot(m.xyz, s.n) <= 0.0 {
        return;
    }
    counts.environment += 1u;
    if occluded(lift, m.xyz, FAR) {
        return;
    }
    let p = env_pixel(m.xyz);
    let f = throughput * response(s, m.xyz, wo);
    for (var j = 0u; j < parts; j++) {
        let at = env_part_at(env_part(j), p);
        add_layer(pixel, LAYER_ENVIRONMENT, f * at.xyz * (power_heuristic(m.w, at.w) / m.w));
    }
}
