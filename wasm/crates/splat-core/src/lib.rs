//! splat-core: the viewer's platform-independent half. Math constants (`constants`), cameras (`camera`),
//! Gaussians and their 24-byte GPU record (`gaussians`), the .wsplat v1 + v2 progressive decoder (`wsplat`) with the
//! range coder of v2's dynamic records (`dyna_range`), the 3DGS
//! PLY reader (`ply`), scenes (`scene`), the view state behind the Viewer API (`view_state`), the wgpu renderer
//! (`renderer`) with its device setup (`device`), shader registry (`shaders`), per-view uniform (`view`), the
//! WebGL2 path's resident records (`records`), GPU
//! radix sort (`gpu_sort`), CPU sort for WebGL2 (`cpu_sort`), worker-sort protocol (`external_sort`) and
//! readback (`readback`), the splat draw's quad batches (`quads`) and the frame budget (`budget`). Imports go one way: renderer -> the others; none of them imports the renderer.

pub mod budget;
pub mod camera;
pub mod constants;
pub mod cpu_sort;
pub mod device;
pub mod dyna_range;
pub mod external_sort;
pub mod gaussians;
pub mod gpu_sort;
#[cfg(not(target_arch = "wasm32"))]
pub mod headless;
pub mod ply;
pub mod quads;
pub mod readback;
pub mod records;
pub mod renderer;
pub mod scene;
pub mod shaders;
pub mod view;
pub mod view_state;
pub mod wsplat;
