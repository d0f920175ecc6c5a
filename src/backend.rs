//! The compute backend the solver, initialisation and exploration run on: a renderer that can
//! also score in batches, and the choice of which one opens.
//!
//! Why a module above [`render`](crate::render), [`scoring`](crate::scoring) and the GPU
//! backend: choosing a backend has to know every backend there is (the wgpu one included),
//! while rendering and scoring must not know about their callers or about the GPU. Functions
//! that only render take a `&dyn SilhouetteRenderer`; those that also score (a solve with its
//! posterior refinement, exploration) take a `&dyn Backend`, which coerces to the former.

use std::sync::Arc;

use crate::render::{CpuRenderer, SilhouetteRenderer};

use crate::config::RendererChoice;
use crate::scoring::BatchScoring;

/// Rendering and batched scoring on one device: what a solve or an exploration round needs.
/// Every type with both capabilities is one (a blanket impl), so `&CpuRenderer` and
/// `&WgpuRenderer` pass where a `&dyn Backend` is asked for.
pub trait Backend: SilhouetteRenderer + BatchScoring {}

impl<T: SilhouetteRenderer + BatchScoring> Backend for T {}

/// Whether Linux exposes a GPU: a DRM render node (Mesa, AMD, Intel, virtio) or NVIDIA's
/// proprietary device nodes.
#[cfg(all(feature = "wgpu", target_os = "linux"))]
fn linux_gpu_device_present() -> bool {
    let render_node = std::fs::read_dir("/dev/dri")
        .map(|d| {
            d.flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with("renderD"))
        })
        .unwrap_or(false);
    render_node || std::path::Path::new("/dev/nvidia0").exists()
}

/// Opens the backend `choice` asks for and logs which one (and which adapter) runs, on
/// stderr unless `quiet`. `wgpu` fails when there is no adapter or the `wgpu` feature is off;
/// `auto` falls back to the CPU and says why.
pub fn open_renderer(choice: RendererChoice, quiet: bool) -> Result<Arc<dyn Backend>, String> {
    let log = |m: String| {
        if !quiet {
            tracing::info!("{m}");
        }
    };
    match choice {
        RendererChoice::Cpu => {
            log("renderer: cpu".into());
            Ok(Arc::new(CpuRenderer))
        }
        #[cfg(all(feature = "wgpu", target_os = "linux"))]
        RendererChoice::Auto if !linux_gpu_device_present() => {
            // No GPU device node: only a software adapter could answer, and probing one
            // makes Mesa print display-server noise on headless machines.
            log("renderer: cpu (no GPU device in /dev/dri or /dev/nvidia*)".into());
            Ok(Arc::new(CpuRenderer))
        }
        #[cfg(feature = "wgpu")]
        RendererChoice::Wgpu | RendererChoice::Auto => {
            let policy = if choice == RendererChoice::Wgpu {
                crate::gpu::AdapterPolicy::Any
            } else {
                crate::gpu::AdapterPolicy::HardwareOnly
            };
            match crate::gpu::WgpuRenderer::new(policy) {
                Ok(r) => {
                    log(format!("renderer: wgpu on {}", r.adapter()));
                    Ok(Arc::new(r))
                }
                Err(e) if choice == RendererChoice::Auto => {
                    log(format!("renderer: cpu ({e})"));
                    Ok(Arc::new(CpuRenderer))
                }
                Err(e) => Err(e),
            }
        }
        #[cfg(not(feature = "wgpu"))]
        RendererChoice::Wgpu => {
            Err("the wgpu renderer is not built in: rebuild with --features wgpu".into())
        }
        #[cfg(not(feature = "wgpu"))]
        RendererChoice::Auto => {
            log("renderer: cpu (built without the wgpu feature)".into());
            Ok(Arc::new(CpuRenderer))
        }
    }
}
