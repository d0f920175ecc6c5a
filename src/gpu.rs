//! The wgpu backend of [`SilhouetteRenderer`]: rasterises silhouettes on a GPU and scores
//! exploration candidates there in batches.
//!
//! Two GPU paths, both ending in the exact integers the CPU backend computes:
//! - **Silhouettes** ([`SilhouetteRenderer::render_many`]): vertices are projected on the CPU in
//!   f64 (the same projection, distortion and near-plane rule as [`CpuRenderer`]), uploaded as
//!   pixel positions, and every view of a solve is drawn into one layer of a texture array in
//!   a single submission; the masks come back and the outline samples are taken from them on
//!   the CPU with [`outline_samples`], so the solver's gradient is the CPU's code on the
//!   GPU's mask.
//! - **Exploration** ([`BatchScoring::disagreement_many`]): a compute rasteriser, one
//!   thread per (triangle, camera candidate, joint sample), applies the CPU's pixel rule in f32
//!   and sets one bit per covered pixel in the candidate's bitmask; a second pass counts per
//!   pixel how many candidates cover it and reduces `count * (K - count)` to one integer per
//!   sample, and only those integers are read back. Compute instead of the graphics pipeline:
//!   exploration's triangles are mostly smaller than a scoring pixel, and on data-centre GPUs
//!   (an H100 has graphics units in only a few of its clusters) every shader core can run it.
//!   Batches are sized so GPU memory stays bounded whatever the sample count.
//!
//! Pixel centres: the CPU samples pixel `(u, v)` at image coordinates `(u, v)`; the GPU samples
//! framebuffer pixel centres at `+0.5`, so positions are shifted by half a pixel on the way
//! in. The rasteriser's fill rule and fixed-point snapping differ from the CPU's inclusive
//! edge test only for pixel centres within about 1/256 px of an edge.
//!
//! [`CpuRenderer`]: crate::render::CpuRenderer

use std::collections::HashMap;
use std::sync::{Arc, Mutex, Weak};

use nalgebra::Isometry3;
use rayon::prelude::*;
use wgpu::util::DeviceExt;

use crate::camera::Camera;
use crate::mask::Mask;
use crate::mesh::TriMesh;
use crate::render::{
    outline_samples, project_vertices, PosedRobot, Silhouette, SilhouetteRenderer,
};
use crate::scoring::BatchScoring;

/// GPU memory one exploration batch may use for its candidate bitmasks and vertices, bytes.
const EXPLORE_BATCH_BYTES: u64 = 256 << 20;
/// Threads per workgroup of the exploration shaders (`@workgroup_size` in their WGSL).
const BITS_WORKGROUP: u32 = 64;

/// Which adapters a caller accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterPolicy {
    /// Hardware adapters only (discrete, integrated or virtual GPUs): what `auto` wants.
    HardwareOnly,
    /// Any adapter, software rasterisers (lavapipe, llvmpipe) included, hardware first.
    Any,
}

/// What a chosen adapter is, for logs and the README's figures.
#[derive(Clone, Debug)]
pub struct AdapterSummary {
    /// Adapter name as the driver reports it.
    pub name: String,
    /// Backend (Vulkan, GL…).
    pub backend: String,
    /// Discrete / integrated / virtual GPU or CPU.
    pub device_type: String,
    /// Driver name and version.
    pub driver: String,
    /// True for a software rasteriser.
    pub software: bool,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({}, {}, driver {})",
            self.name, self.backend, self.device_type, self.driver
        )
    }
}

/// A view's projected vertices (pixels) and camera-frame points, as the outline sampler
/// takes them.
type Projected = (Vec<[f64; 2]>, Vec<nalgebra::Point3<f64>>);

/// Index buffer of one mesh topology, cached while the topology lives.
struct CachedMesh {
    topology: Weak<TriMesh>,
    indices: wgpu::Buffer,
    count: u32,
}

/// Reusable render target and readback buffer of one size.
struct Targets {
    width: u32,
    height: u32,
    layers: u32,
    texture: wgpu::Texture,
    readback: wgpu::Buffer,
}

/// Silhouettes and exploration scores on a wgpu device.
pub struct WgpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: AdapterSummary,
    max_layers: u32,
    raster: wgpu::RenderPipeline,
    raster_layout: wgpu::BindGroupLayout,
    max_storage_binding: u64,
    bits_raster: wgpu::ComputePipeline,
    bits_raster_layout: wgpu::BindGroupLayout,
    bits_reduce: wgpu::ComputePipeline,
    bits_reduce_layout: wgpu::BindGroupLayout,
    band_reduce: wgpu::ComputePipeline,
    band_reduce_layout: wgpu::BindGroupLayout,
    meshes: Mutex<HashMap<usize, CachedMesh>>,
    targets: Mutex<Vec<Targets>>,
    /// Renders of fewer pixels than this (all views together) run on the CPU.
    min_pixels: u64,
    /// Whether a GPU failure has been reported (once is enough).
    warned: std::sync::atomic::AtomicBool,
}

/// Default of [`WgpuRenderer`]'s CPU hand-off: below about a quarter-resolution 5-view
/// solve level, a GPU round trip costs more than the CPU rasteriser.
const DEFAULT_MIN_PIXELS: u64 = 100_000;

const RASTER_WGSL: &str = r#"
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
"#;

/// `BitsParams` in WGSL, bound first by every shader of the bit rasteriser (prepended to
/// each of their sources).
const BITS_PARAMS_WGSL: &str = r#"
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
"#;

const BITS_RASTER_WGSL: &str = r#"
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
"#;

/// The variance reduce's per-word part: per pixel, how many candidates cover it (c), summed
/// as c * (K - c), per pool entry (`gid.y`).
const BITS_REDUCE_WGSL: &str = r#"
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
"#;

/// The refinement's reduce, per-word part: band pixels whose coverage differs from the
/// observation, per (view `gid.z`, pose `gid.y`).
const BAND_REDUCE_WGSL: &str = r#"
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
"#;

/// The entry point both reduces share (appended to each): one thread per 32-pixel word
/// (`gid.x`), its `value` summed over the workgroup, one atomic add per workgroup into
/// `out[slot]` (a workgroup spans words only, so its slot is one).
const REDUCE_MAIN_WGSL: &str = r#"
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
"#;

/// A batch of meshes uploaded for the bit rasteriser.
struct PoolUpload {
    params: wgpu::Buffer,
    indices: wgpu::Buffer,
    vertices: wgpu::Buffer,
    entries: u32,
    max_triangles: u32,
}

/// `Params` of the exploration shaders (uniform layout, 48 bytes).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BitsParams {
    intrinsics: [f32; 4],
    tile: [u32; 2],
    words: u32,
    candidates: u32,
    triangles: u32,
    table: u32,
    near: f32,
    pad: u32,
}

fn type_name(t: wgpu::DeviceType) -> &'static str {
    match t {
        wgpu::DeviceType::DiscreteGpu => "discrete GPU",
        wgpu::DeviceType::IntegratedGpu => "integrated GPU",
        wgpu::DeviceType::VirtualGpu => "virtual GPU",
        wgpu::DeviceType::Cpu => "software (CPU)",
        wgpu::DeviceType::Other => "other",
    }
}

fn rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

impl WgpuRenderer {
    /// Opens the best adapter `policy` allows (discrete before integrated before software,
    /// Vulkan before GL), or says why none fits. `WGPU_BACKEND` (`vulkan`, `gl`) narrows the
    /// backends, as in wgpu's own tools.
    pub fn new(policy: AdapterPolicy) -> Result<WgpuRenderer, String> {
        // Vulkan first; GL (EGL) only when Vulkan has nothing, since probing EGL prints
        // display-server noise on headless machines.
        let tries = match wgpu::Backends::from_env() {
            Some(b) => vec![b],
            None => vec![wgpu::Backends::VULKAN, wgpu::Backends::GL],
        };
        let mut adapters = Vec::new();
        for backends in tries {
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
            desc.backends = backends;
            let instance = wgpu::Instance::new(desc);
            adapters = pollster::block_on(instance.enumerate_adapters(backends));
            // Any Vulkan adapter settles it: a machine with a GPU but no Vulkan driver is
            // the case GL is for, and probing EGL where Vulkan works only adds noise.
            if !adapters.is_empty() {
                break;
            }
        }
        adapters.sort_by_key(|a| {
            let info = a.get_info();
            (
                rank(info.device_type),
                info.backend != wgpu::Backend::Vulkan,
            )
        });
        let seen: Vec<String> = adapters
            .iter()
            .map(|a| {
                let i = a.get_info();
                format!("{} ({:?}, {})", i.name, i.backend, type_name(i.device_type))
            })
            .collect();
        let adapter = adapters
            .into_iter()
            .find(|a| {
                policy == AdapterPolicy::Any || a.get_info().device_type != wgpu::DeviceType::Cpu
            })
            .ok_or_else(|| {
                if seen.is_empty() {
                    "no wgpu adapter found (no Vulkan or GL driver; install mesa-vulkan-drivers for a software one)".to_string()
                } else {
                    format!(
                        "no hardware GPU adapter (found only: {}); use --renderer wgpu to accept a software one",
                        seen.join(", ")
                    )
                }
            })?;
        let info = adapter.get_info();
        let summary = AdapterSummary {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: type_name(info.device_type).to_string(),
            driver: format!("{} {}", info.driver, info.driver_info)
                .trim()
                .to_string(),
            software: info.device_type == wgpu::DeviceType::Cpu,
        };
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("easyhec"),
            required_limits: wgpu::Limits {
                max_texture_dimension_2d: limits.max_texture_dimension_2d,
                max_texture_array_layers: limits.max_texture_array_layers,
                max_buffer_size: limits.max_buffer_size,
                max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
                ..wgpu::Limits::downlevel_defaults()
            },
            ..Default::default()
        }))
        .map_err(|e| format!("wgpu device on {summary}: {e}"))?;
        Ok(Self::build(device, queue, summary, &limits))
    }

    fn build(
        device: wgpu::Device,
        queue: wgpu::Queue,
        adapter: AdapterSummary,
        limits: &wgpu::Limits,
    ) -> WgpuRenderer {
        let uniform = |binding, visibility| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let storage = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let target = [Some(wgpu::ColorTargetState {
            format: wgpu::TextureFormat::R8Unorm,
            blend: None,
            write_mask: wgpu::ColorWrites::RED,
        })];
        let primitive = wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            cull_mode: None,
            ..Default::default()
        };

        let raster_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("raster"),
            entries: &[
                uniform(0, wgpu::ShaderStages::VERTEX),
                storage(1),
                storage(2),
            ],
        });
        // A shader module and a pipeline layout of one bind group, for either kind of pipeline.
        let shader = |label: &str, source: &str, bind: &wgpu::BindGroupLayout| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(bind)],
                immediate_size: 0,
            });
            (module, layout)
        };
        let render_pipeline =
            |label: &str,
             source: &str,
             bind: &wgpu::BindGroupLayout,
             buffers: &[Option<wgpu::VertexBufferLayout>]| {
                let (module, layout) = shader(label, source, bind);
                device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some(label),
                    layout: Some(&layout),
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some("vs"),
                        compilation_options: Default::default(),
                        buffers,
                    },
                    primitive,
                    depth_stencil: None,
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some("fs"),
                        compilation_options: Default::default(),
                        targets: &target,
                    }),
                    multiview_mask: None,
                    cache: None,
                })
            };
        let raster = render_pipeline("raster", RASTER_WGSL, &raster_layout, &[]);

        // A compute stage: the bind group layout (binding 0 the uniform parameters, then one
        // storage buffer per entry of `read_only`, in order) and its pipeline.
        let compute_stage = |label: &str, source: &str, read_only: &[bool]| {
            let entries: Vec<wgpu::BindGroupLayoutEntry> =
                std::iter::once(uniform(0, wgpu::ShaderStages::COMPUTE))
                    .chain(read_only.iter().zip(1u32..).map(|(&read_only, binding)| {
                        wgpu::BindGroupLayoutEntry {
                            binding,
                            visibility: wgpu::ShaderStages::COMPUTE,
                            ty: wgpu::BindingType::Buffer {
                                ty: wgpu::BufferBindingType::Storage { read_only },
                                has_dynamic_offset: false,
                                min_binding_size: None,
                            },
                            count: None,
                        }
                    }))
                    .collect();
            let bind = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            });
            let (module, layout) = shader(label, source, &bind);
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&layout),
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            });
            (pipeline, bind)
        };
        let (bits_raster, bits_raster_layout) = compute_stage(
            "bits raster",
            &format!("{BITS_PARAMS_WGSL}{BITS_RASTER_WGSL}"),
            &[true, true, true, false],
        );
        let (bits_reduce, bits_reduce_layout) = compute_stage(
            "bits reduce",
            &format!("{BITS_PARAMS_WGSL}{BITS_REDUCE_WGSL}{REDUCE_MAIN_WGSL}"),
            &[true, false],
        );
        let (band_reduce, band_reduce_layout) = compute_stage(
            "band reduce",
            &format!("{BITS_PARAMS_WGSL}{BAND_REDUCE_WGSL}{REDUCE_MAIN_WGSL}"),
            &[true, true, false],
        );
        WgpuRenderer {
            device,
            queue,
            adapter,
            max_layers: limits.max_texture_array_layers.max(1),
            raster,
            raster_layout,
            max_storage_binding: limits.max_storage_buffer_binding_size.max(1),
            bits_raster,
            bits_raster_layout,
            bits_reduce,
            bits_reduce_layout,
            band_reduce,
            band_reduce_layout,
            meshes: Mutex::new(HashMap::new()),
            targets: Mutex::new(Vec::new()),
            min_pixels: std::env::var("EASYHEC_GPU_MIN_PIXELS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(DEFAULT_MIN_PIXELS),
            warned: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// Sends renders of fewer than `pixels` pixels (all views together) to the CPU renderer
    /// (0: everything on the GPU, as the parity tests want). `EASYHEC_GPU_MIN_PIXELS` sets the
    /// initial value.
    pub fn set_min_pixels(&mut self, pixels: u64) {
        self.min_pixels = pixels;
    }

    /// The adapter this renderer runs on.
    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    /// The index buffer of `topology`, uploaded once while the topology lives.
    fn mesh(&self, topology: &Arc<TriMesh>) -> (wgpu::Buffer, u32) {
        let key = Arc::as_ptr(topology) as usize;
        let mut cache = self.meshes.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = cache.get(&key) {
            if c.topology
                .upgrade()
                .is_some_and(|t| Arc::ptr_eq(&t, topology))
            {
                return (c.indices.clone(), c.count);
            }
        }
        if cache.len() >= 64 {
            cache.retain(|_, c| c.topology.strong_count() > 0);
        }
        let flat: Vec<u32> = topology.triangles.iter().flatten().copied().collect();
        let indices = self.index_buffer(&flat);
        cache.insert(
            key,
            CachedMesh {
                topology: Arc::downgrade(topology),
                indices: indices.clone(),
                count: flat.len() as u32,
            },
        );
        (indices, flat.len() as u32)
    }

    fn index_buffer(&self, flat: &[u32]) -> wgpu::Buffer {
        // wgpu refuses empty buffers; a lone zero index is never drawn.
        let data: &[u32] = if flat.is_empty() { &[0] } else { flat };
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("indices"),
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::INDEX | wgpu::BufferUsages::STORAGE,
            })
    }

    /// A render target and readback buffer for `layers` masks of `width x height`.
    fn take_targets(&self, width: u32, height: u32, layers: u32) -> Targets {
        let mut pool = self.targets.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = pool
            .iter()
            .position(|t| t.width == width && t.height == height && t.layers == layers)
        {
            return pool.swap_remove(i);
        }
        drop(pool);
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("masks"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: layers,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R8Unorm,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded_row(width)) * u64::from(height) * u64::from(layers),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        Targets {
            width,
            height,
            layers,
            texture,
            readback,
        }
    }

    fn give_back(&self, targets: Targets) {
        let mut pool = self.targets.lock().unwrap_or_else(|e| e.into_inner());
        if pool.len() >= 8 {
            pool.remove(0);
        }
        pool.push(targets);
    }

    /// Maps `buffer` for reading and waits for the GPU; `None` when the device fails (lost,
    /// out of memory), after which callers redo the work on the CPU.
    fn read(&self, buffer: &wgpu::Buffer, size: u64) -> Option<Vec<u8>> {
        let slice = buffer.slice(..size);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        loop {
            let polled = self.device.poll(wgpu::PollType::wait_indefinitely());
            match rx.try_recv() {
                Ok(Ok(())) => break,
                Ok(Err(e)) => return self.failed(&format!("readback: {e}")),
                Err(std::sync::mpsc::TryRecvError::Empty) => {
                    if let Err(e) = polled {
                        return self.failed(&format!("waiting for the GPU: {e}"));
                    }
                }
                Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                    return self.failed("readback callback dropped")
                }
            }
        }
        let out = slice.get_mapped_range().map(|v| v.to_vec()).ok();
        buffer.unmap();
        out
    }

    /// Reports a GPU failure once per renderer; the caller falls back to the CPU.
    fn failed(&self, what: &str) -> Option<Vec<u8>> {
        if !self.warned.swap(true, std::sync::atomic::Ordering::Relaxed) {
            eprintln!(
                "renderer: wgpu on {} failed ({what}); rendering on the CPU instead",
                self.adapter
            );
        }
        None
    }

    /// Masks of every robot at one camera pose, in one submission.
    fn masks(
        &self,
        robots: &[&PosedRobot],
        camera: &Camera,
        camera_from_base: &Isometry3<f64>,
        with_points: bool,
    ) -> Vec<(Mask, Projected)> {
        let (w, h) = (camera.width, camera.height);
        let mut out = Vec::with_capacity(robots.len());
        let chunk = (self.max_layers as usize).clamp(1, 64);
        for group in robots.chunks(chunk) {
            let projected: Vec<Projected> = group
                .iter()
                .map(|r| project_vertices(&r.vertices_base, camera, camera_from_base))
                .collect();
            let layers = group.len() as u32;
            let targets = self.take_targets(w, h, layers);
            let frame = self
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("frame"),
                    contents: bytemuck::cast_slice(&[w as f32, h as f32, 0.0, 0.0]),
                    usage: wgpu::BufferUsages::UNIFORM,
                });
            let mut encoder = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            let mut keep = Vec::new();
            for (layer, (robot, (pixels, _))) in group.iter().zip(&projected).enumerate() {
                let positions: Vec<[f32; 4]> = pixels
                    .iter()
                    .map(|p| {
                        if p[0].is_nan() {
                            [0.0; 4]
                        } else {
                            [p[0] as f32, p[1] as f32, 1.0, 0.0]
                        }
                    })
                    .collect();
                let (indices, count) = self.mesh(&robot.topology);
                let vertices = self
                    .device
                    .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some("pixels"),
                        contents: if positions.is_empty() {
                            bytemuck::cast_slice(&[0f32; 4])
                        } else {
                            bytemuck::cast_slice(&positions)
                        },
                        usage: wgpu::BufferUsages::STORAGE,
                    });
                let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("raster"),
                    layout: &self.raster_layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: frame.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: vertices.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: indices.as_entire_binding(),
                        },
                    ],
                });
                {
                    let mut pass =
                        layer_pass(&mut encoder, &targets.texture, layer as u32, "silhouette");
                    if count > 0 {
                        pass.set_pipeline(&self.raster);
                        pass.set_bind_group(0, &bind, &[]);
                        pass.draw(0..count, 0..1);
                    }
                }
                keep.push((vertices, indices, bind));
            }
            let row = padded_row(w);
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: &targets.texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &targets.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row),
                        rows_per_image: Some(h),
                    },
                },
                wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: layers,
                },
            );
            self.queue.submit([encoder.finish()]);
            let Some(bytes) = self.read(
                &targets.readback,
                u64::from(row) * u64::from(h) * u64::from(layers),
            ) else {
                drop(keep);
                for (robot, (pixels, points)) in group.iter().zip(projected) {
                    let mask = crate::render::rasterize(&robot.topology, &pixels, w, h);
                    out.push((mask, (pixels, points)));
                }
                continue;
            };
            drop(keep);
            self.give_back(targets);
            let (wu, hu, ru) = (w as usize, h as usize, row as usize);
            for (layer, (pixels, points)) in projected.into_iter().enumerate() {
                let mut mask = Mask::new(w, h);
                let base = layer * ru * hu;
                for v in 0..hu {
                    let src = &bytes[base + v * ru..base + v * ru + wu];
                    for (d, &s) in mask.data[v * wu..(v + 1) * wu].iter_mut().zip(src) {
                        *d = u8::from(s > 127);
                    }
                }
                if with_points {
                    out.push((mask, (pixels, points)));
                } else {
                    out.push((mask, (Vec::new(), Vec::new())));
                }
            }
        }
        out
    }

    /// `poses` as column-major f32 matrices, as WGSL's `mat4x4` expects.
    fn pose_buffer(&self, poses: &[Isometry3<f64>]) -> wgpu::Buffer {
        let poses: Vec<[f32; 16]> = poses
            .iter()
            .map(|p| {
                let m = p.to_homogeneous();
                let mut a = [0f32; 16];
                for c in 0..4 {
                    for r in 0..4 {
                        a[c * 4 + r] = m[(r, c)] as f32;
                    }
                }
                a
            })
            .collect();
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("poses"),
                contents: bytemuck::cast_slice(&poses),
                usage: wgpu::BufferUsages::STORAGE,
            })
    }

    /// Uploads `group`'s meshes for the bit rasteriser: the entry table and each distinct
    /// mesh's indices once (a `CoarseRobot`'s poses all share one), the vertices as f32.
    /// `None` when a mesh has more triangles than one dispatch row holds.
    fn upload_pool(
        &self,
        camera: &Camera,
        group: &[&PosedRobot],
        candidates: u32,
        words: u32,
    ) -> Option<PoolUpload> {
        let entries = group.len() as u32;
        let table = 3 * entries;
        let mut indices: Vec<u32> = Vec::with_capacity(table as usize);
        let mut meshes: Vec<u32> = Vec::new();
        let mut seen: HashMap<usize, u32> = HashMap::new();
        let mut first_vertex = 0u32;
        let mut max_triangles = 0u32;
        for r in group {
            let at = *seen
                .entry(Arc::as_ptr(&r.topology) as usize)
                .or_insert_with(|| {
                    let at = table + meshes.len() as u32;
                    meshes.extend(r.topology.triangles.iter().flatten());
                    at
                });
            let count = r.topology.triangles.len() as u32;
            indices.extend([at, count, first_vertex]);
            first_vertex += r.vertices_base.len() as u32;
            max_triangles = max_triangles.max(count);
        }
        indices.extend(meshes);
        if max_triangles.div_ceil(BITS_WORKGROUP) > 65_535 {
            return None;
        }
        let params = BitsParams {
            intrinsics: [
                camera.fx as f32,
                camera.fy as f32,
                camera.cx as f32,
                camera.cy as f32,
            ],
            tile: [camera.width, camera.height],
            words,
            candidates,
            triangles: max_triangles,
            table,
            near: crate::render::NEAR_PLANE_M as f32,
            pad: 0,
        };
        let params = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("bits params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let indices = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("pool indices"),
                contents: bytemuck::cast_slice(&indices),
                usage: wgpu::BufferUsages::STORAGE,
            });
        // Every core converts its share (2000 samples of a coarse robot are about 20 million
        // floats a round; one thread spends longer on them than the GPU on the whole round).
        let mut vertices = vec![0f32; (first_vertex as usize * 3).max(3)];
        let mut parts = Vec::with_capacity(group.len());
        let mut rest: &mut [f32] = &mut vertices;
        for r in group {
            let (part, tail) = std::mem::take(&mut rest).split_at_mut(r.vertices_base.len() * 3);
            parts.push(part);
            rest = tail;
        }
        parts
            .into_par_iter()
            .zip(group.par_iter())
            .for_each(|(out, r)| {
                for (o, p) in out.chunks_exact_mut(3).zip(&r.vertices_base) {
                    o[0] = p.x as f32;
                    o[1] = p.y as f32;
                    o[2] = p.z as f32;
                }
            });
        let vertices = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("pool vertices"),
                contents: bytemuck::cast_slice(&vertices),
                usage: wgpu::BufferUsages::STORAGE,
            });
        Some(PoolUpload {
            params,
            indices,
            vertices,
            entries,
            max_triangles,
        })
    }

    /// One submission: the bit rasteriser draws every (entry, pose) silhouette of `upload`
    /// into cleared bits, then `reduce` runs over them with the bindings `params, bits,
    /// inputs..., output` (a cleared `u32` array of `outputs` entries), dispatched as
    /// `dispatch`; only the output is read back. `None` when the device fails.
    #[allow(clippy::too_many_arguments)]
    fn raster_and_reduce(
        &self,
        upload: &PoolUpload,
        poses: &wgpu::Buffer,
        candidates: u32,
        words: u32,
        reduce: (&wgpu::ComputePipeline, &wgpu::BindGroupLayout),
        inputs: &[&wgpu::Buffer],
        outputs: u64,
        dispatch: [u32; 3],
    ) -> Option<Vec<u32>> {
        let storage = |label, size, usage| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let copy_dst = wgpu::BufferUsages::COPY_DST;
        let bits = storage(
            "silhouette bits",
            u64::from(upload.entries) * u64::from(candidates) * u64::from(words) * 4,
            wgpu::BufferUsages::STORAGE | copy_dst,
        );
        let size = outputs.max(1) * 4;
        let out = storage(
            "reduced",
            size,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | copy_dst,
        );
        let readback = storage("readback", size, wgpu::BufferUsages::MAP_READ | copy_dst);
        let bind = |layout: &wgpu::BindGroupLayout, buffers: &[&wgpu::Buffer]| {
            let entries: Vec<wgpu::BindGroupEntry> = buffers
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: b.as_entire_binding(),
                })
                .collect();
            self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout,
                entries: &entries,
            })
        };
        let raster_bind = bind(
            &self.bits_raster_layout,
            &[
                &upload.params,
                poses,
                &upload.vertices,
                &upload.indices,
                &bits,
            ],
        );
        let mut reduce_buffers = vec![&upload.params, &bits];
        reduce_buffers.extend_from_slice(inputs);
        reduce_buffers.push(&out);
        let reduce_bind = bind(reduce.1, &reduce_buffers);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        encoder.clear_buffer(&bits, 0, None);
        encoder.clear_buffer(&out, 0, None);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("silhouette bits"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.bits_raster);
            pass.set_bind_group(0, &raster_bind, &[]);
            pass.dispatch_workgroups(
                upload.max_triangles.div_ceil(BITS_WORKGROUP).max(1),
                candidates,
                upload.entries,
            );
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("reduce"),
                timestamp_writes: None,
            });
            pass.set_pipeline(reduce.0);
            pass.set_bind_group(0, &reduce_bind, &[]);
            pass.dispatch_workgroups(dispatch[0], dispatch[1], dispatch[2]);
        }
        encoder.copy_buffer_to_buffer(&out, 0, &readback, 0, size);
        self.queue.submit([encoder.finish()]);
        let bytes = self.read(&readback, size)?;
        Some(
            bytes
                .chunks_exact(4)
                .take(outputs as usize)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
        )
    }

    /// [`BatchScoring::band_mismatches`] on the GPU alone: every (view, pose) silhouette as
    /// bits in one submission per batch of views, compared with the band and observation
    /// bits on the GPU, only the counts read back. `None` where the GPU does not take the
    /// batch (a distorted camera, fewer pixels than the CPU hand-off, masks of the wrong
    /// size, a batch over the memory bound, a device failure); the trait method then counts
    /// on the CPU. Public so that the parity tests can tell the two paths apart.
    pub fn band_mismatches_on_gpu(
        &self,
        camera: &Camera,
        robots: &[&PosedRobot],
        band: &[&[u8]],
        observed: &[&[u8]],
        poses: &[Isometry3<f64>],
    ) -> Option<Vec<u32>> {
        let pixels = u64::from(camera.width) * u64::from(camera.height) * robots.len() as u64;
        if camera.is_distorted()
            || pixels < self.min_pixels
            || band.len() != robots.len()
            || observed.len() != robots.len()
        {
            return None;
        }
        let k = poses.len() as u32;
        let words = (camera.width * camera.height).div_ceil(32);
        let bits_per_view = u64::from(k) * u64::from(words) * 4;
        if k == 0 || bits_per_view > self.max_storage_binding.min(EXPLORE_BATCH_BYTES) {
            return None;
        }
        let per_batch = (self.max_storage_binding.min(EXPLORE_BATCH_BYTES) / bits_per_view)
            .clamp(1, 65_535) as usize;
        let pose_buffer = self.pose_buffer(poses);
        let mut counts = vec![0u32; poses.len() * robots.len()];
        for (batch, first) in robots.chunks(per_batch).zip((0..).step_by(per_batch)) {
            let upload = self.upload_pool(camera, batch, k, words)?;
            let entries = upload.entries;
            // Per view: its band's bits, then its observation's.
            let pixels = (camera.width * camera.height) as usize;
            let masks: Vec<&[u8]> = (first..first + batch.len())
                .flat_map(|v| [band[v], observed[v]])
                .collect();
            if masks.iter().any(|m| m.len() != pixels) {
                return None;
            }
            let mut reference = vec![0u32; masks.len() * words as usize];
            reference
                .par_chunks_mut(words as usize)
                .zip(masks.par_iter())
                .for_each(|(out, m)| {
                    for (w, c) in out.iter_mut().zip(m.chunks(32)) {
                        *w = c
                            .iter()
                            .enumerate()
                            .fold(0, |w, (i, &v)| w | (u32::from(v != 0) << i));
                    }
                });
            let reference = self
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("band and observation"),
                    contents: bytemuck::cast_slice(&reference),
                    usage: wgpu::BufferUsages::STORAGE,
                });
            let reduced = self.raster_and_reduce(
                &upload,
                &pose_buffer,
                k,
                words,
                (&self.band_reduce, &self.band_reduce_layout),
                &[&reference],
                u64::from(entries) * u64::from(k),
                [words.div_ceil(BITS_WORKGROUP), k, entries],
            )?;
            // GPU layout [view][pose]; the trait's is [pose][view].
            let views = robots.len();
            for (i, c) in reduced.into_iter().enumerate() {
                let (v, s) = (first + i / k as usize, i % k as usize);
                counts[s * views + v] = c;
            }
        }
        Some(counts)
    }

    /// Per-sample disagreement of `candidates` over `pool` (see
    /// [`crate::scoring::cpu::disagreement`]), on the GPU, in batches.
    fn disagreement_gpu(
        &self,
        camera: &Camera,
        pool: &[&PosedRobot],
        candidates: &[Isometry3<f64>],
    ) -> Vec<f64> {
        if pool.is_empty() {
            return Vec::new();
        }
        let k = candidates.len() as u32;
        let (tw, th) = (camera.width, camera.height);
        let words = (tw * th).div_ceil(32);
        let bits_per_entry = u64::from(k) * u64::from(words) * 4;
        let poses = self.pose_buffer(candidates);
        let mut scores = Vec::with_capacity(pool.len());
        let mut start = 0;
        while start < pool.len() {
            // A batch: as many entries as fit the memory bound (at least one).
            let (mut end, mut bytes, mut vertex_bytes, mut index_bytes) = (start, 0, 0, 0);
            let mut batch_meshes = std::collections::HashSet::new();
            while end < pool.len() && end - start < 65_535 {
                let r = pool[end];
                let v = r.vertices_base.len() as u64 * 12;
                let i = if batch_meshes.contains(&Arc::as_ptr(&r.topology)) {
                    12
                } else {
                    12 + r.topology.triangles.len() as u64 * 12
                };
                let entries = (end - start + 1) as u64;
                if end > start
                    && (bytes + bits_per_entry + v + i > EXPLORE_BATCH_BYTES
                        || vertex_bytes + v > self.max_storage_binding
                        || index_bytes + i > self.max_storage_binding
                        || entries * bits_per_entry > self.max_storage_binding)
                {
                    break;
                }
                batch_meshes.insert(Arc::as_ptr(&r.topology));
                bytes += bits_per_entry + v + i;
                vertex_bytes += v;
                index_bytes += i;
                end += 1;
            }
            let group = &pool[start..end];
            start = end;
            let entries = group.len() as u32;
            let Some(upload) = self.upload_pool(camera, group, k, words) else {
                // More triangles than one dispatch row holds: a mesh no scoring pass decimates
                // to; the CPU takes it.
                scores.extend(crate::scoring::cpu::disagreement_many(
                    camera, group, candidates,
                ));
                continue;
            };
            let Some(totals) = self.raster_and_reduce(
                &upload,
                &poses,
                k,
                words,
                (&self.bits_reduce, &self.bits_reduce_layout),
                &[],
                u64::from(entries),
                [words.div_ceil(BITS_WORKGROUP), entries, 1],
            ) else {
                scores.extend(crate::scoring::cpu::disagreement_many(
                    camera, group, candidates,
                ));
                continue;
            };
            let kk = f64::from(k) * f64::from(k);
            scores.extend(totals.into_iter().map(|t| f64::from(t) / kk));
        }
        scores
    }
}

/// A render pass into layer `layer` of `texture`, cleared to background.
fn layer_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    texture: &wgpu::Texture,
    layer: u32,
    label: &str,
) -> wgpu::RenderPass<'e> {
    let view = texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2),
        base_array_layer: layer,
        array_layer_count: Some(1),
        ..Default::default()
    });
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: &view,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                store: wgpu::StoreOp::Store,
            },
        })],
        depth_stencil_attachment: None,
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

/// Bytes per row of a readback copy: a multiple of 256, as wgpu requires.
fn padded_row(width: u32) -> u32 {
    width.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
}

impl SilhouetteRenderer for WgpuRenderer {
    fn name(&self) -> &str {
        "wgpu"
    }

    fn render(
        &self,
        robot: &PosedRobot,
        camera: &Camera,
        camera_from_base: &Isometry3<f64>,
        boundary_step_px: Option<f64>,
    ) -> Silhouette {
        self.render_many(&[robot], camera, camera_from_base, boundary_step_px)
            .pop()
            .unwrap_or_else(|| Silhouette {
                mask: Mask::new(camera.width, camera.height),
                boundary: Vec::new(),
            })
    }

    fn render_many(
        &self,
        robots: &[&PosedRobot],
        camera: &Camera,
        camera_from_base: &Isometry3<f64>,
        boundary_step_px: Option<f64>,
    ) -> Vec<Silhouette> {
        // Small jobs (coarse pyramid levels, the coarse search) cost less on the CPU than a GPU
        // round trip; both give the same masks.
        let pixels = u64::from(camera.width) * u64::from(camera.height) * robots.len() as u64;
        if pixels < self.min_pixels {
            return crate::render::CpuRenderer.render_many(
                robots,
                camera,
                camera_from_base,
                boundary_step_px,
            );
        }
        let masks = self.masks(robots, camera, camera_from_base, boundary_step_px.is_some());
        masks
            .into_par_iter()
            .zip(robots.par_iter())
            .map(|((mask, (pixels, points)), robot)| {
                let boundary = match boundary_step_px {
                    Some(step) => outline_samples(&robot.topology, &pixels, &points, &mask, step),
                    None => Vec::new(),
                };
                Silhouette { mask, boundary }
            })
            .collect()
    }
}

impl BatchScoring for WgpuRenderer {
    fn disagreement_many(
        &self,
        camera: &Camera,
        pool: &[&PosedRobot],
        candidates: &[Isometry3<f64>],
    ) -> Vec<f64> {
        if camera.is_distorted() || candidates.is_empty() {
            return crate::scoring::cpu::disagreement_many(camera, pool, candidates);
        }
        self.disagreement_gpu(camera, pool, candidates)
    }

    fn band_mismatches(
        &self,
        camera: &Camera,
        robots: &[&PosedRobot],
        band: &[&[u8]],
        observed: &[&[u8]],
        poses: &[Isometry3<f64>],
    ) -> Vec<u32> {
        self.band_mismatches_on_gpu(camera, robots, band, observed, poses)
            .unwrap_or_else(|| {
                crate::scoring::cpu::band_mismatches(camera, robots, band, observed, poses)
            })
    }
}
