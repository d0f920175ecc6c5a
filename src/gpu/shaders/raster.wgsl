// Silhouette masks on the graphics pipeline (gpu/raster.rs): one draw per view into one layer
// of an R8 texture array. Vertices arrive already projected on the CPU in f64; the vertex
// stage grows each triangle slightly so the rasteriser's coverage is a superset, and the
// fragment stage trims it back to the CPU renderer's exact rule (pixel centre inside or on
// all three edges), so both backends give the same masks.

struct Frame { size: vec2<f32>, pad: vec2<f32> };
@group(0) @binding(0) var<uniform> frame: Frame;
// Projected vertices: image x, y, and 1 when in front of the near plane (0 otherwise).
@group(0) @binding(1) var<storage, read> pixels: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> indices: array<u32>;

struct Out {
    @builtin(position) position: vec4<f32>,
    @location(0) @interpolate(flat) a: vec2<f32>,
    @location(1) @interpolate(flat) b: vec2<f32>,
    @location(2) @interpolate(flat) c: vec2<f32>,
};

// Half-pixel shift: image coordinates put pixel centres on integers, framebuffers at +0.5.
fn to_clip(p: vec2<f32>) -> vec4<f32> {
    return vec4<f32>((p.x + 0.5) / frame.size.x * 2.0 - 1.0,
                     1.0 - (p.y + 0.5) / frame.size.y * 2.0, 0.0, 1.0);
}

@vertex
fn vs(@builtin(vertex_index) i: u32) -> Out {
    let t = i / 3u;
    let pa = pixels[indices[3u * t]];
    let pb = pixels[indices[3u * t + 1u]];
    let pc = pixels[indices[3u * t + 2u]];
    var out: Out;
    out.a = pa.xy;
    out.b = pb.xy;
    out.c = pc.xy;
    if (pa.z * pb.z * pc.z == 0.0) {
        // A vertex behind the near plane: the CPU drops the triangle, so draw nothing.
        out.position = vec4<f32>(2.0, 2.0, 0.0, 1.0);
        return out;
    }
    // Grow the triangle about its incentre so every edge moves out by EPS px (up to 2 px of
    // growth for slivers): the rasteriser's snapped coverage is then a superset of the exact
    // one, which the fragment stage trims back to the CPU's rule.
    let la = length(pb.xy - pc.xy);
    let lb = length(pc.xy - pa.xy);
    let lc = length(pa.xy - pb.xy);
    let perimeter = la + lb + lc;
    var p = pa.xy;
    if (i % 3u == 1u) { p = pb.xy; } else if (i % 3u == 2u) { p = pc.xy; }
    if (perimeter > 0.0) {
        let incentre = (pa.xy * la + pb.xy * lb + pc.xy * lc) / perimeter;
        let cross = abs((pb.x - pa.x) * (pc.y - pa.y) - (pb.y - pa.y) * (pc.x - pa.x));
        let inradius = cross / perimeter;
        let reach = max(max(length(pa.xy - incentre), length(pb.xy - incentre)),
                        length(pc.xy - incentre));
        let eps = 1.0 / 32.0;
        var grow = 2.0 / max(reach, 1e-6);
        if (inradius > 0.0) { grow = min(eps / inradius, grow); }
        p = incentre + (p - incentre) * (1.0 + grow);
    }
    out.position = to_clip(p);
    return out;
}

@fragment
fn fs(in: Out) -> @location(0) vec4<f32> {
    // The CPU's test: the pixel centre lies inside or on all three edges.
    let x = in.position.xy - vec2<f32>(0.5, 0.5);
    let area = (in.b.x - in.a.x) * (in.c.y - in.a.y) - (in.b.y - in.a.y) * (in.c.x - in.a.x);
    if (area == 0.0) {
        discard;
    }
    let s = sign(area);
    let e0 = s * ((in.b.x - in.a.x) * (x.y - in.a.y) - (in.b.y - in.a.y) * (x.x - in.a.x));
    let e1 = s * ((in.c.x - in.b.x) * (x.y - in.b.y) - (in.c.y - in.b.y) * (x.x - in.b.x));
    let e2 = s * ((in.a.x - in.c.x) * (x.y - in.c.y) - (in.a.y - in.c.y) * (x.x - in.c.x));
    if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) {
        discard;
    }
    return vec4<f32>(1.0, 0.0, 0.0, 1.0);
}
