// The viewport denoiser's guides on the device (core/modes/src/trace/guides.rs is the
// reference): one ray through each pixel's centre and, at its first hit, the shading
// normal, the distance and the colour the surface reflects (`ShadedMaterial::albedo`: a BRDF's
// albedo, a MERL table's albedo at normal view times its tint, a mirror's
// reflectance; for packs and BTFs pi times the response seen and lit along the
// normal). Appended to the integrator's module: it reads that module's bindings and
// writes into the one it calls `frame`, which the guides' kernel binds to a buffer of
// its own: GUIDE_FLOATS per pixel (normal, distance; albedo, 0). A ray that leaves the
// scene gets a zero normal and albedo and an infinite distance.

const GUIDE_FLOATS: u32 = 8u;
// Words of a MERL record before its albedo at normal view (core/gpu/src/data.rs).
const MERL_ALBEDO_WORD: u32 = 4u;

fn guide_albedo(s: Shading) -> vec3<f32> {
    let at = params.material_table + s.material * MATERIAL_WORDS;
    let kind = data[at];
    if kind == MATERIAL_BRDF || kind == MATERIAL_MIRROR {
        return rgb_at(at + 4u);
    }
    if kind == MATERIAL_MERL {
        return rgb_at(at + 4u) * rgb_at(data[at + 1u] + MERL_ALBEDO_WORD);
    }
    return response(s, s.n, s.n) * PI;
}

@compute @workgroup_size(64)
fn guides(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = pixel_of_invocation(id, groups);
    if pixel >= params.width * params.height {
        return;
    }
    let origin = params.cam_origin.xyz;
    let dir = camera_dir(pixel, vec2<f32>(0.5));
    let hit = traverse(make_ray(origin, dir, 0.0, FAR), false);
    let at = pixel * GUIDE_FLOATS;
    var normal = vec3<f32>(0.0);
    var depth = bitcast<f32>(F32_INFINITY_BITS);
    var albedo = vec3<f32>(0.0);
    if hit.prim != NO_HIT {
        let s = shading_at(hit.prim, origin, dir, hit.t);
        normal = s.n;
        depth = hit.t;
        albedo = guide_albedo(s);
    }
    frame[at] = normal.x;
    frame[at + 1u] = normal.y;
    frame[at + 2u] = normal.z;
    frame[at + 3u] = depth;
    frame[at + 4u] = albedo.x;
    frame[at + 5u] = albedo.y;
    frame[at + 6u] = albedo.z;
    frame[at + 7u] = 0.0;
}
