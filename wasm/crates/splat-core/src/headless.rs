//! Native headless rendering (tests, `splat-render`): an adapter from the environment (`WGPU_BACKEND`,
//! `WGPU_ADAPTER_NAME`; with no GPU that is Mesa lavapipe), render views to RGBA8 bytes.

use crate::renderer::{DrawPath, Gpu, Offscreen, Renderer, RenderStats, ViewRect};

pub fn adapter() -> Result<wgpu::Adapter, String> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    pollster::block_on(wgpu::util::initialize_adapter_from_env_or_default(&instance, None))
        .map_err(|e| format!("no wgpu adapter (install Mesa lavapipe: mesa-vulkan-drivers): {e}"))
}

/// A device on the default adapter; `path` forces a draw path (None = what the adapter supports).
pub fn gpu(path: Option<DrawPath>) -> Result<Gpu, String> {
    let a = adapter()?;
    let g = pollster::block_on(Gpu::new(&a))?;
    Ok(match path {
        Some(p) => g.with_path(p),
        None => g,
    })
}

/// Render into an offscreen RGBA8 image of `size` and read it back.
pub fn render_rgba(renderer: &mut Renderer, views: &[ViewRect], size: [u32; 2]) -> Result<(Vec<u8>, RenderStats), String> {
    let target = Offscreen::new(&renderer.device, size);
    let stats = renderer.render(views, &target.view, wgpu::TextureFormat::Rgba8Unorm, size)?;
    let mut readback = target.start_readback(&renderer.device, &renderer.queue);
    renderer.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| format!("device poll: {e}"))?;
    let rgba = readback.try_finish().ok_or("readback: map callback did not fire")??;
    Ok((rgba, stats))
}
