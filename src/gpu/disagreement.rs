//! Exploration's score on the GPU ([`BatchScoring::disagreement_many`]): per pool entry, the
//! per-pixel variance of the candidate camera poses' silhouettes, from the bit rasteriser and
//! a reduce that counts, per pixel, the candidates covering it.
//!
//! [`BatchScoring::disagreement_many`]: crate::scoring::BatchScoring::disagreement_many

use std::sync::Arc;

use nalgebra::Isometry3;

use super::{WgpuRenderer, BITS_WORKGROUP, EXPLORE_BATCH_BYTES};
use crate::camera::Intrinsics;
use crate::render::PosedRobot;

impl WgpuRenderer {
    /// Per-sample disagreement of `candidates` over `pool` (see
    /// [`crate::scoring::cpu::disagreement`]), on the GPU, in batches.
    pub(super) fn disagreement_gpu(
        &self,
        camera: &Intrinsics,
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
                (
                    &self.pipelines.bits_reduce,
                    &self.pipelines.bits_reduce_layout,
                ),
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
