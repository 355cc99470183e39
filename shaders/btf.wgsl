// `btf` materials (core/materials/src/btf/table.rs): the nearest texel's reflectance, tiled like
// an SPMM pack, interpolated over the light and the view direction sets exactly as the
// SPMM residual is (`direction_weights` in spmm.wgsl: barycentric weights in the
// Delaunay triangle holding the projected direction, the nearest hull point outside;
// on the light side the value over cos theta_l, times the query's cos theta:
// `cosine_weights`), so BTF(t, wi, wo) = cos theta_i sum_l sum_v w_l(wi) w_v(wo)
// table(t, l, v) / cos theta_l, at most 3 x 3 reads.
// Values are f16 two to a word (low half first) when the CPU holds them as f16, else f32.

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
