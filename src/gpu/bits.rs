//! The compute bit rasteriser both batched scores start with: every (pool entry, pose)
//! silhouette of a batch as one bit per pixel in a storage buffer, followed in the same
//! submission by a score's reduce over those bits, so only the reduced integers come back.
//!
//! The rasteriser projects in f32 on the GPU (the CPU's pixel rule, but not its f64
//! projection), which is why the scores agree with the CPU reference only up to pixel-centre
//! ties; the silhouettes a solve uses go through the graphics path (`raster`) instead.

use std::collections::HashMap;
use std::sync::Arc;

use nalgebra::Isometry3;
use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::{WgpuRenderer, BITS_WORKGROUP};
use crate::camera::Intrinsics;
use crate::render::PosedRobot;

/// A batch of meshes uploaded for the bit rasteriser.
pub(super) struct PoolUpload {
    /// `BitsParams` as a uniform buffer.
    params: wgpu::Buffer,
    /// The entry table, then each distinct mesh's indices.
    indices: wgpu::Buffer,
    /// Every entry's vertices (base frame, f32), entry after entry.
    vertices: wgpu::Buffer,
    /// Pool entries in the batch.
    pub(super) entries: u32,
    /// Most triangles of any entry (the dispatch's width).
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

impl WgpuRenderer {
    /// `poses` as column-major f32 matrices, as WGSL's `mat4x4` expects.
    pub(super) fn pose_buffer(&self, poses: &[Isometry3<f64>]) -> wgpu::Buffer {
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
    pub(super) fn upload_pool(
        &self,
        camera: &Intrinsics,
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
    pub(super) fn raster_and_reduce(
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
            &self.pipelines.bits_raster_layout,
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
            pass.set_pipeline(&self.pipelines.bits_raster);
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
}
