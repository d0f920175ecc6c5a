//! Silhouette masks on the graphics pipeline: every view of a solve drawn into one layer of a
//! texture array in one submission, the masks read back for the CPU's outline sampler.
//!
//! Index buffers and render targets are cached across calls: a solve renders the same meshes
//! at the same sizes for dozens of iterations, and re-uploading them each time would cost
//! more than the draw.

use std::sync::{Arc, Weak};

use nalgebra::Isometry3;
use wgpu::util::DeviceExt;

use super::WgpuRenderer;
use crate::camera::Intrinsics;
use crate::mask::Mask;
use crate::mesh::TriMesh;
use crate::render::{project_vertices, PosedRobot};

/// A view's projected vertices (pixels) and camera-frame points, as the outline sampler
/// takes them.
type Projected = (Vec<[f64; 2]>, Vec<nalgebra::Point3<f64>>);

/// Index buffer of one mesh topology, cached while the topology lives.
pub(super) struct CachedMesh {
    topology: Weak<TriMesh>,
    indices: wgpu::Buffer,
    count: u32,
}

/// Reusable render target and readback buffer of one size.
pub(super) struct Targets {
    width: u32,
    height: u32,
    layers: u32,
    texture: wgpu::Texture,
    readback: wgpu::Buffer,
}

impl WgpuRenderer {
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

    /// Masks of every robot at one camera pose, in one submission.
    pub(super) fn masks(
        &self,
        robots: &[&PosedRobot],
        camera: &Intrinsics,
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
                    layout: &self.pipelines.raster_layout,
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
                        pass.set_pipeline(&self.pipelines.raster);
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
