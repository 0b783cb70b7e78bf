//! Native headless rendering (tests, `splat-render`): an adapter from the environment (`WGPU_BACKEND`,
//! `WGPU_ADAPTER_NAME`; with no GPU that is Mesa lavapipe), render views to RGBA8 bytes.

use crate::renderer::{DrawPath, Gpu, Offscreen, RenderStats, Renderer, ViewRect};

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

/// The first `len` u32 of a buffer with COPY_SRC usage (tests inspect the GPU sort's order and draw arguments).
pub fn read_u32s(renderer: &Renderer, buffer: &wgpu::Buffer, len: usize) -> Result<Vec<u32>, String> {
    let bytes = (len.max(1) * 4) as u64;
    let staging = renderer.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("u32 readback"),
        size: bytes,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = renderer.device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes);
    renderer.queue.submit([encoder.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    renderer.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| format!("device poll: {e}"))?;
    rx.recv().map_err(|e| e.to_string())?.map_err(|e| format!("map: {e}"))?;
    let data = staging.get_mapped_range(..).map_err(|e| format!("mapped range: {e:?}"))?;
    let out = bytemuck::cast_slice::<u8, u32>(&data)[..len].to_vec();
    Ok(out)
}
