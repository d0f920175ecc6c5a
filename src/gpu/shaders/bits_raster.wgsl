// The compute bit rasteriser both batched scores start with (gpu/bits.rs): every silhouette
// of a batch as one bit per pixel, projected and tested in f32 with the CPU renderer's rule.
// Compute rather than the graphics pipeline because scoring triangles are mostly smaller
// than a scoring pixel and data-centre GPUs have few graphics units. Prepended with
// bits_params.wgsl.

@group(0) @binding(1) var<storage, read> camera_from_base: array<mat4x4<f32>>;
@group(0) @binding(2) var<storage, read> vertices: array<f32>;
// Per pool entry (first index position, triangle count, first vertex), then the indices of
// every distinct mesh in the batch.
@group(0) @binding(3) var<storage, read> indices: array<u32>;
@group(0) @binding(4) var<storage, read_write> bits: array<atomic<u32>>;

// Pixel position and 1, or 0 in z when the vertex is not in front of the near plane.
fn project(m: mat4x4<f32>, v: u32) -> vec3<f32> {
    let p = m * vec4<f32>(vertices[3u * v], vertices[3u * v + 1u], vertices[3u * v + 2u], 1.0);
    if (p.z <= params.near) {
        return vec3<f32>(0.0, 0.0, 0.0);
    }
    return vec3<f32>(params.intrinsics.x * p.x / p.z + params.intrinsics.z,
                     params.intrinsics.y * p.y / p.z + params.intrinsics.w, 1.0);
}

fn edge(p: vec3<f32>, q: vec3<f32>, s: f32) -> vec3<f32> {
    let ex = q.x - p.x;
    let ey = q.y - p.y;
    return vec3<f32>(-s * ey, s * ex, s * (ey * p.x - ex * p.y));
}

// One thread per (triangle, candidate, pool entry): the CPU's rule (pixel centres at integer
// coordinates, all three edge functions >= 0) over the triangle's bounding box, one bit per
// covered pixel.
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x;
    if (t >= params.triangles) {
        return;
    }
    let k = gid.y;
    let entry = gid.z;
    let first = indices[3u * entry];
    if (t >= indices[3u * entry + 1u]) {
        return;
    }
    let base = indices[3u * entry + 2u];
    let m = camera_from_base[k];
    let a = project(m, base + indices[first + 3u * t]);
    let b = project(m, base + indices[first + 3u * t + 1u]);
    let c = project(m, base + indices[first + 3u * t + 2u]);
    if (a.z == 0.0 || b.z == 0.0 || c.z == 0.0) {
        return;
    }
    let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
    if (!(abs(area) >= 1e-12) || abs(area) > 1e30) {
        return;
    }
    let x0 = max(ceil(min(a.x, min(b.x, c.x))), 0.0);
    let x1 = min(floor(max(a.x, max(b.x, c.x))), f32(params.tile.x) - 1.0);
    let y0 = max(ceil(min(a.y, min(b.y, c.y))), 0.0);
    let y1 = min(floor(max(a.y, max(b.y, c.y))), f32(params.tile.y) - 1.0);
    if (x0 > x1 || y0 > y1) {
        return;
    }
    let s = sign(area);
    let e0 = edge(a, b, s);
    let e1 = edge(b, c, s);
    let e2 = edge(c, a, s);
    let tile = (entry * params.candidates + k) * params.words;
    for (var y = u32(y0); y <= u32(y1); y = y + 1u) {
        let yf = f32(y);
        let r0 = e0.y * yf + e0.z;
        let r1 = e1.y * yf + e1.z;
        let r2 = e2.y * yf + e2.z;
        for (var x = u32(x0); x <= u32(x1); x = x + 1u) {
            let xf = f32(x);
            if (e0.x * xf + r0 >= 0.0 && e1.x * xf + r1 >= 0.0 && e2.x * xf + r2 >= 0.0) {
                let i = y * params.tile.x + x;
                atomicOr(&bits[tile + i / 32u], 1u << (i % 32u));
            }
        }
    }
}
