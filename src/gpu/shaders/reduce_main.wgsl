// The entry point both reduces share (appended to each): one thread per 32-pixel word
// (`gid.x`), its `value` summed over the workgroup, one atomic add per workgroup into
// `out[slot]` (a workgroup spans words only, so its slot is one).

var<workgroup> partial: atomic<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    if (lid == 0u) {
        atomicStore(&partial, 0u);
    }
    workgroupBarrier();
    if (gid.x < params.words) {
        let v = value(gid);
        if (v > 0u) {
            atomicAdd(&partial, v);
        }
    }
    workgroupBarrier();
    if (lid == 0u) {
        let total = atomicLoad(&partial);
        if (total > 0u) {
            atomicAdd(&out[slot(gid)], total);
        }
    }
}
