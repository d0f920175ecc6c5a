//! The wgpu backend: implements [`SilhouetteRenderer`] (silhouettes rasterised on a GPU) and
//! [`BatchScoring`] (exploration's and the refinement's scores computed there in batches).
//!
//! Two GPU paths, both ending in the exact integers the CPU backend computes:
//! - **Silhouettes** ([`SilhouetteRenderer::render_many`]): vertices are projected on the CPU in
//!   f64 (the same projection, distortion and near-plane rule as [`CpuRenderer`]), uploaded as
//!   pixel positions, and every view of a solve is drawn into one layer of a texture array in
//!   a single submission; the masks come back and the outline samples are taken from them on
//!   the CPU with [`crate::render::outline_samples`], so the solver's gradient is the CPU's
//!   code on the GPU's mask.
//! - **Exploration** ([`BatchScoring::disagreement_many`]): a compute rasteriser, one
//!   thread per (triangle, camera candidate, joint sample), applies the CPU's pixel rule in f32
//!   and sets one bit per covered pixel in the candidate's bitmask; a second pass counts per
//!   pixel how many candidates cover it and reduces `count * (K - count)` to one integer per
//!   sample, and only those integers are read back. Compute instead of the graphics pipeline:
//!   exploration's triangles are mostly smaller than a scoring pixel, and on data-centre GPUs
//!   (an H100 has graphics units in only a few of its clusters) every shader core can run it.
//!   Batches are sized so GPU memory stays bounded whatever the sample count.
//! - **Refinement** ([`BatchScoring::band_mismatches`]): the same bit rasteriser draws every
//!   (view, sampled pose) silhouette; a reduce compares them with the band and observation
//!   bits and only the per-(pose, view) counts are read back.
//!
//! Whatever the GPU cannot take (a distorted camera, a job too small to pay for a round trip,
//! a device failure) runs on the CPU reference ([`CpuRenderer`], [`crate::scoring::cpu`]), so
//! callers always get an answer.
//!
//! Layout, by purpose: `device` opens an adapter and reads results back, `pipelines` compiles
//! the WGSL shaders (`shaders/*.wgsl`), `raster` draws silhouette masks on the graphics
//! pipeline, `bits` is the compute bit rasteriser both scores start with, and `disagreement`
//! and `band` are the two scores.
//!
//! Pixel centres: the CPU samples pixel `(u, v)` at image coordinates `(u, v)`; the GPU samples
//! framebuffer pixel centres at `+0.5`, so positions are shifted by half a pixel on the way
//! in. The rasteriser's fill rule and fixed-point snapping differ from the CPU's inclusive
//! edge test only for pixel centres within about 1/256 px of an edge.
//!
//! [`CpuRenderer`]: crate::render::CpuRenderer

mod band;
mod bits;
mod device;
mod disagreement;
mod pipelines;
mod raster;

use std::collections::HashMap;
use std::sync::Mutex;

use nalgebra::Isometry3;
use rayon::prelude::*;

use crate::camera::Intrinsics;
use crate::mask::Mask;
use crate::render::{silhouette_from, PosedRobot, Silhouette, SilhouetteRenderer};
use crate::scoring::BatchScoring;

/// GPU memory one exploration batch may use for its candidate bitmasks and vertices, bytes.
const EXPLORE_BATCH_BYTES: u64 = 256 << 20;
/// Threads per workgroup of the exploration shaders (`@workgroup_size` in their WGSL).
const BITS_WORKGROUP: u32 = 64;

/// Default of [`WgpuRenderer`]'s CPU hand-off: below about a quarter-resolution 5-view
/// solve level, a GPU round trip costs more than the CPU rasteriser.
const DEFAULT_MIN_PIXELS: u64 = 100_000;

/// Which adapters a caller accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterPolicy {
    /// Hardware adapters only (discrete, integrated or virtual GPUs): what `auto` wants.
    HardwareOnly,
    /// Any adapter, software rasterisers (lavapipe, llvmpipe) included, hardware first.
    Any,
}

/// What a chosen adapter is, for logs and the benchmark figures.
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

/// Silhouettes and batched scores on a wgpu device.
pub struct WgpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: AdapterSummary,
    max_layers: u32,
    max_storage_binding: u64,
    pipelines: pipelines::Pipelines,
    /// Index buffers of the meshes drawn lately, by topology address.
    meshes: Mutex<HashMap<usize, raster::CachedMesh>>,
    /// Render targets and readback buffers of the sizes drawn lately.
    targets: Mutex<Vec<raster::Targets>>,
    /// Renders of fewer pixels than this (all views together) run on the CPU.
    min_pixels: u64,
    /// Whether a GPU failure has been reported (once is enough).
    warned: std::sync::atomic::AtomicBool,
}

impl WgpuRenderer {
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
}

impl SilhouetteRenderer for WgpuRenderer {
    fn name(&self) -> &str {
        "wgpu"
    }

    fn render(
        &self,
        robot: &PosedRobot,
        camera: &Intrinsics,
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
        camera: &Intrinsics,
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
                silhouette_from(robot, &pixels, &points, mask, boundary_step_px)
            })
            .collect()
    }
}

/// Both scores on the GPU where it takes the batch, on the CPU reference otherwise (a
/// distorted camera, which the bit rasteriser's pinhole projection cannot follow; nothing to
/// score; or whatever `band_mismatches_on_gpu` declines).
impl BatchScoring for WgpuRenderer {
    fn disagreement_many(
        &self,
        camera: &Intrinsics,
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
        camera: &Intrinsics,
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
