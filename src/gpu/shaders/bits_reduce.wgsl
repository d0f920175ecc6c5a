// Exploration's reduce, per-word part (gpu/disagreement.rs): per pixel, how many candidates
// cover it (c), summed as c * (K - c), per pool entry (`gid.y`). Built as
// bits_params.wgsl + this + reduce_main.wgsl.

@group(0) @binding(1) var<storage, read> bits: array<u32>;
@group(0) @binding(2) var<storage, read_write> out: array<atomic<u32>>;

fn value(gid: vec3<u32>) -> u32 {
    let entry = gid.y;
    var counts: array<u32, 32>;
    for (var k = 0u; k < params.candidates; k = k + 1u) {
        let w = bits[(entry * params.candidates + k) * params.words + gid.x];
        if (w != 0u) {
            for (var i = 0u; i < 32u; i = i + 1u) {
                counts[i] = counts[i] + ((w >> i) & 1u);
            }
        }
    }
    var total = 0u;
    for (var i = 0u; i < 32u; i = i + 1u) {
        total = total + counts[i] * (params.candidates - counts[i]);
    }
    return total;
}

fn slot(gid: vec3<u32>) -> u32 {
    return gid.y;
}
