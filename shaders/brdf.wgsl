// The analytic BRDF dictionary of spec/brdf.md in f32, mirroring core/src/brdf/ (the
// f64 reference) formula by formula: the same half-vector forms, the same log-space
// powers, so the f32 error stays within the tolerances stated in docs/gpu.md.
// A BRDF is a record of 8 words in the `data` buffer: model, then up to 7 parameters.

const PI: f32 = 3.14159265358979;
const INV_PI: f32 = 0.318309886183791;
const F32_MAX: f32 = 3.40282347e38;

const LAMBERTIAN: u32 = 0u;
const OREN_NAYAR: u32 = 1u;
const BLINN_PHONG: u32 = 2u;
const WARD: u32 = 3u;
const COOK_TORRANCE: u32 = 4u;
const LAFORTUNE: u32 = 5u;
const ASHIKHMIN_SHIRLEY: u32 = 6u;

struct Brdf {
    model: u32,
    // Per model: oren_nayar (A, B), blinn_phong (n), ward (ax, ay), cook_torrance (m, f0),
    // lafortune (cx, cy, cz, n), ashikhmin_shirley (nu, nv, rs).
    p: vec4<f32>,
}

fn load_brdf(at: u32) -> Brdf {
    return Brdf(data[at], vec4<f32>(
        bitcast<f32>(data[at + 1u]), bitcast<f32>(data[at + 2u]),
        bitcast<f32>(data[at + 3u]), bitcast<f32>(data[at + 4u])));
}

// ln(1 + x) without the cancellation of log(1 + x) for small x (Goldberg's trick).
fn log1p_f32(x: f32) -> f32 {
    let u = 1.0 + x;
    if u == 1.0 {
        return x;
    }
    return log(u) * x / (u - 1.0);
}

// ln(cos_h) of a unit half vector, accurate near the normal where cos_h rounds to 1.
fn ln_cos(h: vec3<f32>) -> f32 {
    let t = h.x * h.x + h.y * h.y;
    if t < 0.5 {
        return 0.5 * log1p_f32(-t);
    }
    return log(h.z);
}

struct HalfVector {
    h: vec3<f32>,
    cos_d: f32,
    one_minus_cos_d: f32,
}

fn half_vector(wi: vec3<f32>, wo: vec3<f32>) -> HalfVector {
    let s = wi + wo;
    let len = length(s);
    let d = wi - wo;
    return HalfVector(s / len, 0.5 * len, dot(d, d) / (2.0 * (2.0 + len)));
}

fn schlick(f0: f32, one_minus_cos: f32) -> f32 {
    let m2 = one_minus_cos * one_minus_cos;
    return f0 + (1.0 - f0) * m2 * m2 * one_minus_cos;
}

fn brdf_eval(b: Brdf, wi: vec3<f32>, wo: vec3<f32>) -> f32 {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return 0.0;
    }
    switch b.model {
        case 0u: {
            return INV_PI;
        }
        case 1u: {
            let azimuthal = max(wi.x * wo.x + wi.y * wo.y, 0.0);
            return INV_PI * (b.p.x + b.p.y * azimuthal / max(wi.z, wo.z));
        }
        case 2u: {
            let h = half_vector(wi, wo).h;
            var p = 1.0;
            if b.p.x != 0.0 {
                p = exp(b.p.x * ln_cos(h));
            }
            return (b.p.x + 8.0) / (8.0 * PI) * p;
        }
        case 3u: {
            let s = wi + wo;
            let r = 1.0 / s.z;
            let x = s.x * r / b.p.x;
            let y = s.y * r / b.p.y;
            return exp(-(x * x + y * y)) / (4.0 * PI * b.p.x * b.p.y * sqrt(wi.z) * sqrt(wo.z));
        }
        case 4u: {
            let s = wi + wo;
            let m2 = b.p.x * b.p.x;
            let e = exp(-(s.x * s.x + s.y * s.y) / (s.z * s.z * m2));
            if e == 0.0 {
                return 0.0;
            }
            let cos_h = s.z / length(s);
            let c2 = cos_h * cos_h;
            let d = e / (PI * m2 * c2 * c2);
            let hv = half_vector(wi, wo);
            let g = min(1.0, min(2.0 * hv.h.z * wo.z / hv.cos_d, 2.0 * hv.h.z * wi.z / hv.cos_d));
            return d * schlick(b.p.y, hv.one_minus_cos_d) * g / (4.0 * wi.z * wo.z);
        }
        case 5u: {
            let s = 0.5 * (dot(wi, b.p.xyz * wo) + dot(wo, b.p.xyz * wi));
            if s <= 0.0 {
                return 0.0;
            }
            // exp2 of a finite exponent; clamped where the f64 reference clamps to MAX.
            let e = b.p.w * log2(s);
            if e >= 128.0 {
                return F32_MAX;
            }
            return exp2(e);
        }
        case 6u: {
            let hv = half_vector(wi, wo);
            let h = hv.h;
            let t = h.x * h.x + h.y * h.y;
            var p = 1.0;
            if t != 0.0 {
                let e = (b.p.x * h.x * h.x + b.p.y * h.y * h.y) / t;
                p = exp(e * ln_cos(h));
            }
            let norm = sqrt((b.p.x + 1.0) * (b.p.y + 1.0));
            return norm / (8.0 * PI) * p / (hv.cos_d * max(wi.z, wo.z))
                * schlick(b.p.z, hv.one_minus_cos_d);
        }
        default: {
            return 0.0;
        }
    }
}

// An SPMM basis function (spec/brdf.md): the BRDF tilted onto its own normal, with
// the foreshortening cosine. Record: the BRDF's 8 words, then the frame x, y, z (9).
const BASIS_WORDS: u32 = 20u;

fn basis_eval(at: u32, wi: vec3<f32>, wo: vec3<f32>) -> f32 {
    let fx = vec3<f32>(bitcast<f32>(data[at + 8u]), bitcast<f32>(data[at + 9u]), bitcast<f32>(data[at + 10u]));
    let fy = vec3<f32>(bitcast<f32>(data[at + 11u]), bitcast<f32>(data[at + 12u]), bitcast<f32>(data[at + 13u]));
    let fz = vec3<f32>(bitcast<f32>(data[at + 14u]), bitcast<f32>(data[at + 15u]), bitcast<f32>(data[at + 16u]));
    let c = dot(fz, wi);
    if c <= 0.0 {
        return 0.0;
    }
    let li = vec3<f32>(dot(wi, fx), dot(wi, fy), c);
    let lo = vec3<f32>(dot(wo, fx), dot(wo, fy), dot(wo, fz));
    return brdf_eval(load_brdf(at), li, lo) * c;
}
