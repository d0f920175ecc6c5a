//! The posterior refinement's score on the GPU ([`BatchScoring::band_mismatches`]): per
//! (sampled pose, view), the band pixels whose coverage differs from the observation, from
//! the bit rasteriser and a reduce against the band and observation bits.
//!
//! [`BatchScoring::band_mismatches`]: crate::scoring::BatchScoring::band_mismatches

use nalgebra::Isometry3;
use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::{WgpuRenderer, BITS_WORKGROUP, EXPLORE_BATCH_BYTES};
use crate::camera::Intrinsics;
use crate::render::PosedRobot;

impl WgpuRenderer {
    /// The band scores ([`BatchScoring::band_mismatches`](crate::scoring::BatchScoring))
    /// on the GPU alone: every (view, pose) silhouette as bits in one submission per batch
    /// of views, compared with the band and observation bits on the GPU, only the counts
    /// read back. `None` where the GPU does not take the
    /// batch (a distorted camera, fewer pixels than the CPU hand-off, masks of the wrong
    /// size, a batch over the memory bound, a device failure); the trait method then counts
    /// on the CPU. Public so that the parity tests can tell the two paths apart.
    pub fn band_mismatches_on_gpu(
        &self,
        camera: &Intrinsics,
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
                (
                    &self.pipelines.band_reduce,
                    &self.pipelines.band_reduce_layout,
                ),
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
}
