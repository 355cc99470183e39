// SPMM evaluation (Silva & Santos 2013 eq. 1-3) in f32, mirroring
// core/materials/src/spmm/prepared.rs: the sparse basis sum of a texel plus its cluster's PCA
// residual, interpolated over the tabulated light and view directions (the light
// side over value / cos theta_l, `cosine_weights`)
// (core/materials/src/spmm/directions.rs: a DIRECTION_GRID x DIRECTION_GRID grid of triangle
// lists over the projected directions, barycentric weights, the nearest hull edge
// outside the hull; this shader tests every hull edge, the CPU only its cell's list).
// Every loop is bounded by a count read from the data (llvmpipe ends loops silently).

// Header of one prepared SPMM material in `data` (word offsets are absolute).
const SPMM_WIDTH: u32 = 0u;
const SPMM_HEIGHT: u32 = 1u;
const SPMM_TEXEL_CLUSTER: u32 = 2u;
const SPMM_OFFSETS: u32 = 3u;
const SPMM_BASIS: u32 = 4u;
const SPMM_RGB: u32 = 5u;
const SPMM_CLUSTER_BASES: u32 = 6u;
const SPMM_HAS_RESIDUAL: u32 = 7u;
const SPMM_K: u32 = 8u;
const SPMM_CLUSTER_CELLS: u32 = 9u;
const SPMM_COEFFICIENTS: u32 = 10u;
const SPMM_LIGHT_TABLE: u32 = 11u;
const SPMM_VIEW_TABLE: u32 = 12u;
const SPMM_UV_SCALE_X: u32 = 13u;
const SPMM_UV_SCALE_Y: u32 = 14u;
// 1: the residual's cells are half floats two to a word, and the cluster table holds
// value indices (twice a word index); 0: f32 cells at word indices.
const SPMM_RESIDUAL_HALF: u32 = 15u;
const SPMM_HEADER_WORDS: u32 = 16u;

const NO_CLUSTER: u32 = 0xffffffffu;
const DIRECTION_GRID: u32 = 32u;
// Components a moving camera keeps (`spmm::MOVING_NPCA`); every prepared one otherwise.
const MOVING_NPCA: u32 = 4u;
const ALL_COMPONENTS: u32 = 0xffffffffu;

fn f32_at(i: u32) -> f32 {
    return bitcast<f32>(data[i]);
}

fn rgb_at(i: u32) -> vec3<f32> {
    return vec3<f32>(f32_at(i), f32_at(i + 1u), f32_at(i + 2u));
}

// The half float at value index `i` of the data (two to a word, the low half first).
fn half_at(i: u32) -> f32 {
    let pair = unpack2x16float(data[i / 2u]);
    return select(pair.x, pair.y, i % 2u == 1u);
}

// Residual value `i`: f32 at word `i`, or the half float at value index `i`.
fn residual_at(i: u32, halves: bool) -> f32 {
    if halves {
        return half_at(i);
    }
    return f32_at(i);
}

fn residual_rgb_at(i: u32, halves: bool) -> vec3<f32> {
    return vec3<f32>(residual_at(i, halves), residual_at(i + 1u, halves), residual_at(i + 2u, halves));
}

struct DirectionWeights {
    index: vec3<u32>,
    weight: vec3<f32>,
}

fn grid_cell(v: f32) -> u32 {
    return u32(clamp(i32((v + 1.0) * 0.5 * f32(DIRECTION_GRID)), 0, i32(DIRECTION_GRID) - 1));
}

fn cross2(a: vec2<f32>, b: vec2<f32>) -> f32 {
    return a.x * b.y - a.y * b.x;
}

// Table record: [points, points_at, triangles_at, cell_starts_at (1025 words),
// cell_triangles_at, hull_len, hull_at].
fn direction_weights(table: u32, d: vec3<f32>) -> DirectionWeights {
    let points = data[table + 1u];
    let tris = data[table + 2u];
    let starts = data[table + 3u];
    let cell_tris = data[table + 4u];
    let p = d.xy;
    let cell = grid_cell(p.y) * DIRECTION_GRID + grid_cell(p.x);
    let first = data[starts + cell];
    let last = min(data[starts + cell + 1u], first + 4096u);
    for (var i = first; i < last; i++) {
        let ti = data[cell_tris + i];
        let a = data[tris + 3u * ti];
        let b = data[tris + 3u * ti + 1u];
        let c = data[tris + 3u * ti + 2u];
        let pa = vec2<f32>(f32_at(points + 2u * a), f32_at(points + 2u * a + 1u));
        let pb = vec2<f32>(f32_at(points + 2u * b), f32_at(points + 2u * b + 1u));
        let pc = vec2<f32>(f32_at(points + 2u * c), f32_at(points + 2u * c + 1u));
        let area = cross2(pb - pa, pc - pa);
        let wa = cross2(pb - p, pc - p) / area;
        let wb = cross2(pc - p, pa - p) / area;
        let wc = 1.0 - wa - wb;
        // f32 barycentrics of a point on a shared edge can miss both triangles by an
        // ulp; the interpolant is continuous there, so a small tolerance is exact enough.
        let eps = -1e-5;
        if wa >= eps && wb >= eps && wc >= eps {
            let w = max(vec3<f32>(wa, wb, wc), vec3<f32>(0.0));
            return DirectionWeights(vec3<u32>(a, b, c), w / (w.x + w.y + w.z));
        }
    }
    // Outside the hull: the nearest point on its boundary.
    let hull_len = min(data[table + 5u], 4096u);
    let hull = data[table + 6u];
    var best = 3.4e38;
    var result = DirectionWeights(vec3<u32>(0u), vec3<f32>(1.0, 0.0, 0.0));
    for (var i = 0u; i < hull_len; i++) {
        let a = data[hull + i];
        let b = data[hull + (i + 1u) % hull_len];
        let pa = vec2<f32>(f32_at(points + 2u * a), f32_at(points + 2u * a + 1u));
        let pb = vec2<f32>(f32_at(points + 2u * b), f32_at(points + 2u * b + 1u));
        let ab = pb - pa;
        let s = clamp(dot(p - pa, ab) / dot(ab, ab), 0.0, 1.0);
        let q = p - (pa + ab * s);
        let dist = dot(q, q);
        if dist < best {
            best = dist;
            result = DirectionWeights(vec3<u32>(a, b, b), vec3<f32>(1.0 - s, s, 0.0));
        }
    }
    return result;
}

// The largest factor cos theta_i / cos theta_l (`MAX_COSINE_RATIO` in
// core/materials/src/spmm/directions.rs).
const MAX_COSINE_RATIO: f32 = 20.0;

// Light-side weights of a tabulated quantity that includes the light's foreshortening
// cosine, a BTF or a residual (`DirectionTable::cosine_weights`): the value over
// cos theta_l is interpolated and the query's cos theta applied, so the cosine is
// exact everywhere and the value fades to zero at the horizon beyond the outer ring.
fn cosine_weights(table: u32, d: vec3<f32>) -> DirectionWeights {
    var w = direction_weights(table, d);
    let points = data[table + 1u];
    let c = max(d.z, 0.0);
    for (var a = 0u; a < 3u; a++) {
        let i = w.index[a];
        let p = vec2<f32>(f32_at(points + 2u * i), f32_at(points + 2u * i + 1u));
        let cos_l = sqrt(max(1.0 - dot(p, p), 0.0));
        // min(c / cos_l, MAX_COSINE_RATIO) without dividing by a zero cosine.
        w.weight[a] *= min(c, MAX_COSINE_RATIO * cos_l) / max(cos_l, 1e-30);
    }
    return w;
}

// BTF(t, wi, wo), RGB, of texel `t` of the material whose header is at `m`;
// `residual` false skips the residual, else its mean and at most `components` of its
// components are added (`MOVING_NPCA` while the camera moves, as on the CPU).
fn spmm_eval_texel(
    m: u32,
    t: u32,
    wi: vec3<f32>,
    wo: vec3<f32>,
    residual: bool,
    components: u32,
) -> vec3<f32> {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return vec3<f32>(0.0);
    }
    let c = data[data[m + SPMM_TEXEL_CLUSTER] + t];
    let bases = data[data[m + SPMM_CLUSTER_BASES] + c];
    let offsets = data[m + SPMM_OFFSETS];
    let first = data[offsets + t];
    let last = min(data[offsets + t + 1u], first + 1024u);
    var rgb = vec3<f32>(0.0);
    for (var i = first; i < last; i++) {
        let j = data[data[m + SPMM_BASIS] + i];
        let w = rgb_at(data[m + SPMM_RGB] + 3u * i);
        rgb += w * basis_eval(bases + j * BASIS_WORDS, wi, wo);
    }
    if !residual || data[m + SPMM_HAS_RESIDUAL] == 0u {
        return rgb;
    }
    let base = data[data[m + SPMM_CLUSTER_CELLS] + c];
    if base == NO_CLUSTER {
        return rgb;
    }
    let k = min(data[m + SPMM_K], 256u);
    let stride = (1u + k) * 3u;
    let summed = min(k, components);
    let views = data[m + SPMM_VIEW_TABLE];
    let nv = data[views];
    let coef = data[m + SPMM_COEFFICIENTS] + t * k;
    let halves = data[m + SPMM_RESIDUAL_HALF] != 0u;
    let lw = cosine_weights(data[m + SPMM_LIGHT_TABLE], wi);
    let vw = direction_weights(views, wo);
    for (var a = 0u; a < 3u; a++) {
        for (var b = 0u; b < 3u; b++) {
            let w = lw.weight[a] * vw.weight[b];
            if w == 0.0 {
                continue;
            }
            let cell = base + (lw.index[a] * nv + vw.index[b]) * stride;
            var e = residual_rgb_at(cell, halves);
            for (var kk = 0u; kk < summed; kk++) {
                e += f32_at(coef + kk) * residual_rgb_at(cell + 3u + 3u * kk, halves);
            }
            rgb += w * e;
        }
    }
    return rgb;
}

// The row-major texel a UV position falls in (nearest, tiled by the material's scale).
fn spmm_texel_at(m: u32, uv: vec2<f32>) -> u32 {
    let scale = vec2<f32>(f32_at(m + SPMM_UV_SCALE_X), f32_at(m + SPMM_UV_SCALE_Y));
    return texel_in_grid(data[m + SPMM_WIDTH], data[m + SPMM_HEIGHT], scale, uv);
}

// `TexelGrid::nearest`: the row-major texel of a `w` x `h` grid tiled by `scale` that
// `uv` falls in (u right, v up, row 0 the top, wrapping); SPMM packs and BTFs alike.
fn texel_in_grid(w: u32, h: u32, scale: vec2<f32>, uv: vec2<f32>) -> u32 {
    let su = uv.x * scale.x;
    let sv = uv.y * scale.y;
    let u = su - floor(su);
    let v = sv - floor(sv);
    let x = u32(clamp(i32(floor(u * f32(w))), 0, i32(w) - 1));
    let y = u32(clamp(i32(floor((1.0 - v) * f32(h))), 0, i32(h) - 1));
    return y * w + x;
}

// Importance sampling of a texel's BTF (core/materials/src/spmm/prepared/sampling.rs): a mixture
// of the texel's own bases, each drawn by its BRDF's sampler in its own frame and
// chosen in proportion to its weight's luminance times its selection albedo (word 17
// of its record), plus DEFENSIVE_SHARE of the half-cosine, half-uniform mixture.
const DEFENSIVE_SHARE: f32 = 0.1;
const BASIS_ALBEDO: u32 = 17u;
// The largest f32 below 1 (the CPU clamps to 1 - f64::EPSILON).
const BELOW_ONE: f32 = 0.99999994;

// The defensive mixture's direction from two uniform numbers (`defensive_sample`).
fn defensive_sample(u: vec2<f32>) -> vec3<f32> {
    if u.x < 0.5 {
        return cosine_dir(vec2<f32>(2.0 * u.x, u.y));
    }
    let z = 1.0 - u.y;
    let r = sqrt(max(1.0 - z * z, 0.0));
    let phi = 2.0 * PI * (2.0 * u.x - 1.0);
    return vec3<f32>(r * cos(phi), r * sin(phi), z);
}

// Its solid-angle pdf (`defensive_pdf`).
fn defensive_pdf(w: vec3<f32>) -> f32 {
    return select(0.0, 0.5 * w.z * INV_PI + 0.25 * INV_PI, w.z > 0.0);
}

// A texel's weight entries and the sum of their selection weights.
struct Selection {
    first: u32,
    last: u32,
    // The cluster's first basis record.
    bases: u32,
    total: f32,
}

// Selection weight of weight entry `i` whose cluster's bases start at `bases`.
fn spmm_selection(m: u32, bases: u32, i: u32) -> f32 {
    let w = rgb_at(data[m + SPMM_RGB] + 3u * i);
    let luminance = 0.2126 * w.x + 0.7152 * w.y + 0.0722 * w.z;
    let j = data[data[m + SPMM_BASIS] + i];
    let s = max(luminance, 0.0) * f32_at(bases + j * BASIS_WORDS + BASIS_ALBEDO);
    return select(0.0, s, s < F32_MAX);
}

fn spmm_selection_total(m: u32, t: u32) -> Selection {
    let c = data[data[m + SPMM_TEXEL_CLUSTER] + t];
    let bases = data[data[m + SPMM_CLUSTER_BASES] + c];
    let offsets = data[m + SPMM_OFFSETS];
    let first = data[offsets + t];
    let last = min(data[offsets + t + 1u], first + 1024u);
    var total = 0.0;
    for (var i = first; i < last; i++) {
        total += spmm_selection(m, bases, i);
    }
    return Selection(first, last, bases, total);
}

// A basis record's frame as columns (x, y, z), from words 8 to 16.
fn basis_frame(at: u32) -> mat3x3<f32> {
    return mat3x3<f32>(rgb_at(at + 8u), rgb_at(at + 11u), rgb_at(at + 14u));
}

// The mixture's pdf of texel-frame `wi` for `wo` (`mixture_pdf`).
fn spmm_mixture_pdf(m: u32, sel: Selection, wi: vec3<f32>, wo: vec3<f32>) -> f32 {
    if sel.total <= 0.0 {
        return defensive_pdf(wi);
    }
    var mixture = 0.0;
    for (var i = sel.first; i < sel.last; i++) {
        let s = spmm_selection(m, sel.bases, i);
        if s > 0.0 {
            let at = sel.bases + data[data[m + SPMM_BASIS] + i] * BASIS_WORDS;
            let frame = basis_frame(at);
            // Transposed: world (texel frame) to the basis's local frame.
            mixture += s * brdf_pdf(load_brdf(at), wo * frame, wi * frame);
        }
    }
    return DEFENSIVE_SHARE * defensive_pdf(wi) + (1.0 - DEFENSIVE_SHARE) * mixture / sel.total;
}

// The solid-angle density with which `spmm_sample_texel(m, t, wo, .)` returns `wi`
// (`PreparedSpmm::texel_pdf`).
fn spmm_texel_pdf(m: u32, t: u32, wi: vec3<f32>, wo: vec3<f32>) -> f32 {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return 0.0;
    }
    return spmm_mixture_pdf(m, spmm_selection_total(m, t), wi, wo);
}

// A direction (texel frame) drawn for `wo` at texel `t` with its pdf (w; 0: none, as the
// CPU's `None`), from two uniform numbers (`PreparedSpmm::sample_texel`).
fn spmm_sample_texel(m: u32, t: u32, wo: vec3<f32>, u: vec2<f32>) -> vec4<f32> {
    if wo.z <= 0.0 {
        return vec4<f32>(0.0);
    }
    let sel = spmm_selection_total(m, t);
    var wi: vec3<f32>;
    if sel.total <= 0.0 || u.x < DEFENSIVE_SHARE {
        var x = u.x;
        if sel.total > 0.0 {
            x = u.x / DEFENSIVE_SHARE;
        }
        wi = defensive_sample(vec2<f32>(min(x, BELOW_ONE), u.y));
    } else {
        // u.x again: its position inside the chosen entry's interval is uniform.
        var x = (u.x - DEFENSIVE_SHARE) / (1.0 - DEFENSIVE_SHARE) * sel.total;
        var chosen = sel.last - 1u;
        for (var i = sel.first; i < sel.last; i++) {
            let s = spmm_selection(m, sel.bases, i);
            if x < s {
                chosen = i;
                x = x / s;
                break;
            }
            x -= s;
        }
        let at = sel.bases + data[data[m + SPMM_BASIS] + chosen] * BASIS_WORDS;
        let frame = basis_frame(at);
        let b = brdf_sample(load_brdf(at), wo * frame, vec2<f32>(clamp(x, 0.0, BELOW_ONE), u.y));
        if !(b.w > 0.0) {
            return vec4<f32>(0.0);
        }
        wi = frame * b.xyz;
    }
    if wi.z <= 0.0 {
        return vec4<f32>(0.0);
    }
    let pdf = spmm_mixture_pdf(m, sel, wi, wo);
    if pdf > 0.0 && pdf < F32_MAX {
        return vec4<f32>(wi, pdf);
    }
    return vec4<f32>(0.0);
}
