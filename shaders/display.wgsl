// A resolved image (film.wgsl's `resolve`) to the viewport's texture, as
// core/materials/src/image/tonemap.rs encodes it for a PNG or the host's texture: exposure
// (a scale of 2^stops), clamp to [0, 1] (NaN shows black), the sRGB curve of
// IEC 61966-2-1, then 8-bit quantisation. The texture is `rgba8unorm` holding the
// encoded values, which the window (egui's renderer) samples as they are. One
// invocation per pixel.

struct DisplayParams {
    width: u32,
    height: u32,
    scale: f32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> params: DisplayParams;
@group(0) @binding(1) var<storage, read> image: array<vec4<f32>>;
@group(0) @binding(2) var shown: texture_storage_2d<rgba8unorm, write>;

fn encode(linear: f32) -> f32 {
    var c = linear * params.scale;
    // NaN by its bits (fast-math may fold `c != c` away): shown black.
    let bits = bitcast<u32>(c);
    if (bits & 0x7f800000u) == 0x7f800000u && (bits & 0x007fffffu) != 0u {
        c = 0.0;
    }
    c = clamp(c, 0.0, 1.0);
    var e: f32;
    if c <= 0.0031308 {
        e = 12.92 * c;
    } else {
        e = 1.055 * pow(c, 1.0 / 2.4) - 0.055;
    }
    // The stored value is the quantised code over 255, so the unorm conversion
    // reproduces the code whatever its rounding rule.
    return round(clamp(e, 0.0, 1.0) * 255.0) / 255.0;
}

@compute @workgroup_size(8, 8)
fn show(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= params.width || id.y >= params.height {
        return;
    }
    let v = image[id.y * params.width + id.x];
    textureStore(shown, vec2<u32>(id.xy), vec4<f32>(encode(v.x), encode(v.y), encode(v.z), 1.0));
}
