//! splat-core: the viewer's renderer over the formats of splat-format (Gaussians, cameras, the .wsplat decoder, PLY,
//! scenes). The free and BEV cameras (`camera`), the view state behind the Viewer API (`view_state`), the wgpu
//! renderer (`renderer`) with its device setup (`device`), shader registry (`shaders`), per-view uniform (`view`),
//! the WebGL2 path's resident records (`records`), GPU radix sort (`gpu_sort`), CPU sort for WebGL2 (`cpu_sort`),
//! worker-sort protocol (`external_sort`) and readback (`readback`), the splat draw's quad batches (`quads`) and the
//! frame budget (`budget`), the agent objects' pose table (`poses`); `scene_upload` puts a scene's frame on a renderer
//! (objects posed on the GPU or baked on the CPU). Imports go one way: scene_upload -> renderer -> the others; none of
//! them imports the renderer.

pub mod budget;
pub mod camera;
pub mod cpu_sort;
pub mod device;
pub mod external_sort;
pub mod gpu_sort;
#[cfg(not(target_arch = "wasm32"))]
pub mod headless;
pub mod poses;
pub mod quads;
pub mod readback;
pub mod records;
pub mod renderer;
pub mod scene_upload;
pub mod shaders;
pub mod view;
pub mod view_state;
