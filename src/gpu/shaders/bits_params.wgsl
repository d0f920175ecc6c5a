// The uniform every shader of the bit rasteriser binds first (`BitsParams` in gpu/bits.rs,
// same layout). Not a module on its own: gpu/pipelines.rs prepends it to bits_raster.wgsl
// and to each reduce.

struct Params {
    intrinsics: vec4<f32>,   // fx fy cx cy
    tile: vec2<u32>,         // tile width, height
    words: u32,              // 32-pixel words per tile
    candidates: u32,
    triangles: u32,          // most triangles of any entry in the batch
    table: u32,              // u32s of the entry table heading `indices`
    near: f32,
    pad: u32,
};
@group(0) @binding(0) var<uniform> params: Params;
