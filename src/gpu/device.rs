//! Opening a wgpu device and talking to it: adapter choice, device limits, and the blocking
//! readback every GPU path ends with (where a device failure turns into a CPU fallback).

use std::collections::HashMap;
use std::sync::Mutex;

use super::pipelines::Pipelines;
use super::{AdapterPolicy, AdapterSummary, WgpuRenderer, DEFAULT_MIN_PIXELS};

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

    /// The renderer on an opened device: its limits and every pipeline, compiled once.
    fn build(
        device: wgpu::Device,
        queue: wgpu::Queue,
        adapter: AdapterSummary,
        limits: &wgpu::Limits,
    ) -> WgpuRenderer {
        let pipelines = Pipelines::new(&device);
        WgpuRenderer {
            device,
            queue,
            adapter,
            max_layers: limits.max_texture_array_layers.max(1),
            max_storage_binding: limits.max_storage_buffer_binding_size.max(1),
            pipelines,
            meshes: Mutex::new(HashMap::new()),
            targets: Mutex::new(Vec::new()),
            min_pixels: std::env::var("EASYHEC_GPU_MIN_PIXELS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(DEFAULT_MIN_PIXELS),
            warned: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// Maps `buffer` for reading and waits for the GPU; `None` when the device fails (lost,
    /// out of memory), after which callers redo the work on the CPU.
    pub(super) fn read(&self, buffer: &wgpu::Buffer, size: u64) -> Option<Vec<u8>> {
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
            tracing::warn!(
                "renderer: wgpu on {} failed ({what}); rendering on the CPU instead",
                self.adapter
            );
        }
        None
    }
}
