//! The backend's shaders and the pipelines compiled from them, once per device.
//!
//! The WGSL lives in `shaders/*.wgsl` so that it reads (and diffs) as shader code. The bit
//! rasteriser's shaders share their uniform (`bits_params.wgsl`) and both reduces share their
//! entry point (`reduce_main.wgsl`): each pipeline's source is the concatenation of its parts.

/// The silhouette mask shader of the graphics pipeline (`vs` and `fs`).
const RASTER_WGSL: &str = include_str!("shaders/raster.wgsl");
/// `BitsParams` in WGSL, bound first by every shader of the bit rasteriser (prepended to
/// each of their sources).
const BITS_PARAMS_WGSL: &str = include_str!("shaders/bits_params.wgsl");
/// The compute bit rasteriser: one thread per (triangle, pose, entry).
const BITS_RASTER_WGSL: &str = include_str!("shaders/bits_raster.wgsl");
/// The variance reduce's per-word part: per pixel, how many candidates cover it (c), summed
/// as c * (K - c), per pool entry.
const BITS_REDUCE_WGSL: &str = include_str!("shaders/bits_reduce.wgsl");
/// The refinement's reduce, per-word part: band pixels whose coverage differs from the
/// observation, per (view, pose).
const BAND_REDUCE_WGSL: &str = include_str!("shaders/band_reduce.wgsl");
/// The entry point both reduces share (appended to each).
const REDUCE_MAIN_WGSL: &str = include_str!("shaders/reduce_main.wgsl");

/// Every pipeline of the backend, each with the layout of its one bind group.
pub(super) struct Pipelines {
    /// Silhouette masks on the graphics pipeline: binds the frame size, the projected
    /// vertices and the indices.
    pub(super) raster: wgpu::RenderPipeline,
    pub(super) raster_layout: wgpu::BindGroupLayout,
    /// The compute bit rasteriser: binds `BitsParams`, poses, vertices, the entry table and
    /// indices, and the output bits.
    pub(super) bits_raster: wgpu::ComputePipeline,
    pub(super) bits_raster_layout: wgpu::BindGroupLayout,
    /// Exploration's variance reduce: binds `BitsParams`, the bits and the per-entry totals.
    pub(super) bits_reduce: wgpu::ComputePipeline,
    pub(super) bits_reduce_layout: wgpu::BindGroupLayout,
    /// The refinement's band reduce: binds `BitsParams`, the bits, the band and observation
    /// bits, and the per-(view, pose) counts.
    pub(super) band_reduce: wgpu::ComputePipeline,
    pub(super) band_reduce_layout: wgpu::BindGroupLayout,
}

impl Pipelines {
    /// Compiles every shader on `device`.
    pub(super) fn new(device: &wgpu::Device) -> Pipelines {
        let (raster, raster_layout) = raster_pipeline(device);
        let (bits_raster, bits_raster_layout) = compute_stage(
            device,
            "bits raster",
            &format!("{BITS_PARAMS_WGSL}{BITS_RASTER_WGSL}"),
            &[true, true, true, false],
        );
        let (bits_reduce, bits_reduce_layout) = compute_stage(
            device,
            "bits reduce",
            &format!("{BITS_PARAMS_WGSL}{BITS_REDUCE_WGSL}{REDUCE_MAIN_WGSL}"),
            &[true, false],
        );
        let (band_reduce, band_reduce_layout) = compute_stage(
            device,
            "band reduce",
            &format!("{BITS_PARAMS_WGSL}{BAND_REDUCE_WGSL}{REDUCE_MAIN_WGSL}"),
            &[true, true, false],
        );
        Pipelines {
            raster,
            raster_layout,
            bits_raster,
            bits_raster_layout,
            bits_reduce,
            bits_reduce_layout,
            band_reduce,
            band_reduce_layout,
        }
    }
}

/// A bind group layout entry for the uniform buffer at `binding`.
fn uniform(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A bind group layout entry for the storage buffer at `binding`.
fn storage(
    binding: u32,
    visibility: wgpu::ShaderStages,
    read_only: bool,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A shader module and a pipeline layout of one bind group, for either kind of pipeline.
fn shader(
    device: &wgpu::Device,
    label: &str,
    source: &str,
    bind: &wgpu::BindGroupLayout,
) -> (wgpu::ShaderModule, wgpu::PipelineLayout) {
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
}

/// The silhouette mask pipeline: triangle lists from storage buffers (no vertex buffers),
/// no culling, into an R8 target.
fn raster_pipeline(device: &wgpu::Device) -> (wgpu::RenderPipeline, wgpu::BindGroupLayout) {
    let vertex = wgpu::ShaderStages::VERTEX;
    let bind = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("raster"),
        entries: &[
            uniform(0, vertex),
            storage(1, vertex, true),
            storage(2, vertex, true),
        ],
    });
    let (module, layout) = shader(device, "raster", RASTER_WGSL, &bind);
    let target = [Some(wgpu::ColorTargetState {
        format: wgpu::TextureFormat::R8Unorm,
        blend: None,
        write_mask: wgpu::ColorWrites::RED,
    })];
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("raster"),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            cull_mode: None,
            ..Default::default()
        },
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
    });
    (pipeline, bind)
}

/// A compute stage: the bind group layout (binding 0 the uniform parameters, then one
/// storage buffer per entry of `read_only`, in order) and its pipeline (entry point `main`).
fn compute_stage(
    device: &wgpu::Device,
    label: &str,
    source: &str,
    read_only: &[bool],
) -> (wgpu::ComputePipeline, wgpu::BindGroupLayout) {
    let compute = wgpu::ShaderStages::COMPUTE;
    let entries: Vec<wgpu::BindGroupLayoutEntry> = std::iter::once(uniform(0, compute))
        .chain(
            read_only
                .iter()
                .zip(1u32..)
                .map(|(&read_only, binding)| storage(binding, compute, read_only)),
        )
        .collect();
    let bind = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    });
    let (module, layout) = shader(device, label, source, &bind);
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: Some(&layout),
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    });
    (pipeline, bind)
}
