//! The instanced (WebGL2) path's resident records: the 24-byte `PackedSplat`s live in two integer textures, so a
//! re-sort uploads only the draw order (4 bytes per Gaussian) instead of every record again. Texel `i` (row
//! `i / RECORD_TEX_WIDTH`, column `i % RECORD_TEX_WIDTH`) of `a` (`Rgba32Uint`) holds the mean's f32 bits and the
//! packed colour + opacity, of `b` (`Rg32Uint`) the two shape words: 16 + 8 = 24 bytes, as the storage buffer of
//! the compute path. `shaders/splat_instanced.wgsl` fetches them with `textureLoad`. A third texture (`R32Uint`)
//! holds the draw order (texel k: the record drawn k-th), read by vertex index: 4 bytes per Gaussian.

use splat_format::gaussians::PackedSplat;

/// Texels per row of both record textures (`RECORD_TEX_WIDTH` in `splat_instanced.wgsl`; a test compares them).
/// 2048 is the smallest `max_texture_dimension_2d` wgpu allows, so any adapter takes the width.
pub const RECORD_TEX_WIDTH: u32 = 2048;

pub struct RecordTextures {
    a: wgpu::Texture,
    b: wgpu::Texture,
    order: wgpu::Texture,
    pub view_a: wgpu::TextureView,
    pub view_b: wgpu::TextureView,
    pub view_order: wgpu::TextureView,
    /// Records the textures can hold (whole rows).
    pub capacity: u32,
    staging_a: Vec<[u32; 4]>,
    staging_b: Vec<[u32; 2]>,
}

impl RecordTextures {
    /// Textures for at least `capacity` records, capped at the device's largest 2D texture.
    pub fn new(device: &wgpu::Device, capacity: u32) -> RecordTextures {
        let max_rows = device.limits().max_texture_dimension_2d.max(1);
        let rows = capacity.max(1).div_ceil(RECORD_TEX_WIDTH).min(max_rows);
        let make = |label, format| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d { width: RECORD_TEX_WIDTH, height: rows, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        };
        let a = make("records a (mean, rgba)", wgpu::TextureFormat::Rgba32Uint);
        let b = make("records b (shape)", wgpu::TextureFormat::Rg32Uint);
        let order = make("draw order", wgpu::TextureFormat::R32Uint);
        RecordTextures {
            view_a: a.create_view(&Default::default()),
            view_b: b.create_view(&Default::default()),
            view_order: order.create_view(&Default::default()),
            a,
            b,
            order,
            capacity: rows * RECORD_TEX_WIDTH,
            staging_a: Vec::new(),
            staging_b: Vec::new(),
        }
    }

    /// GPU bytes of the three textures (24 B of record + 4 B of order per Gaussian).
    pub fn bytes(&self) -> u64 {
        self.capacity as u64 * (16 + 8 + 4)
    }

    /// Upload a draw order (record indices, nearest first) into the order texture: whole rows in one copy, then
    /// the partial last row. Returns the number of Gaussians it draws (what fits the capacity).
    pub fn write_order(&self, queue: &wgpu::Queue, order: &[u32]) -> u32 {
        let order = &order[..order.len().min(self.capacity as usize)];
        let w = RECORD_TEX_WIDTH as usize;
        let (rows, rest) = (order.len() / w, order.len() % w);
        for (first_row, texels, width, height) in [(0, &order[..rows * w], w, rows), (rows, &order[rows * w..], rest, 1)] {
            if texels.is_empty() {
                continue;
            }
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &self.order,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: first_row as u32, z: 0 },
                    aspect: wgpu::TextureAspect::All,
                },
                bytemuck::cast_slice(texels),
                wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some((width * 4) as u32), rows_per_image: Some(height as u32) },
                wgpu::Extent3d { width: width as u32, height: height as u32, depth_or_array_layers: 1 },
            );
        }
        order.len() as u32
    }

    /// Upload `records` as records `first..first + records.len()` (what does not fit the capacity is left out):
    /// the partial first row, the whole rows in one copy, the partial last row.
    pub fn write(&mut self, queue: &wgpu::Queue, first: usize, records: &[PackedSplat]) {
        let end = (first + records.len()).min(self.capacity as usize);
        if first >= end {
            return;
        }
        let records = &records[..end - first];
        self.staging_a.clear();
        self.staging_a.extend(records.iter().map(|r| [r.mean[0].to_bits(), r.mean[1].to_bits(), r.mean[2].to_bits(), r.rgba]));
        self.staging_b.clear();
        self.staging_b.extend(records.iter().map(|r| r.shape));
        let w = RECORD_TEX_WIDTH as usize;
        let mut i = first;
        while i < end {
            let (row, col) = (i / w, i % w);
            // A run of texels within one row, or several whole rows at once.
            let (width, rows) = if col == 0 && end - i >= w { (w, (end - i) / w) } else { ((w - col).min(end - i), 1) };
            let n = width * rows;
            let k = i - first;
            let origin = wgpu::Origin3d { x: col as u32, y: row as u32, z: 0 };
            let extent = wgpu::Extent3d { width: width as u32, height: rows as u32, depth_or_array_layers: 1 };
            for (texture, bytes, texel) in [
                (&self.a, bytemuck::cast_slice::<[u32; 4], u8>(&self.staging_a[k..k + n]), 16),
                (&self.b, bytemuck::cast_slice::<[u32; 2], u8>(&self.staging_b[k..k + n]), 8),
            ] {
                queue.write_texture(
                    wgpu::TexelCopyTextureInfo { texture, mip_level: 0, origin, aspect: wgpu::TextureAspect::All },
                    bytes,
                    wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some((width * texel) as u32), rows_per_image: Some(rows as u32) },
                    extent,
                );
            }
            i += n;
        }
    }
}
