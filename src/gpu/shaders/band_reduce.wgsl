// The posterior refinement's reduce, per-word part (gpu/band.rs): band pixels whose
// coverage differs from the observation, per (view `gid.z`, pose `gid.y`). Built as
// bits_params.wgsl + this + reduce_main.wgsl.

@group(0) @binding(1) var<storage, read> bits: array<u32>;
// Per view: its band's words, then its observation's.
@group(0) @binding(2) var<storage, read> reference: array<u32>;
@group(0) @binding(3) var<storage, read_write> out: array<atomic<u32>>;

fn value(gid: vec3<u32>) -> u32 {
    let k = gid.y;
    let view = gid.z;
    let rendered = bits[(view * params.candidates + k) * params.words + gid.x];
    let band = reference[2u * view * params.words + gid.x];
    let observed = reference[(2u * view + 1u) * params.words + gid.x];
    return countOneBits((rendered ^ observed) & band);
}

fn slot(gid: vec3<u32>) -> u32 {
    return gid.z * params.candidates + gid.y;
}
