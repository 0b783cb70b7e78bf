//! What one draw of a view needs on the GPU side: the draw path, the per-view uniform (mirrors `struct View` in
//! `shaders/view.wgsl`, shared by the splat draw and the GPU sort) and the view rectangle.

use bytemuck::{Pod, Zeroable};
use splat_format::camera::Camera;

/// Most views one `render` call composes (the 6-camera mosaic needs 6).
pub const MAX_VIEWS: usize = 8;
/// Bytes between the views' uniforms in the uniform buffer (the dynamic-offset alignment every adapter accepts).
pub const UNIFORM_STRIDE: u64 = 256;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DrawPath {
    Storage,
    Instanced,
}

/// Mirrors `struct View` in `shaders/view.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct ViewUniform {
    pub row0: [f32; 4],
    pub row1: [f32; 4],
    pub row2: [f32; 4],
    pub intrinsics: [f32; 4],
    pub size: [f32; 2],
    pub origin: [f32; 2],
    pub count: u32,
    pub num_blocks: u32,
    /// Bit 0: draw the spec's full square quads (`Renderer::square_quads`).
    pub flags: u32,
    /// Instanced path: Gaussians in the uploaded draw order (the last instance's spare quads are culled).
    pub drawn: u32,
    /// Record indices `skip[0]..skip[1]` are left out of the sort and the draw (the frame budget).
    pub skip: [u32; 2],
    pub pad: [u32; 2],
}

/// Gaussians per instance of the splat draw (`QUAD_BATCH` in `shaders/view.wgsl`): each instance is an indexed
/// list of `QUAD_BATCH` quads (`quads::QuadIndices`). A few hundred instances instead of one per Gaussian (software
/// rasterizers set up every instance as a draw of its own), 4 vertices per Gaussian (the index buffer shares
/// the corners of its two triangles) instead of the 6 of a plain triangle list.
pub const QUAD_BATCH: u32 = 128;

impl ViewUniform {
    pub fn new(cam: &Camera, origin: [u32; 2], count: u32) -> ViewUniform {
        let m = &cam.world_to_camera;
        let row = |i: usize| [m[i][0] as f32, m[i][1] as f32, m[i][2] as f32, m[i][3] as f32];
        ViewUniform {
            row0: row(0),
            row1: row(1),
            row2: row(2),
            intrinsics: [cam.fx as f32, cam.fy as f32, cam.cx as f32, cam.cy as f32],
            size: [cam.width as f32, cam.height as f32],
            origin: [origin[0] as f32, origin[1] as f32],
            count,
            num_blocks: 0, // set by the renderer for its sort's block size
            flags: 0,
            drawn: 0,
            skip: [0, 0],
            pad: [0, 0],
        }
    }
}

/// One view of a frame: a camera drawn into the viewport at `origin` (its size is the camera's).
#[derive(Clone, Debug)]
pub struct ViewRect {
    pub camera: Camera,
    pub origin: [u32; 2],
}
