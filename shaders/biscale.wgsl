// The biscale mode's frame on the GPU (core/modes/src/biscale/mode.rs, `sample`, is the
// reference): a jittered primary ray, mirrors as in the integrator, then at the first
// other surface the precomputed environment: L* of the refined vertices around the hit
// (the triangle's quadtree, descended with the hit's barycentric coordinates),
// interpolated, dotted with the material's tabulated BTF row for the view direction
// into the environment layer; the environment's brightest pixels (the split's peaks)
// traced with one shadow ray; the lights and the ambient term by the integrator's own
// estimators (lights.wgsl). Concatenated after integrator.wgsl, whose bindings,
// parameters and shading it uses. The biscale words (core/gpu/src/biscale.rs) sit in
// `env` after the environment's own, from `params.biscale`; every offset in their
// header is relative to that start. Every loop is bounded.

const BIS_CELLS: u32 = 0u;        // M, local cells
const BIS_LOCAL_RES: u32 = 1u;
const BIS_VIEW_RES: u32 = 2u;
const BIS_LIT: u32 = 3u;          // 1: an environment lights the scene (L* is not zero)
const BIS_MESH_FIRST: u32 = 4u;   // per mesh, its first triangle's index in the roots
const BIS_ROOTS: u32 = 5u;        // per scene triangle, its quadtree's root node
const BIS_NODES: u32 = 6u;        // LEAF_BIT | leaf, or the first of four children
const BIS_LEAVES: u32 = 7u;       // per leaf, three vertices
const BIS_LSTAR: u32 = 8u;        // per vertex, [channel][M] f32
const BIS_TABLES: u32 = 9u;       // per material: kind, offset
const BIS_PEAKS: u32 = 10u;       // 1: the peaks are traced
const BIS_PEAKS_WIDTH: u32 = 11u;
const BIS_PEAKS_HEIGHT: u32 = 12u;
const BIS_PEAKS_ROW_CDF: u32 = 13u;
const BIS_PEAKS_COL_CDF: u32 = 14u;
const BIS_PEAKS_PDF: u32 = 15u;
const BIS_PEAKS_RGB: u32 = 16u;

const TABLE_NONE: u32 = 0u;
// [view][M] rows, times the albedo (words 0..3 of the table).
const TABLE_GRAY: u32 = 1u;
// [view][channel][M] rows.
const TABLE_RGB: u32 = 2u;
// A `btf` material: each cell's response at one jittered direction (`shade_untabulated`).
const TABLE_CELLS: u32 = 3u;
// An SPMM pack: [clusters, terms], per cluster [basis rows' offset (NO_ROWS: not
// uploaded), bases, residual rows' offset (NO_ROWS: none)], then per cluster its
// basis rows [basis][view][M] and residual rows [term][view][channel][M]. The texel's
// cluster, weights and PCA coefficients are the pack the material record points at in
// `data` (spmm.wgsl's header), the GPU spmm mode's own upload.
const TABLE_SPMM: u32 = 4u;
const NO_ROWS: u32 = 0xffffffffu;
const SPMM_CLUSTER_WORDS: u32 = 3u;

const LEAF_BIT: u32 = 0x80000000u;
// `refine::MAX_DEPTH` + 1 steps.
const QUADTREE_STEPS: u32 = 13u;
// `BiscaleSettings::problem` allows at most 32 x 32 cells and 64 x 64 views.
const MAX_CELLS: u32 = 1024u;

fn bis(i: u32) -> u32 {
    return env[params.biscale + i];
}

fn bis_f(i: u32) -> f32 {
    return bitcast<f32>(env[params.biscale + i]);
}

struct Around {
    v: vec3<u32>,
    w: vec3<f32>,
}

// `Refinement::locate`: the refined vertices around barycentric (b1, b2) of scene
// triangle `t` of mesh `mesh`, with their weights.
fn locate(mesh: u32, t: u32, b1: f32, b2: f32) -> Around {
    let tri = bis(bis(BIS_MESH_FIRST) + mesh) + t;
    var node = bis(bis(BIS_NODES) + bis(bis(BIS_ROOTS) + tri));
    var u = b1;
    var v = b2;
    for (var k = 0u; k < QUADTREE_STEPS; k++) {
        if (node & LEAF_BIT) != 0u {
            let at = bis(BIS_LEAVES) + (node & ~LEAF_BIT) * 3u;
            return Around(vec3<u32>(bis(at), bis(at + 1u), bis(at + 2u)), vec3<f32>(max(1.0 - u - v, 0.0), u, v));
        }
        // `refine::child_of`.
        var child = 0u;
        if u >= 0.5 {
            child = 1u;
            u = 2.0 * u - 1.0;
            v = 2.0 * v;
        } else if v >= 0.5 {
            child = 2u;
            u = 2.0 * u;
            v = 2.0 * v - 1.0;
        } else if u + v < 0.5 {
            u = 2.0 * u;
            v = 2.0 * v;
        } else {
            child = 3u;
            u = 1.0 - 2.0 * u;
            v = 1.0 - 2.0 * v;
        }
        node = bis(bis(BIS_NODES) + node + child);
    }
    // A damaged tree: nothing (the CPU refuses such a tree before upload).
    return Around(vec3<u32>(0u), vec3<f32>(0.0));
}

// L* of cell `m`, RGB, interpolated at the hit.
fn lstar_at(a: Around, m: u32, cells: u32) -> vec3<f32> {
    let base = bis(BIS_LSTAR);
    var l = vec3<f32>(0.0);
    for (var k = 0u; k < 3u; k++) {
        let at = base + a.v[k] * 3u * cells + m;
        l += a.w[k] * vec3<f32>(bis_f(at), bis_f(at + cells), bis_f(at + 2u * cells));
    }
    return l;
}

// `hemisphere::square_to_hemisphere`.
fn square_to_hemisphere(s: vec2<f32>) -> vec3<f32> {
    let a = 2.0 * s.x - 1.0;
    let b = 2.0 * s.y - 1.0;
    if a == 0.0 && b == 0.0 {
        return vec3<f32>(0.0, 0.0, 1.0);
    }
    var r = b;
    var phi = 0.5 * PI - 0.25 * PI * (a / b);
    if abs(a) > abs(b) {
        r = a;
        phi = 0.25 * PI * (b / a);
    }
    let r2 = r * r;
    let k = sqrt(max(2.0 - r2, 0.0));
    return vec3<f32>(r * cos(phi) * k, r * sin(phi) * k, 1.0 - r2);
}

// `hemisphere::hemisphere_to_square`.
fn hemisphere_to_square(d: vec3<f32>) -> vec2<f32> {
    let z = clamp(d.z, 0.0, 1.0);
    let r = sqrt(1.0 - z);
    if r == 0.0 {
        return vec2<f32>(0.5);
    }
    let phi = atan2(d.y, d.x);
    let q = 0.25 * PI;
    var ab: vec2<f32>;
    if phi >= -q && phi <= q {
        ab = vec2<f32>(r, r * phi / q);
    } else if phi > q && phi <= 3.0 * q {
        ab = vec2<f32>(r * (2.0 * q - phi) / q, r);
    } else if phi >= -3.0 * q && phi < -q {
        ab = vec2<f32>(r * (2.0 * q + phi) / q, -r);
    } else if phi > 0.0 {
        ab = vec2<f32>(-r, -r * (phi - PI) / q);
    } else {
        ab = vec2<f32>(-r, -r * (phi + PI) / q);
    }
    return clamp((ab + 1.0) * 0.5, vec2<f32>(0.0), vec2<f32>(1.0));
}

// One of the four views around local `wo` (`HemisphereGrid::bilinear`), chosen with
// probability equal to its bilinear weight (`ViewLookup::Pick`): an unbiased
// estimate of the bilinear interpolant.
fn pick_view(wo: vec3<f32>, res: u32, u: f32) -> u32 {
    let s = hemisphere_to_square(wo);
    let n = f32(res);
    let f = clamp(s * n - 0.5, vec2<f32>(0.0), vec2<f32>(n - 1.0));
    let x0 = min(u32(floor(f.x)), res - 1u);
    let y0 = min(u32(floor(f.y)), res - 1u);
    let x1 = min(x0 + 1u, res - 1u);
    let y1 = min(y0 + 1u, res - 1u);
    let tx = f.x - f32(x0);
    let ty = f.y - f32(y0);
    // The column by its weight, then the row by its weight with what is left of
    // `u` (the product is the view's bilinear weight).
    let keep = 1.0 - tx;
    var x = x0;
    var uy = 0.0;
    if u < keep {
        uy = u / keep;
    } else {
        x = x1;
        uy = (u - keep) / max(tx, 1e-30);
    }
    let y = select(y0, y1, uy >= 1.0 - ty);
    return y * res + x;
}

// Eq. 3 for an SPMM texel (`BtfTable::shade`, `BtfTable::Spmm`): per local cell, L*
// times the texel's weighted basis rows of its cluster for `view`, plus the residual's
// mean row and its components' rows times the texel's coefficients (the first
// MOVING_NPCA while the camera moves). Texels of a cluster not uploaded, or of a pack
// no mesh carries, are dark (no ray reaches them).
fn biscale_spmm(s: Shading, at: u32, view: u32, a: Around, cells: u32) -> vec3<f32> {
    let rec = params.material_table + s.material * MATERIAL_WORDS;
    if data[rec] != MATERIAL_SPMM {
        return vec3<f32>(0.0);
    }
    let m = data[rec + 1u];
    let t = spmm_texel_at(m, s.uv);
    let c = data[data[m + SPMM_TEXEL_CLUSTER] + t];
    if c >= bis(at) {
        return vec3<f32>(0.0);
    }
    let entry = at + 2u + c * SPMM_CLUSTER_WORDS;
    let bases = bis(entry);
    if bases == NO_ROWS {
        return vec3<f32>(0.0);
    }
    let basis_count = bis(entry + 1u);
    let vc = bis(BIS_VIEW_RES) * bis(BIS_VIEW_RES);
    let offsets = data[m + SPMM_OFFSETS];
    let first = data[offsets + t];
    let last = min(data[offsets + t + 1u], first + 1024u);
    // The residual where the pack's upload has one for this cluster (the record's
    // flag; a view that hides a cluster's residual leaves its cells unset).
    var residual = bis(entry + 2u);
    let k = min(data[m + SPMM_K], 256u);
    var terms = min(bis(at + 1u), k);
    if params.moving != 0u {
        terms = min(terms, MOVING_NPCA);
    }
    let cells_at = data[m + SPMM_CLUSTER_CELLS];
    if data[rec + 2u] == 0u || data[m + SPMM_HAS_RESIDUAL] == 0u || data[cells_at + c] == NO_CLUSTER {
        residual = NO_ROWS;
    }
    let coef = data[m + SPMM_COEFFICIENTS] + t * k;
    let stride = vc * cells;
    var out = vec3<f32>(0.0);
    for (var cell = 0u; cell < cells; cell++) {
        let l = lstar_at(a, cell, cells);
        var sum = vec3<f32>(0.0);
        for (var i = first; i < last; i++) {
            let j = data[data[m + SPMM_BASIS] + i];
            if j < basis_count {
                let w = rgb_at(data[m + SPMM_RGB] + 3u * i);
                sum += w * bis_f(bases + j * stride + view * cells + cell);
            }
        }
        out += sum * l;
        if residual != NO_ROWS {
            var e = vec3<f32>(0.0);
            for (var term = 0u; term <= terms; term++) {
                var x = 1.0;
                if term > 0u {
                    x = f32_at(coef + term - 1u);
                }
                let row = residual + (term * vc + view) * 3u * cells + cell;
                e += x * vec3<f32>(bis_f(row), bis_f(row + cells), bis_f(row + 2u * cells));
            }
            out += e * l;
        }
    }
    return out;
}

// Eq. 3 at the hit: the tabulated row of the view (or, for a `btf` material, the
// response at a jittered direction per cell) dotted with L*, RGB.
fn biscale_radiance(s: Shading, wo: vec3<f32>, a: Around, rng: ptr<function, Rng>) -> vec3<f32> {
    let u_view = rand(rng);
    let jitter = rand2(rng);
    let lo = vec3<f32>(dot(wo, s.t), dot(wo, s.b), dot(wo, s.n));
    if lo.z <= 0.0 || bis(BIS_LIT) == 0u {
        return vec3<f32>(0.0);
    }
    let cells = min(bis(BIS_CELLS), MAX_CELLS);
    let table = bis(BIS_TABLES) + s.material * 2u;
    let kind = bis(table);
    let at = bis(table + 1u);
    var out = vec3<f32>(0.0);
    if kind == TABLE_GRAY || kind == TABLE_RGB {
        let view = pick_view(lo, bis(BIS_VIEW_RES), u_view);
        for (var m = 0u; m < cells; m++) {
            let l = lstar_at(a, m, cells);
            if kind == TABLE_GRAY {
                out += bis_f(at + 3u + view * cells + m) * l;
            } else {
                let row = at + view * 3u * cells + m;
                out += vec3<f32>(bis_f(row), bis_f(row + cells), bis_f(row + 2u * cells)) * l;
            }
        }
        if kind == TABLE_GRAY {
            out *= vec3<f32>(bis_f(at), bis_f(at + 1u), bis_f(at + 2u));
        }
    } else if kind == TABLE_SPMM {
        out = biscale_spmm(s, at, pick_view(lo, bis(BIS_VIEW_RES), u_view), a, cells);
    } else if kind == TABLE_CELLS {
        let res = max(bis(BIS_LOCAL_RES), 1u);
        for (var m = 0u; m < cells; m++) {
            let c = vec2<f32>(f32(m % res), f32(m / res));
            let li = square_to_hemisphere((c + jitter) / f32(res));
            let wi = s.t * li.x + s.b * li.y + s.n * li.z;
            out += response(s, wi, wo) * lstar_at(a, m, cells);
        }
    }
    return out;
}

// `EnvironmentSampler::sample` of the split's peaks, rotated into the world as the
// map is (the environment's own rotation in `env`).
fn peaks_sample(u: vec2<f32>) -> EnvSample {
    let w = bis(BIS_PEAKS_WIDTH);
    let h = bis(BIS_PEAKS_HEIGHT);
    let row = cdf_pick(CDF_IN_ENV, params.biscale + bis(BIS_PEAKS_ROW_CDF), h, u.x, CDF_STEPS, 0.99999994);
    let y = row.index;
    let col = cdf_pick(CDF_IN_ENV, params.biscale + bis(BIS_PEAKS_COL_CDF) + y * (w + 1u), w, u.y, CDF_STEPS, 0.99999994);
    let x = col.index;
    let phi = 2.0 * PI * ((f32(x) + col.t) / f32(w) - 0.5);
    let c0 = cos(PI * f32(y) / f32(h));
    let c1 = cos(PI * f32(y + 1u) / f32(h));
    let cos_t = c0 + (c1 - c0) * row.t;
    let sin_t = sqrt(max(1.0 - cos_t * cos_t, 0.0));
    let m = vec3<f32>(sin_t * cos(phi), cos_t, sin_t * sin(phi));
    let p = y * w + x;
    let rgb = bis(BIS_PEAKS_RGB) + p * 3u;
    return EnvSample(
        rotate_about_y(m, env_f(ENV_COS), env_f(ENV_SIN)),
        bis_f(bis(BIS_PEAKS_PDF) + p),
        vec3<f32>(bis_f(rgb), bis_f(rgb + 1u), bis_f(rgb + 2u)));
}

// The peaks' part (`BiscaleMode::trace_exact`): one direction drawn from them, one
// shadow ray. Always draws two numbers.
fn sample_peaks(s: Shading, wo: vec3<f32>, lift: vec3<f32>, throughput: vec3<f32>, pixel: u32, rng: ptr<function, Rng>) {
    let u = rand2(rng);
    if bis(BIS_PEAKS) == 0u {
        return;
    }
    let e = peaks_sample(u);
    if e.pdf > 0.0 && dot(e.dir, s.n) > 0.0 {
        counts.environment += 1u;
        if !occluded(lift, e.dir, FAR) {
            add_layer(pixel, LAYER_ENVIRONMENT, throughput * response(s, e.dir, wo) * e.radiance / e.pdf);
        }
    }
}

@compute @workgroup_size(64)
fn render_biscale(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = pixel_of_invocation(id, groups);
    if pixel >= params.width * params.height {
        return;
    }
    var rng = start_sample(pixel);
    let r = first_surface(pixel, &rng);
    if r.found {
        let wo = -r.dir;
        let lift = lifted(r.s);
        // The hit's barycentric coordinates, as `shading_at` finds them.
        let b = barycentrics(r.prim, r.origin + r.dir * r.t);
        let t = r.prim * TRI_WORDS;
        let around = locate(tris[t + 10u], tris[t + 11u], b.x, b.y);
        add_layer(pixel, LAYER_ENVIRONMENT, r.throughput * biscale_radiance(r.s, wo, around, &rng));
        sample_peaks(r.s, wo, lift, r.throughput, pixel, &rng);
        sample_lights(r.s, wo, lift, r.throughput, pixel, &rng);
        sample_ambient(r.s, wo, lift, r.throughput, pixel, &rng);
    }
    finish_sample(pixel, 1u);
}
