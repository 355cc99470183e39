// The adaptive mode's samples (concatenated after integrator.wgsl): each pixel takes
// the samples its frame's plan gave it (adaptive.wgsl `counts`: AUX_PLANNED of its
// `aux` words, AUX_FIRST the index of the first along its own sequence), each the spmm
// mode's estimator (`spmm_sample`, the same expectation as the CPU adaptive mode's
// samples), and writes their sum, their count and the moments of their luminance
// (emissions applied) for the film and the plan of the next frame. A sample with a
// non-finite layer is dropped whole (counted in COUNT_DROPPED).

const AUX_FIRST: u32 = 7u;
const AUX_MOMENTS: u32 = 8u;
const AUX_PLANNED: u32 = 12u;
// Samples of a pixel per dispatch: a frame's samples go in chunks (`params.sample_lo`
// is the chunk's first), so no invocation runs long (llvmpipe ends a shader's loops
// after 65,535 iterations, counted over all of them) and pixels of many samples do not
// hold their workgroup up; `core/gpu/src/mode/adaptive.rs` mirrors it.
const ADAPTIVE_CHUNK: u32 = 8u;
const COUNT_DROPPED: u32 = 8u;

fn finite3(v: vec3<f32>) -> bool {
    let m = vec3<u32>(0x7f800000u);
    return all((bitcast<vec3<u32>>(v) & m) != m);
}

@compute @workgroup_size(64)
fn render_adaptive(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let pixel = pixel_of_invocation(id, groups);
    if pixel >= params.width * params.height {
        return;
    }
    let a = pixel * params.aux_words;
    let planned = aux[a + AUX_PLANNED];
    let start = params.sample_lo;
    let end = min(planned, start + ADAPTIVE_CHUNK);
    let first = aux[a + AUX_FIRST];
    let layers = min(params.layers, MAX_LAYERS);
    var total: array<vec3<f32>, MAX_LAYERS>;
    counts = Counts(0u, 0u, 0u, 0u, 0u);
    mask = vec2<u32>(0u);
    uv_box = vec4<f32>(3.4e38, 3.4e38, -3.4e38, -3.4e38);
    var kept = 0u;
    var dropped = 0u;
    var mean = 0.0;
    var m2 = 0.0;
    for (var k = start; k < end; k++) {
        for (var l = 0u; l < MAX_LAYERS; l++) {
            acc[l] = vec3<f32>(0.0);
        }
        var rng = rng_for_sample(params.sampler, params.seed, first + k, 0u, pixel);
        spmm_sample(pixel, &rng);
        var ok = true;
        var value = 0.0;
        for (var l = 0u; l < layers; l++) {
            ok = ok && finite3(acc[l]);
            value += dot(acc[l] * params.weights[l].xyz, LUMINANCE);
        }
        if !ok {
            dropped += 1u;
            continue;
        }
        for (var l = 0u; l < layers; l++) {
            total[l] += acc[l];
        }
        // Welford's running mean and M2 of the samples' luminance.
        kept += 1u;
        let delta = value - mean;
        mean += delta / f32(kept);
        m2 += delta * (value - mean);
    }
    for (var l = 0u; l < MAX_LAYERS; l++) {
        acc[l] = total[l];
    }
    finish_sample(pixel, kept);
    aux[a + AUX_MOMENTS] = kept;
    aux[a + AUX_MOMENTS + 1u] = bitcast<u32>(mean);
    aux[a + AUX_MOMENTS + 2u] = bitcast<u32>(m2);
    // finish_sample counted one primary ray per kept sample; the dropped ones too.
    atomicAdd(&counters[COUNT_PRIMARY], dropped);
    atomicAdd(&counters[COUNT_DROPPED], dropped);
}
