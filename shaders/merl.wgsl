// MERL materials (core/materials/src/merl/ is the reference): the table looked up at the cell
// that holds the pair's Rusinkiewicz half/difference angles, as the MERL reader and
// `MerlBrdf::eval` do (nearest cell, the same atan2 forms and fold), and the CPU's
// tabulated importance sampling (`MerlSampler`: per band of theta_o a piecewise-
// constant density over (cos theta_i, phi_i - phi_o)) from its own tables in f32.
// Record in `data` (7 words): the offsets of the table (RGB per cell, scaled; cells
// without data 0), the cell probabilities, the row CDFs and the column CDFs, then the
// albedo at normal view (RGB, the denoiser's guide: guides.wgsl).

const MERL_THETA_H: u32 = 90u;
const MERL_THETA_D: u32 = 90u;
const MERL_PHI_D: u32 = 180u;
const MERL_BANDS: u32 = 45u;
const MERL_Z: u32 = 64u;
const MERL_PHI: u32 = 128u;
const MERL_HALF_PI: f32 = 1.57079632679490;
// The CDFs have at most 129 entries: a binary search ends within 9 steps.
const MERL_PICK_STEPS: u32 = 9u;

// `HalfDiff::from_directions(wi, wo).cell()`.
fn merl_cell(wi: vec3<f32>, wo: vec3<f32>) -> u32 {
    let s = wi + wo;
    let d = wi - wo;
    let s_len = length(s);
    let s_xy = length(s.xy);
    let theta_h = atan2(s_xy, s.z);
    let theta_d = atan2(length(d), s_len);
    var cos_ph = 1.0;
    var sin_ph = 0.0;
    if s_xy > 0.0 {
        cos_ph = s.x / s_xy;
        sin_ph = s.y / s_xy;
    }
    let cos_th = s.z / s_len;
    let sin_th = s_xy / s_len;
    var x = cos_th * (cos_ph * d.x + sin_ph * d.y) - sin_th * d.z;
    var y = cos_ph * d.y - sin_ph * d.x;
    if y < 0.0 || (y == 0.0 && x < 0.0) {
        x = -x;
        y = -y;
    }
    let phi_d = atan2(abs(y), x);
    let th = min(u32(max(sqrt(max(theta_h / MERL_HALF_PI, 0.0)) * f32(MERL_THETA_H), 0.0)), MERL_THETA_H - 1u);
    let td = min(u32(max(theta_d / MERL_HALF_PI * f32(MERL_THETA_D), 0.0)), MERL_THETA_D - 1u);
    let pd = min(u32(max(phi_d / PI * f32(MERL_PHI_D), 0.0)), MERL_PHI_D - 1u);
    return pd + MERL_PHI_D * (td + MERL_THETA_D * th);
}

// `MerlBrdf::eval`: f(wi, wo) per channel, local frame.
fn merl_eval(m: u32, wi: vec3<f32>, wo: vec3<f32>) -> vec3<f32> {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return vec3<f32>(0.0);
    }
    return rgb_at(data[m] + 3u * merl_cell(wi, wo));
}

fn merl_band(wo: vec3<f32>) -> u32 {
    let theta_o = atan2(length(wo.xy), wo.z);
    return min(u32(max(theta_o / MERL_HALF_PI * f32(MERL_BANDS), 0.0)), MERL_BANDS - 1u);
}

// `sample::pick`: the bin of the CDF at `at` (n + 1 entries in `data`) holding `u`
// (cdf.wgsl).
fn merl_pick(at: u32, n: u32, u: f32) -> CdfPick {
    return cdf_pick(CDF_IN_DATA, at, n, u, MERL_PICK_STEPS, 1.0);
}

const MERL_CELL_SOLID_ANGLE: f32 = 7.66990393942820e-4; // 2 pi / (64 x 128)

// `MerlSampler::pdf`.
fn merl_pdf(m: u32, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return 0.0;
    }
    let band = merl_band(wo);
    let row = min(u32(max(wi.z * f32(MERL_Z), 0.0)), MERL_Z - 1u);
    let turn = 2.0 * PI;
    var phi = atan2(wi.y, wi.x) - atan2(wo.y, wo.x);
    phi = phi - turn * floor(phi / turn);
    let col = min(u32(max(phi / turn * f32(MERL_PHI), 0.0)), MERL_PHI - 1u);
    return f32_at(data[m + 1u] + (band * MERL_Z + row) * MERL_PHI + col) / MERL_CELL_SOLID_ANGLE;
}

// `MerlSampler::sample`: wi and its pdf (w; 0: none).
fn merl_sample(m: u32, wo: vec3<f32>, u: vec2<f32>) -> vec4<f32> {
    if wo.z <= 0.0 {
        return vec4<f32>(0.0);
    }
    let band = merl_band(wo);
    let row = merl_pick(data[m + 2u] + band * (MERL_Z + 1u), MERL_Z, u.x);
    let col = merl_pick(data[m + 3u] + (band * MERL_Z + row.index) * (MERL_PHI + 1u), MERL_PHI, u.y);
    let z = min((f32(row.index) + row.t) / f32(MERL_Z), 1.0);
    if z <= 0.0 {
        return vec4<f32>(0.0);
    }
    let phi = (f32(col.index) + col.t) / f32(MERL_PHI) * 2.0 * PI + atan2(wo.y, wo.x);
    let pdf = f32_at(data[m + 1u] + (band * MERL_Z + row.index) * MERL_PHI + col.index) / MERL_CELL_SOLID_ANGLE;
    return vec4<f32>(spherical_dir(z, sqrt(max(1.0 - z * z, 0.0)), phi), pdf);
}
