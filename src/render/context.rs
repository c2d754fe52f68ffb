//! Opening a headless wgpu device: which backend, which adapter, which limits.

use super::RenderError;

/// Disables Mesa's Vulkan device-selection layer (`NODEVICE_SELECT=1`) unless the caller
/// chose a device through it (`MESA_VK_DEVICE_SELECT`) or set the switch themselves. The
/// layer connects to a Wayland display to rank GPUs by the one showing the desktop; on a
/// headless server there is none, and libwayland says so on stderr (`error:
/// XDG_RUNTIME_DIR is invalid or not set in the environment.`, twice per renderer), a
/// line no log collector can parse. wgpu ranks adapters itself (high performance first).
///
/// Call it at the start of `main`, before any thread: it sets an environment variable.
pub fn quiet_headless_vulkan_loader() {
    if std::env::var_os("MESA_VK_DEVICE_SELECT").is_none() && std::env::var_os("NODEVICE_SELECT").is_none() {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}

pub(crate) struct GpuContext {
    // Held so the instance lives exactly as long as the device it opened.
    _instance: wgpu::Instance,
    pub info: wgpu::AdapterInfo,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

impl GpuContext {
    /// Backends from `WGPU_BACKEND` when set (e.g. `vulkan`, `gl`), else Vulkan, then GL.
    pub fn open() -> Result<Self, RenderError> {
        let candidates = match wgpu::Backends::from_env() {
            Some(b) => vec![b],
            None => vec![wgpu::Backends::VULKAN, wgpu::Backends::GL],
        };
        for &backends in &candidates {
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
            desc.backends = backends;
            let instance = wgpu::Instance::new(desc);
            let options = wgpu::RequestAdapterOptions { power_preference: wgpu::PowerPreference::HighPerformance, ..Default::default() };
            match pollster::block_on(instance.request_adapter(&options)) {
                Ok(adapter) => return Self::with_adapter(instance, adapter),
                Err(e) => tracing::debug!("no adapter on {backends:?}: {e}"),
            }
        }
        let tried = candidates.iter().map(|b| format!("{b:?}")).collect::<Vec<_>>().join(", ");
        Err(RenderError::NoAdapter { tried })
    }

    fn with_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter) -> Result<Self, RenderError> {
        let info = adapter.get_info();
        let desc = wgpu::DeviceDescriptor {
            label: Some("b2tf renderer"),
            // The adapter's own limits: large textures and readback buffers are wanted, and
            // the defaults (8192 px) are lower than what most drivers offer.
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) =
            pollster::block_on(adapter.request_device(&desc)).map_err(|e| RenderError::RequestDevice { adapter: format!("{} ({:?})", info.name, info.backend), message: e.to_string() })?;
        tracing::info!("renderer on {} ({:?}, {})", info.name, info.backend, info.driver_info);
        Ok(Self { _instance: instance, info, device, queue })
    }

    /// Runs `work` with validation and out-of-memory errors captured, so that they become
    /// `RenderError::Gpu` instead of wgpu's default panic. Error scopes are per thread, and
    /// `work` runs on this one.
    pub fn catching<R>(&self, work: impl FnOnce() -> R) -> Result<R, RenderError> {
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let r = work();
        let oom = pollster::block_on(oom.pop());
        let validation = pollster::block_on(validation.pop());
        match oom.or(validation) {
            // The description already carries wgpu's "Caused by" chain.
            Some(e) => Err(RenderError::Gpu(e.to_string())),
            None => Ok(r),
        }
    }
}
