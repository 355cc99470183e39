// Test kernels (core's gpu tests only): BRDF, basis-function and SPMM-texel
// evaluations, and closest hits of given rays, read back and compared with the CPU.

@group(0) @binding(0) var<storage, read> data: array<u32>;
// eval_cases: per case 8 words: kind (0 BRDF, 1 basis, 2 SPMM texel, 3 BRDF sampling
// pdf, 4 BRDF sample with the uniform numbers in wi.xy, 5 MERL value, 6 MERL sampling
// pdf, 7 MERL sample, 8 SPMM texel sampling pdf, 9 SPMM texel sample with the uniform
// numbers in wi.xy, 10 BTF texel, 11 SPMM texel with MOVING_NPCA components, 12 BTF
// sampling pdf, 13 BTF sample with the uniform numbers in wi.xy), record offset,
// wi, wo (f32 bits); SPMM cases: texel in word 8, residual flag in word 9 (10 words).
// trace_rays: per ray 8 words: origin, direction (f32 bits), tmin, tmax.
@group(0) @binding(1) var<storage, read> cases: array<u32>;
@group(0) @binding(2) var<storage, read_write> results: array<f32>;
@group(0) @binding(3) var<storage, read> nodes: array<u32>;
@group(0) @binding(4) var<storage, read> tris: array<u32>;
@group(0) @binding(5) var<storage, read_write> counters: array<atomic<u32>>;
// Unused by the kernels; cdf.wgsl names it.
@group(0) @binding(6) var<storage, read> env: array<u32>;

const CASE_WORDS: u32 = 10u;

fn case_vec(at: u32) -> vec3<f32> {
    return vec3<f32>(bitcast<f32>(cases[at]), bitcast<f32>(cases[at + 1u]), bitcast<f32>(cases[at + 2u]));
}

@compute @workgroup_size(64)
fn eval_cases(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = arrayLength(&cases) / CASE_WORDS;
    if id.x >= n {
        return;
    }
    let at = id.x * CASE_WORDS;
    let kind = cases[at];
    let record = cases[at + 1u];
    let wi = case_vec(at + 2u);
    let wo = case_vec(at + 5u);
    var v = vec3<f32>(0.0);
    if kind == 0u {
        v = vec3<f32>(brdf_eval(load_brdf(record), wi, wo));
    } else if kind == 1u {
        v = vec3<f32>(basis_eval(record, wi, wo));
    } else if kind == 3u {
        v = vec3<f32>(brdf_pdf(load_brdf(record), wo, wi));
    } else if kind == 4u {
        // wi.xy: the two uniform numbers; the drawn direction (zero: none).
        v = brdf_sample(load_brdf(record), wo, wi.xy).xyz;
    } else if kind == 5u {
        v = merl_eval(record, wi, wo);
    } else if kind == 6u {
        v = vec3<f32>(merl_pdf(record, wo, wi));
    } else if kind == 7u {
        v = merl_sample(record, wo, wi.xy).xyz;
    } else if kind == 8u {
        v = vec3<f32>(spmm_texel_pdf(record, cases[at + 8u], wi, wo));
    } else if kind == 9u {
        v = spmm_sample_texel(record, cases[at + 8u], wo, wi.xy).xyz;
    } else if kind == 10u {
        v = btf_eval_texel(record, cases[at + 8u], wi, wo);
    } else if kind == 12u {
        v = vec3<f32>(btf_pdf(record, wi, wo));
    } else if kind == 13u {
        v = btf_sample(record, wo, wi.xy).xyz;
    } else if kind == 11u {
        v = spmm_eval_texel(record, cases[at + 8u], wi, wo, true, MOVING_NPCA);
    } else {
        v = spmm_eval_texel(record, cases[at + 8u], wi, wo, cases[at + 9u] != 0u, ALL_COMPONENTS);
    }
    results[3u * id.x] = v.x;
    results[3u * id.x + 1u] = v.y;
    results[3u * id.x + 2u] = v.z;
}

@compute @workgroup_size(64)
fn trace_rays(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = arrayLength(&cases) / 8u;
    if id.x >= n {
        return;
    }
    let at = id.x * 8u;
    let ray = make_ray(case_vec(at), case_vec(at + 3u), bitcast<f32>(cases[at + 6u]), bitcast<f32>(cases[at + 7u]));
    let hit = traverse(ray, false);
    results[2u * id.x] = hit.t;
    // As a float (exact below 2^24): a bit pattern of NaN may not survive a store.
    results[2u * id.x + 1u] = select(f32(hit.prim), -1.0, hit.prim == NO_HIT);
}

// sobol_points: per case 3 words: index, seed 0, seed 1; per case 4 results: the
// point's x and y as 32-bit fractions in 16-bit halves (exact in f32).
@compute @workgroup_size(64)
fn sobol_points(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = arrayLength(&cases) / 3u;
    if id.x >= n {
        return;
    }
    let at = id.x * 3u;
    let p = sobol_point_bits(cases[at], cases[at + 1u], cases[at + 2u]);
    results[4u * id.x] = f32(p.x >> 16u);
    results[4u * id.x + 1u] = f32(p.x & 0xffffu);
    results[4u * id.x + 2u] = f32(p.y >> 16u);
    results[4u * id.x + 3u] = f32(p.y & 0xffffu);
}
