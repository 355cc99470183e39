// `btf` materials (core/materials/src/btf/table.rs): the nearest texel's reflectance, tiled like
// an SPMM pack, interpolated over the light and the view direction sets exactly as the
// SPMM residual is (`direction_weights` in spmm.wgsl: barycentric weights in the
// Delaunay triangle holding the projected direction, the nearest hull point outside;
// on the light side the value over cos theta_l, times the query's cos theta:
// `cosine_weights`), so BTF(t, wi, wo) = cos theta_i sum_l sum_v w_l(wi) w_v(wo)
// table(t, l, v) / cos theta_l, at most 3 x 3 reads.
// Values are f16 two to a word (low half first) when the CPU holds them as f16, else f32.
// Light directions are drawn from the table's texel-mean lobe, per tabulated view a
// CDF over a fixed grid of cells (core/materials/src/btf/lobe.rs), mixed over the
// query's view weights, plus the defensive share (`BtfTable::sample`).

// Header of one BTF in `data` (core/gpu/src/data.rs, `push_btf`).
const BTF_WIDTH: u32 = 0u;
const BTF_HEIGHT: u32 = 1u;
const BTF_LIGHTS: u32 = 2u;
const BTF_VIEWS: u32 = 3u;
const BTF_VALUES: u32 = 4u;
const BTF_HALF: u32 = 5u;
const BTF_LIGHT_TABLE: u32 = 6u;
const BTF_VIEW_TABLE: u32 = 7u;
const BTF_UV_SCALE: u32 = 8u;
// Two words of UV scale, then the lobe's CDFs: `BTF_CELLS + 1` f32 per view.
const BTF_LOBE: u32 = 10u;

// The lobe's grid (`lobe::RINGS`, `lobe::SECTORS`): rings uniform in
// r = sqrt(1 - cos theta), equal azimuth sectors; cells ring-major.
const BTF_RINGS: u32 = 16u;
const BTF_SECTORS: u32 = 32u;
const BTF_CELLS: u32 = 512u;
// Bisection steps over a view's CDF: ceil(log2(BTF_CELLS)) + 1.
const BTF_PICK_STEPS: u32 = 10u;

// Value `i` of the table at `m`.
fn btf_value(m: u32, i: u32) -> f32 {
    let at = data[m + BTF_VALUES];
    if data[m + BTF_HALF] != 0u {
        return half_at(2u * at + i);
    }
    return f32_at(at + i);
}

// BTF(t, wi, wo), RGB, of texel `t`; zero unless both directions are above the surface.
fn btf_eval_texel(m: u32, t: u32, wi: vec3<f32>, wo: vec3<f32>) -> vec3<f32> {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return vec3<f32>(0.0);
    }
    let nl = data[m + BTF_LIGHTS];
    let nv = data[m + BTF_VIEWS];
    let lw = cosine_weights(data[m + BTF_LIGHT_TABLE], wi);
    let vw = direction_weights(data[m + BTF_VIEW_TABLE], wo);
    var rgb = vec3<f32>(0.0);
    for (var a = 0u; a < 3u; a++) {
        if lw.weight[a] == 0.0 {
            continue;
        }
        for (var b = 0u; b < 3u; b++) {
            let w = lw.weight[a] * vw.weight[b];
            if w != 0.0 {
                let i = ((t * nl + lw.index[a]) * nv + vw.index[b]) * 3u;
                rgb += w * vec3<f32>(btf_value(m, i), btf_value(m, i + 1u), btf_value(m, i + 2u));
            }
        }
    }
    return rgb;
}

// The texel a UV position falls in (`BtfTable::eval_uv`).
fn btf_texel_at(m: u32, uv: vec2<f32>) -> u32 {
    let scale = vec2<f32>(f32_at(m + BTF_UV_SCALE), f32_at(m + BTF_UV_SCALE + 1u));
    return texel_in_grid(data[m + BTF_WIDTH], data[m + BTF_HEIGHT], scale, uv);
}

// cos theta at the top (x) and bottom (y) of ring `ring`.
fn btf_ring_z(ring: u32) -> vec2<f32> {
    let a = f32(ring) / f32(BTF_RINGS);
    let b = f32(ring + 1u) / f32(BTF_RINGS);
    return vec2<f32>(1.0 - a * a, 1.0 - b * b);
}

fn btf_cell_solid_angle(ring: u32) -> f32 {
    let z = btf_ring_z(ring);
    return (z.x - z.y) * 2.0 * PI / f32(BTF_SECTORS);
}

// The lobe's pdf of light direction `li` for view weights `vw` (`LobeSampler::pdf`).
fn btf_lobe_pdf(m: u32, vw: DirectionWeights, li: vec3<f32>) -> f32 {
    if li.z <= 0.0 {
        return 0.0;
    }
    let r = sqrt(max(1.0 - li.z, 0.0));
    let ring = min(u32(r * f32(BTF_RINGS)), BTF_RINGS - 1u);
    let turn = 2.0 * PI;
    var phi = atan2(li.y, li.x);
    phi = phi - turn * floor(phi / turn);
    let sector = min(u32(max(phi / turn * f32(BTF_SECTORS), 0.0)), BTF_SECTORS - 1u);
    let cell = ring * BTF_SECTORS + sector;
    let lobe = data[m + BTF_LOBE];
    var p = 0.0;
    for (var k = 0u; k < 3u; k++) {
        if vw.weight[k] > 0.0 {
            let at = lobe + vw.index[k] * (BTF_CELLS + 1u) + cell;
            p += vw.weight[k] * (f32_at(at + 1u) - f32_at(at));
        }
    }
    return p / btf_cell_solid_angle(ring);
}

// The pdf with which `btf_sample` draws `wi` for `wo` (`BtfTable::pdf`).
fn btf_pdf(m: u32, wi: vec3<f32>, wo: vec3<f32>) -> f32 {
    if wo.z <= 0.0 {
        return 0.0;
    }
    return btf_mixture_pdf(m, direction_weights(data[m + BTF_VIEW_TABLE], wo), wi);
}

// `btf_pdf` for a view with interpolation weights `vw`.
fn btf_mixture_pdf(m: u32, vw: DirectionWeights, wi: vec3<f32>) -> f32 {
    return DEFENSIVE_SHARE * defensive_pdf(wi) + (1.0 - DEFENSIVE_SHARE) * btf_lobe_pdf(m, vw, wi);
}

// A light direction for `wo` and its pdf (w; 0: none), as `BtfTable::sample`: the first
// number picks the defensive mixture or the lobe, then the view and the cell, and,
// rescaled, cos theta in the cell; the second the azimuth.
fn btf_sample(m: u32, wo: vec3<f32>, u: vec2<f32>) -> vec4<f32> {
    if wo.z <= 0.0 {
        return vec4<f32>(0.0);
    }
    let vw = direction_weights(data[m + BTF_VIEW_TABLE], wo);
    var wi: vec3<f32>;
    if u.x < DEFENSIVE_SHARE {
        wi = defensive_sample(vec2<f32>(u.x / DEFENSIVE_SHARE, u.y));
    } else {
        var x = (u.x - DEFENSIVE_SHARE) / (1.0 - DEFENSIVE_SHARE);
        var view = 0u;
        var found = false;
        for (var k = 0u; k < 3u; k++) {
            let w = vw.weight[k];
            if w > 0.0 && !found {
                view = vw.index[k];
                if x < w {
                    x = x / w;
                    found = true;
                } else {
                    x = x - w;
                }
            }
        }
        x = min(x, BELOW_ONE);
        let pick = cdf_pick(CDF_IN_DATA, data[m + BTF_LOBE] + view * (BTF_CELLS + 1u), BTF_CELLS, x, BTF_PICK_STEPS, 1.0);
        let ring = pick.index / BTF_SECTORS;
        let sector = pick.index % BTF_SECTORS;
        let z = btf_ring_z(ring);
        let cos_theta = z.x + (z.y - z.x) * pick.t;
        if cos_theta <= 0.0 {
            return vec4<f32>(0.0);
        }
        let phi = (f32(sector) + u.y) * 2.0 * PI / f32(BTF_SECTORS);
        wi = spherical_dir(cos_theta, sqrt(max(1.0 - cos_theta * cos_theta, 0.0)), phi);
    }
    let pdf = btf_mixture_pdf(m, vw, wi);
    if wi.z <= 0.0 || !(pdf > 0.0) {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(wi, pdf);
}
