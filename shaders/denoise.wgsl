// The viewport denoiser on the device (core/render/src/denoise/reference.rs is the
// reference): one a-trous pass of the edge-avoiding B3-spline filter per dispatch
// (`atrous`, step 2^pass), then the studio's blend of the filtered image with the
// estimate (`blend`). Guides as shaders/guides.wgsl writes them: per pixel two vec4s,
// (normal, distance) and (albedo, 0). Images: one vec4 per pixel, linear RGB. One
// invocation per pixel; every loop runs over the kernel's 5 x 5 taps or an exponent's
// bits.

struct DenoiseParams {
    width: u32,
    height: u32,
    // 2^pass: the distance between taps.
    step: u32,
    normal_power: u32,
    // 1 / sigma_c^2 of this pass.
    inv_color: f32,
    sigma_depth: f32,
    sigma_albedo: f32,
    // blend: the denoised image's share, in [0, 1].
    strength: f32,
}

@group(0) @binding(0) var<uniform> dp: DenoiseParams;
@group(0) @binding(1) var<storage, read> guide: array<vec4<f32>>;
// atrous: the pass's input; blend: the filtered image.
@group(0) @binding(2) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> dst: array<vec4<f32>>;
// blend: the estimate.
@group(0) @binding(4) var<storage, read> noisy: array<vec4<f32>>;

const B3: array<f32, 5> = array<f32, 5>(0.0625, 0.25, 0.375, 0.25, 0.0625);
const DENOISE_INFINITY: u32 = 0x7f800000u;

fn denoise_pixel(id: vec3<u32>, groups: vec3<u32>) -> u32 {
    return id.x + id.y * groups.x * 64u;
}

// Finite by its bits: a compiler's fast-math may fold `x != x` away.
fn denoise_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & DENOISE_INFINITY) != DENOISE_INFINITY;
}

// `c / (1 + c)` per channel of a colour clamped at zero (`compress_channel`).
fn compress(c: vec3<f32>) -> vec3<f32> {
    let v = max(c, vec3<f32>(0.0));
    return v / (vec3<f32>(1.0) + v);
}

// x^n for x in [0, 1] by squaring (Rust's `powi`), n below 2^31.
fn power(x: f32, n: u32) -> f32 {
    var result = 1.0;
    var base = x;
    var e = n;
    for (var bit = 0u; bit < 32u && e != 0u; bit++) {
        if (e & 1u) != 0u {
            result *= base;
        }
        base *= base;
        e = e >> 1u;
    }
    return result;
}

@compute @workgroup_size(64)
fn atrous(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let p = denoise_pixel(id, groups);
    if p >= dp.width * dp.height {
        return;
    }
    let x = i32(p % dp.width);
    let y = i32(p / dp.width);
    let np = guide[2u * p].xyz;
    let zp = guide[2u * p].w;
    let ap = guide[2u * p + 1u].xyz;
    let cp = compress(src[p].xyz);
    let background = !denoise_finite(zp);
    var sum = vec3<f32>(0.0);
    var total = 0.0;
    for (var j = 0; j < 5; j++) {
        let qy = y + (j - 2) * i32(dp.step);
        if qy < 0 || qy >= i32(dp.height) {
            continue;
        }
        for (var i = 0; i < 5; i++) {
            let qx = x + (i - 2) * i32(dp.step);
            if qx < 0 || qx >= i32(dp.width) {
                continue;
            }
            let q = u32(qy) * dp.width + u32(qx);
            let zq = guide[2u * q].w;
            var w = 0.0;
            // Background and surface never mix; two background pixels always do.
            if background || !denoise_finite(zq) {
                w = select(0.0, 1.0, background && !denoise_finite(zq));
            } else {
                let cos = max(dot(np, guide[2u * q].xyz), 0.0);
                let w_normal = power(cos, dp.normal_power);
                if w_normal > 0.0 {
                    let depth = abs(zp - zq) / (dp.sigma_depth * max(zp, 1e-6));
                    let albedo = length(ap - guide[2u * q + 1u].xyz) / dp.sigma_albedo;
                    let dc = cp - compress(src[q].xyz);
                    let color = dot(dc, dc) * dp.inv_color;
                    w = w_normal * exp(-(depth + albedo + color));
                }
            }
            w *= B3[i] * B3[j];
            sum += w * src[q].xyz;
            total += w;
        }
    }
    // The centre's own weight is positive, so `total` is too.
    dst[p] = vec4<f32>(sum / total, 1.0);
}

@compute @workgroup_size(64)
fn blend(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let p = denoise_pixel(id, groups);
    if p >= dp.width * dp.height {
        return;
    }
    let e = noisy[p].xyz;
    dst[p] = vec4<f32>(e + dp.strength * (src[p].xyz - e), 1.0);
}
