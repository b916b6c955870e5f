//! Headless GPU device for server-side rendering (system paper §3.3: the server renders the same
//! cuts the viewer draws). Picks a hardware adapter when one exists, else a software one (Mesa's
//! lavapipe), logs which, and fails with a typed error when there is none. No surface.

use std::sync::Arc;
use wgpu::{Adapter, AdapterInfo, DeviceType};

/// Which adapter to prefer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AdapterChoice {
    /// A hardware GPU when present, else the software adapter.
    #[default]
    Auto,
    /// Only a software (CPU) adapter, e.g. for reproducible images and benchmarks.
    Software,
    /// Only a hardware GPU.
    Hardware,
}

impl AdapterChoice {
    /// Parses `auto`, `software`/`cpu` or `hardware`/`gpu` (as in `MESHWIKI_RENDER_ADAPTER`).
    pub fn parse(s: &str) -> Option<AdapterChoice> {
        match s.trim().to_ascii_lowercase().as_str() {
            "" | "auto" => Some(AdapterChoice::Auto),
            "software" | "cpu" => Some(AdapterChoice::Software),
            "hardware" | "gpu" => Some(AdapterChoice::Hardware),
            _ => None,
        }
    }
}

/// Why no device could be opened.
#[derive(Debug, Clone, thiserror::Error)]
pub enum DeviceError {
    #[error(
        "no GPU adapter found{0} that can draw from storage buffers and tell primitives apart (primitive_index): install a Vulkan driver (on Linux without a GPU: Mesa's lavapipe, package mesa-vulkan-drivers)"
    )]
    NoAdapter(&'static str),
    #[error("adapter {adapter} lacks what rendering needs: {missing}")]
    Unsupported { adapter: String, missing: String },
    #[error("opening the device on {adapter} failed: {message}")]
    RequestDevice { adapter: String, message: String },
}

/// An open device and its queue, shared by every render.
pub struct GpuDevice {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: AdapterInfo,
    pub limits: wgpu::Limits,
    /// CPU and GPU share memory: buffers are mapped and written in place.
    pub shared_memory: bool,
}

impl std::fmt::Debug for GpuDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuDevice")
            .field("adapter", &self.info.name)
            .field("type", &self.info.device_type)
            .finish()
    }
}

fn rank(info: &AdapterInfo) -> u32 {
    match info.device_type {
        DeviceType::DiscreteGpu => 0,
        DeviceType::IntegratedGpu => 1,
        DeviceType::VirtualGpu => 2,
        DeviceType::Other => 3,
        DeviceType::Cpu => 4,
    }
}

fn is_software(info: &AdapterInfo) -> bool {
    info.device_type == DeviceType::Cpu
}

impl GpuDevice {
    /// Opens the best adapter allowed by `choice` (see [`AdapterChoice`]).
    pub fn new(choice: AdapterChoice) -> Result<Arc<GpuDevice>, DeviceError> {
        // Backends and debug flags may be overridden with wgpu's variables (WGPU_BACKEND, ...).
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let mut adapters: Vec<Adapter> =
            pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()))
                .into_iter()
                .filter(|a| match choice {
                    AdapterChoice::Auto => true,
                    AdapterChoice::Software => is_software(&a.get_info()),
                    AdapterChoice::Hardware => !is_software(&a.get_info()),
                })
                .filter(|a| {
                    let d = a.get_downlevel_capabilities();
                    // The exact id buffer needs each fragment's triangle (primitive_index).
                    d.flags.contains(wgpu::DownlevelFlags::VERTEX_STORAGE)
                        && a.features().contains(wgpu::Features::PRIMITIVE_INDEX)
                })
                .collect();
        adapters.sort_by_key(|a| rank(&a.get_info()));
        for a in adapters.iter() {
            let i = a.get_info();
            tracing::debug!(name = %i.name, kind = ?i.device_type, backend = ?i.backend, "render adapter candidate");
        }
        let adapter = adapters
            .into_iter()
            .next()
            .ok_or(DeviceError::NoAdapter(match choice {
                AdapterChoice::Auto => "",
                AdapterChoice::Software => " (software requested)",
                AdapterChoice::Hardware => " (hardware requested)",
            }))?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        if limits.max_texture_dimension_2d < 2048 || limits.max_storage_buffers_per_shader_stage < 4
        {
            return Err(DeviceError::Unsupported {
                adapter: info.name.clone(),
                missing: "2048-pixel textures and 4 storage buffers per stage".into(),
            });
        }
        // Where CPU and GPU share memory, patch buffers are written in place (no staging copy).
        let shared_memory = matches!(
            info.device_type,
            DeviceType::Cpu | DeviceType::IntegratedGpu
        ) && adapter
            .features()
            .contains(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS);
        let required_features = if shared_memory {
            wgpu::Features::MAPPABLE_PRIMARY_BUFFERS | wgpu::Features::PRIMITIVE_INDEX
        } else {
            wgpu::Features::PRIMITIVE_INDEX
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("meshwiki render"),
            required_features,
            required_limits: limits.clone(),
            memory_hints: wgpu::MemoryHints::MemoryUsage,
            ..Default::default()
        }))
        .map_err(|e| DeviceError::RequestDevice {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;
        // Errors not caught by a render's error scope are logged, never panics.
        device.on_uncaptured_error(Arc::new(|e: wgpu::Error| {
            tracing::error!(error = %e, "uncaptured GPU error");
        }));
        device.set_device_lost_callback(|reason, message| {
            tracing::error!(?reason, %message, "GPU device lost");
        });
        tracing::info!(
            adapter = %info.name,
            kind = ?info.device_type,
            backend = ?info.backend,
            driver = %info.driver,
            software = is_software(&info),
            shared_memory,
            "render device opened"
        );
        Ok(Arc::new(GpuDevice {
            device,
            queue,
            info,
            limits,
            shared_memory,
        }))
    }

    /// Whether this is a software (CPU) adapter.
    pub fn is_software(&self) -> bool {
        is_software(&self.info)
    }

    /// Adapter name, type and backend, for logs and benchmark output.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.device_type, self.info.backend
        )
    }
}
