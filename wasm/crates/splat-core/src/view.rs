//! What one draw of a view needs on the GPU side: the draw path, the per-view uniform (mirrors `struct View` in
//! `shaders/view.wgsl`, shared by the splat draw and the GPU sort) and the view rectangle.

use crate::camera::Camera;
use bytemuck::{Pod, Zeroable};

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
    pub pad: u32,
}

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
            pad: 0,
        }
    }
}

/// One view of a frame: a camera drawn into the viewport at `origin` (its size is the camera's).
#[derive(Clone, Debug)]
pub struct ViewRect {
    pub camera: Camera,
    pub origin: [u32; 2],
}
