//! Device setup: request a device with the adapter's own limits and pick the draw path (compute or not) and the
//! accumulation format (blendable `Rgba16Float` where available).

use crate::view::DrawPath;

/// The device and what it can do.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub path: DrawPath,
    pub accum_format: wgpu::TextureFormat,
    /// Keys per thread of the GPU radix sort (`gpu_sort::items_per_thread`).
    pub sort_items: u32,
}

impl Gpu {
    /// Request a device with the adapter's own limits and pick the draw path and accumulation format.
    pub async fn new(adapter: &wgpu::Adapter) -> Result<Gpu, String> {
        let caps = adapter.get_downlevel_capabilities();
        let limits = adapter.limits();
        let compute = caps.flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
            && caps.flags.contains(wgpu::DownlevelFlags::VERTEX_STORAGE)
            && caps.flags.contains(wgpu::DownlevelFlags::INDIRECT_EXECUTION)
            && limits.max_storage_buffers_per_shader_stage >= 5
            && limits.max_compute_workgroup_storage_size >= 8192
            && limits.max_compute_invocations_per_workgroup >= 256;
        let f16 = adapter.get_texture_format_features(wgpu::TextureFormat::Rgba16Float);
        let accum_format = if f16.allowed_usages.contains(wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING)
            && f16.flags.contains(wgpu::TextureFormatFeatureFlags::BLENDABLE)
        {
            wgpu::TextureFormat::Rgba16Float
        } else {
            wgpu::TextureFormat::Rgba8Unorm
        };
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("splat device"),
                required_features: wgpu::Features::empty(),
                required_limits: limits,
                experimental_features: Default::default(),
                memory_hints: wgpu::MemoryHints::Performance,
                trace: Default::default(),
            })
            .await
            .map_err(|e| format!("request_device failed: {e}"))?;
        Ok(Gpu {
            device,
            queue,
            info: adapter.get_info(),
            path: if compute { DrawPath::Storage } else { DrawPath::Instanced },
            accum_format,
            sort_items: crate::gpu_sort::items_per_thread(&adapter.get_info()),
        })
    }

    /// Force the CPU-sorted instanced path (to test it on adapters that have compute).
    pub fn with_path(mut self, path: DrawPath) -> Gpu {
        self.path = path;
        self
    }
}
