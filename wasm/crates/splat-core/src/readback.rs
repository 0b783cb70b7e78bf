//! Reading pixels back: an offscreen RGBA8 target and a mapped-buffer readback that never blocks (poll the device
//! until `try_finish` returns; the browser must yield between polls).

/// An offscreen RGBA8 target that can be read back (tests, the native CLI, `read_pixels` in the browser).
pub struct Offscreen {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub size: [u32; 2],
}

impl Offscreen {
    pub fn new(device: &wgpu::Device, size: [u32; 2]) -> Offscreen {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("offscreen"),
            size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&Default::default());
        Offscreen { texture, view, size }
    }

    /// Copy to a mappable buffer and request the map; `receiver` fires once the device has been polled.
    pub fn start_readback(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Readback {
        let [w, h] = self.size;
        let padded = (w * 4).div_ceil(256) * 256;
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: padded as u64 * h as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo { texture: &self.texture, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded), rows_per_image: Some(h) },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        queue.submit([encoder.finish()]);
        let (tx, rx) = futures_channel::oneshot::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        Readback { buffer, receiver: rx, size: self.size, padded }
    }
}

pub struct Readback {
    buffer: wgpu::Buffer,
    receiver: futures_channel::oneshot::Receiver<Result<(), wgpu::BufferAsyncError>>,
    size: [u32; 2],
    padded: u32,
}

impl Readback {
    /// Tightly packed RGBA8 rows once the map callback has fired (`None` until then; keep polling the device).
    pub fn try_finish(&mut self) -> Option<Result<Vec<u8>, String>> {
        let result = match self.receiver.try_recv() {
            Ok(None) => return None,
            Ok(Some(r)) => r,
            Err(_) => return Some(Err("readback: map request was dropped".into())),
        };
        Some(self.copy_out(result))
    }

    fn copy_out(&self, map_result: Result<(), wgpu::BufferAsyncError>) -> Result<Vec<u8>, String> {
        map_result.map_err(|e| format!("readback map failed: {e}"))?;
        let [w, h] = self.size;
        let data = self.buffer.get_mapped_range(..).map_err(|e| format!("readback range: {e:?}"))?;
        let mut out = Vec::with_capacity((w * h * 4) as usize);
        for row in 0..h as usize {
            let start = row * self.padded as usize;
            out.extend_from_slice(&data[start..start + w as usize * 4]);
        }
        drop(data);
        self.buffer.unmap();
        Ok(out)
    }
}
