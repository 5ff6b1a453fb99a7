//! Adapter and device selection.
//!
//! Every adapter wgpu can see (Vulkan only: the other backends are not compiled in) is ranked:
//! a discrete GPU first, then an integrated one, a virtual one, and last a CPU implementation
//! such as Mesa's lavapipe ("llvmpipe"), so the renderer runs on the rig's GPU and still runs on a
//! machine without one. No adapter at all is a [`DeviceError::NoAdapter`] that says what to
//! install. `ENVLIGHT_ADAPTER=substring` picks the first adapter whose name contains it.
//!
//! Timestamp queries are requested where the adapter has them; the renderer falls back to CPU
//! timing otherwise (see [`super::budget`]). So is blending on `Rgba32Float` targets
//! (`FLOAT32_BLENDABLE`), which draws glTF's blended materials over the HDR frame; without it
//! they are drawn opaque.

use thiserror::Error;

/// Why no device could be made.
#[derive(Debug, Error)]
pub enum DeviceError {
    /// No adapter at all (no GPU driver and no lavapipe).
    #[error(
        "no graphics adapter found (wgpu's Vulkan backend saw none{0}); install a GPU driver, or \
         Mesa's CPU rasteriser lavapipe (Debian: apt-get install mesa-vulkan-drivers libvulkan1)"
    )]
    NoAdapter(String),
    /// The adapter refused to make a device.
    #[error("adapter {adapter:?} cannot create a device: {message}")]
    RequestDevice { adapter: String, message: String },
}

/// A device, its queue and what the renderer needs to know about the adapter.
pub struct Gpu {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    /// Whether GPU timestamp queries are enabled on the device.
    pub timestamps: bool,
    /// Whether `Rgba32Float` targets can be blended (blended materials over the HDR frame).
    pub float32_blendable: bool,
    /// Largest number of layers of the shadow-map array.
    pub max_array_layers: u32,
    /// The first error the device reported outside an error scope (an allocation the GPU could
    /// not make: wgpu's default handler panicked on it), taken by [`Gpu::take_error`].
    errors: std::sync::Arc<std::sync::Mutex<Option<String>>>,
}

impl std::fmt::Debug for Gpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gpu")
            .field("adapter", &self.info.name)
            .field("type", &self.info.device_type)
            .field("backend", &self.info.backend)
            .field("timestamps", &self.timestamps)
            .finish()
    }
}

/// Rank of a device type: lower is preferred (real GPUs before software rasterisers).
pub fn device_type_rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    }
}

impl Gpu {
    /// Opens the preferred adapter (see the module doc).
    pub fn new() -> Result<Self, DeviceError> {
        Self::with_instance(Self::new_instance(), None)
    }

    /// A Vulkan-only wgpu instance.
    pub fn new_instance() -> wgpu::Instance {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::VULKAN;
        wgpu::Instance::new(desc)
    }

    /// Opens the preferred adapter of `instance`; with a `surface`, only adapters that can
    /// present to it are considered.
    pub fn with_instance(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Self, DeviceError> {
        pollster::block_on(Self::new_async(instance, surface))
    }

    async fn new_async(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Self, DeviceError> {
        let mut adapters = instance.enumerate_adapters(wgpu::Backends::VULKAN).await;
        if let Some(s) = surface {
            adapters.retain(|a| a.is_surface_supported(s));
        }
        let wanted = std::env::var("ENVLIGHT_ADAPTER").ok();
        if let Some(w) = &wanted {
            let w = w.to_lowercase();
            adapters.retain(|a| a.get_info().name.to_lowercase().contains(&w));
        }
        adapters.sort_by_key(|a| device_type_rank(a.get_info().device_type));
        let Some(adapter) = adapters.into_iter().next() else {
            return Err(DeviceError::NoAdapter(match wanted {
                Some(w) => format!(" whose name contains {w:?} (ENVLIGHT_ADAPTER)"),
                None => String::new(),
            }));
        };
        let info = adapter.get_info();
        let timestamps = adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let mut required_features = wgpu::Features::empty();
        if timestamps {
            required_features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        let float32_blendable = adapter
            .features()
            .contains(wgpu::Features::FLOAT32_BLENDABLE);
        if float32_blendable {
            required_features |= wgpu::Features::FLOAT32_BLENDABLE;
        }
        let limits = adapter.limits();
        let max_array_layers = limits.max_texture_array_layers;
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("envlight"),
                required_features,
                required_limits: limits,
                ..Default::default()
            })
            .await
            .map_err(|e| DeviceError::RequestDevice {
                adapter: info.name.clone(),
                message: e.to_string(),
            })?;
        let errors = std::sync::Arc::new(std::sync::Mutex::new(None));
        let slot = std::sync::Arc::clone(&errors);
        device.on_uncaptured_error(std::sync::Arc::new(move |error: wgpu::Error| {
            let mut first = slot.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            first.get_or_insert_with(|| error.to_string());
        }));
        Ok(Self {
            instance,
            adapter,
            device,
            queue,
            info,
            timestamps,
            float32_blendable,
            max_array_layers,
            errors,
        })
    }

    /// The first error the device has reported since the last call (an out-of-memory
    /// allocation, a resource too large), if any.
    pub fn take_error(&self) -> Option<String> {
        self.errors
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .take()
    }

    /// "name (type, backend)", for logs and reports.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            self.info.name,
            self.info.device_type,
            self.info.backend,
            self.info.driver,
            self.info.driver_info
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn real_gpus_rank_before_software() {
        let r = device_type_rank;
        assert!(r(wgpu::DeviceType::DiscreteGpu) < r(wgpu::DeviceType::IntegratedGpu));
        assert!(r(wgpu::DeviceType::IntegratedGpu) < r(wgpu::DeviceType::Cpu));
        assert!(r(wgpu::DeviceType::VirtualGpu) < r(wgpu::DeviceType::Cpu));
    }
}
