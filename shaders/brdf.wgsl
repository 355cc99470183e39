// The analytic BRDF dictionary of docs/brdf.md in f32, mirroring core/materials/src/brdf/ (the
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

// An SPMM basis function (docs/brdf.md): the BRDF tilted onto its own normal, with
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

// Importance sampling of the analytic BRDFs, as core/materials/src/brdf/ draws them (warp.rs and
// each model's `sample_half`/`pdf_half`): the cosine hemisphere for Lambertian and
// Oren-Nayar, the half vector for Blinn-Phong, Ward, Cook-Torrance and
// Ashikhmin-Shirley (p(wi) = p(h) / (4 wo.h)), the Phong lobe about the reflected
// axis for Lafortune. Local frame (+z the normal). The environment's MIS uses them.

// A direction from its polar cosine and sine: sharp lobes keep theta near 0, where
// cos rounds to 1 in f32 and sqrt(1 - cos^2) would lose every digit of the sine.
fn spherical_dir(cos_t: f32, sin_t: f32, phi: f32) -> vec3<f32> {
    return vec3<f32>(sin_t * cos(phi), sin_t * sin(phi), cos_t);
}

// e^x - 1 without the cancellation of exp(x) - 1 for small x (Kahan's trick).
fn expm1_f32(x: f32) -> f32 {
    let u = exp(x);
    if u == 1.0 {
        return x;
    }
    let um1 = u - 1.0;
    if um1 == -1.0 {
        return -1.0;
    }
    return um1 * x / log(u);
}

// cos and sin of theta where cos theta = (1 - u)^(1 / (n + 1)) (the Phong lobe and
// Ashikhmin-Shirley's half vector), the sine from 1 - cos^2 = -expm1(2 ln(1 - u) / (n + 1)).
fn power_cos_sin(u: f32, n: f32) -> vec2<f32> {
    let x = 2.0 * log1p_f32(-u) / (n + 1.0);
    return vec2<f32>(exp(0.5 * x), sqrt(max(-expm1_f32(x), 0.0)));
}

// cos and sin of theta from tan^2 theta (Ward, Beckmann).
fn tan2_cos_sin(tan2: f32) -> vec2<f32> {
    let c = 1.0 / sqrt(1.0 + tan2);
    return vec2<f32>(c, sqrt(tan2) * c);
}

// Duff et al. 2017: a tangent and bitangent completing the unit `n`.
fn basis_of(n: vec3<f32>) -> mat3x3<f32> {
    let sign = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    return mat3x3<f32>(
        vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        vec3<f32>(b, sign + n.y * n.y * a, -n.y),
        n);
}

fn phong_lobe(axis: vec3<f32>, n: f32, u: vec2<f32>) -> vec3<f32> {
    let cs = power_cos_sin(u.x, n);
    return basis_of(axis) * spherical_dir(cs.x, cs.y, 2.0 * PI * u.y);
}

fn phong_lobe_pdf(axis: vec3<f32>, n: f32, w: vec3<f32>) -> f32 {
    let c = dot(axis, w);
    if c <= 0.0 {
        return 0.0;
    }
    return (n + 1.0) / (2.0 * PI) * exp2(n * log2(c));
}

fn cosine_dir(u: vec2<f32>) -> vec3<f32> {
    let r = sqrt(u.x);
    let phi = 2.0 * PI * u.y;
    return vec3<f32>(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u.x, 0.0)));
}

// Lafortune's lobe axis for `wo`, or zero where it vanishes (then the cosine).
fn lafortune_axis(b: Brdf, wo: vec3<f32>) -> vec3<f32> {
    let a = b.p.xyz * wo;
    let l2 = dot(a, a);
    if l2 > 1e-36 && l2 < 3.0e38 {
        return a * inverseSqrt(l2);
    }
    return vec3<f32>(0.0);
}

// The half-vector density p(h) of the four microfacet-like models.
fn pdf_half(b: Brdf, h: vec3<f32>) -> f32 {
    switch b.model {
        case 2u: {
            var p = 1.0;
            if b.p.x != 0.0 {
                p = exp(b.p.x * ln_cos(h));
            }
            return (b.p.x + 1.0) / (2.0 * PI) * p;
        }
        case 3u: {
            let r = 1.0 / h.z;
            let x = h.x * r / b.p.x;
            let y = h.y * r / b.p.y;
            let e = exp(-(x * x + y * y));
            if e == 0.0 {
                return 0.0;
            }
            return e / (PI * b.p.x * b.p.y * h.z * h.z * h.z);
        }
        case 4u: {
            let m2 = b.p.x * b.p.x;
            let e = exp(-(h.x * h.x + h.y * h.y) / (h.z * h.z * m2));
            if e == 0.0 {
                return 0.0;
            }
            let c2 = h.z * h.z;
            return e / (PI * m2 * c2 * c2) * h.z;
        }
        case 6u: {
            let t = h.x * h.x + h.y * h.y;
            var p = 1.0;
            if t != 0.0 {
                p = exp((b.p.x * h.x * h.x + b.p.y * h.y * h.y) / t * ln_cos(h));
            }
            return sqrt((b.p.x + 1.0) * (b.p.y + 1.0)) / (2.0 * PI) * p;
        }
        default: {
            return 0.0;
        }
    }
}

fn sample_half(b: Brdf, u: vec2<f32>) -> vec3<f32> {
    switch b.model {
        case 2u: {
            return phong_lobe(vec3<f32>(0.0, 0.0, 1.0), b.p.x, u);
        }
        case 3u: {
            let psi = 2.0 * PI * u.y;
            let phi = atan2(b.p.y * sin(psi), b.p.x * cos(psi));
            let c = cos(phi);
            let s = sin(phi);
            let a = c * c / (b.p.x * b.p.x) + s * s / (b.p.y * b.p.y);
            let cs = tan2_cos_sin(-log1p_f32(-u.x) / a);
            return spherical_dir(cs.x, cs.y, phi);
        }
        case 4u: {
            let cs = tan2_cos_sin(-b.p.x * b.p.x * log1p_f32(-u.x));
            return spherical_dir(cs.x, cs.y, 2.0 * PI * u.y);
        }
        default: {
            let psi = 2.0 * PI * u.y;
            let phi = atan2(sqrt(b.p.x + 1.0) * sin(psi), sqrt(b.p.y + 1.0) * cos(psi));
            let c = cos(phi);
            let s = sin(phi);
            let e = b.p.x * c * c + b.p.y * s * s;
            let cs = power_cos_sin(u.x, e);
            return spherical_dir(cs.x, cs.y, phi);
        }
    }
}

// The solid-angle density with which `brdf_sample(b, wo, .)` returns `wi`.
fn brdf_pdf(b: Brdf, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return 0.0;
    }
    if b.model == LAMBERTIAN || b.model == OREN_NAYAR {
        return wi.z * INV_PI;
    }
    if b.model == LAFORTUNE {
        let axis = lafortune_axis(b, wo);
        if all(axis == vec3<f32>(0.0)) {
            return wi.z * INV_PI;
        }
        return phong_lobe_pdf(axis, b.p.w, wi);
    }
    let hv = half_vector(wi, wo);
    if hv.h.z <= 0.0 {
        return 0.0;
    }
    return pdf_half(b, hv.h) / (4.0 * hv.cos_d);
}

// A direction drawn for `wo` with its pdf (xyz, w); w = 0 where none is drawn (below
// the horizon, as the CPU's `None`).
fn brdf_sample(b: Brdf, wo: vec3<f32>, u: vec2<f32>) -> vec4<f32> {
    if wo.z <= 0.0 {
        return vec4<f32>(0.0);
    }
    var wi: vec3<f32>;
    if b.model == LAMBERTIAN || b.model == OREN_NAYAR {
        wi = cosine_dir(u);
    } else if b.model == LAFORTUNE {
        let axis = lafortune_axis(b, wo);
        if all(axis == vec3<f32>(0.0)) {
            wi = cosine_dir(u);
        } else {
            wi = phong_lobe(axis, b.p.w, u);
        }
    } else {
        let h = sample_half(b, u);
        let d = dot(wo, h);
        if d <= 0.0 {
            return vec4<f32>(0.0);
        }
        wi = 2.0 * d * h - wo;
    }
    let pdf = brdf_pdf(b, wo, wi);
    if wi.z > 0.0 && pdf > 0.0 && pdf < F32_MAX {
        return vec4<f32>(wi, pdf);
    }
    return vec4<f32>(0.0);
}
