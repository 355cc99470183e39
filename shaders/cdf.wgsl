// The bounded binary search over a tabulated CDF that the environment map's sampler
// (environment.wgsl, `env`) and the MERL sampler (merl.wgsl, `data`) share: the first
// interval whose upper end exceeds `u`, and `u` remapped into it. WGSL cannot pass a
// storage buffer to a function, so the caller names the buffer. The search ends
// within `steps` iterations (llvmpipe ends loops silently after 65,535).

const CDF_IN_ENV: u32 = 0u;
const CDF_IN_DATA: u32 = 1u;

struct CdfPick {
    index: u32,
    t: f32,
}

fn cdf_entry(buffer: u32, i: u32) -> f32 {
    if buffer == CDF_IN_ENV {
        return bitcast<f32>(env[i]);
    }
    return bitcast<f32>(data[i]);
}

// The CDF at `at` in `buffer` has n + 1 entries (0 first); `t` is clamped to
// [0, t_max] as the CPU sampler clamps it.
fn cdf_pick(buffer: u32, at: u32, n: u32, u: f32, steps: u32, t_max: f32) -> CdfPick {
    var lo = 0u;
    var hi = n;
    for (var k = 0u; k < steps && lo < hi; k++) {
        let mid = lo + (hi - lo) / 2u;
        if cdf_entry(buffer, at + 1u + mid) <= u {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    let i = min(lo, n - 1u);
    let c0 = cdf_entry(buffer, at + i);
    let width = cdf_entry(buffer, at + i + 1u) - c0;
    var t = 0.5;
    if width > 0.0 {
        t = clamp((u - c0) / width, 0.0, t_max);
    }
    return CdfPick(i, t);
}
