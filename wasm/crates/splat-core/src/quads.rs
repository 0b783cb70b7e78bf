//! The splat draw's index buffer, shared by both draw paths: one instance draws `QUAD_BATCH` Gaussians as quads of
//! 4 vertices (vertex `4 j + corner` is corner `corner` of the instance's Gaussian `j`), each quad the two
//! triangles 0 1 2 and 2 1 3 (the strip order of the spec's square), quads in draw order. Why batches: software
//! rasterizers (SwiftShader, behind Chromium's WebGL2 and WebGPU) set up every instance as a draw of its own, so
//! one instance per Gaussian costs more than the Gaussian; one non-instanced list of 6 vertices per Gaussian runs
//! the vertex shader 6 times where the index buffer shares the corners (4); batches of 128 have neither cost.

use crate::view::QUAD_BATCH;

/// Indices of one instance: `6 * QUAD_BATCH` u16.
pub fn quad_indices() -> Vec<u16> {
    (0..QUAD_BATCH as u16).flat_map(|j| [0, 1, 2, 2, 1, 3].map(|c| 4 * j + c)).collect()
}

/// Indices per instance (the index count of every splat draw).
pub const INDICES_PER_INSTANCE: u32 = 6 * QUAD_BATCH;

/// The index buffer (made once per renderer).
pub fn quad_index_buffer(device: &wgpu::Device) -> wgpu::Buffer {
    let indices = quad_indices();
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("quad indices"),
        size: (indices.len() * 2) as u64,
        usage: wgpu::BufferUsages::INDEX,
        mapped_at_creation: true,
    });
    buffer.get_mapped_range_mut(..).expect("mapped at creation").copy_from_slice(bytemuck::cast_slice(&indices));
    buffer.unmap();
    buffer
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_quad_is_the_strip_of_its_four_corners() {
        let ix = quad_indices();
        assert_eq!(ix.len() as u32, INDICES_PER_INSTANCE);
        assert_eq!(&ix[..12], &[0, 1, 2, 2, 1, 3, 4, 5, 6, 6, 5, 7]);
        assert_eq!(*ix.iter().max().unwrap() as u32, 4 * QUAD_BATCH - 1);
    }
}
