//! splat-format: what the viewer reads, with no GPU in it. The splatting spec's constants (`constants`), Gaussians
//! and their 24-byte GPU record (`gaussians`), poses, the pinhole camera and its JSON, rig cameras (`camera`), the
//! .wsplat v1 + v2 progressive decoder with the range coder of v2's dynamic records (`wsplat`, `wsplat::dyna_range`),
//! the 3DGS PLY reader and writer (`ply`) and the loaded 4D scene (`scene`). The renderer (splat-core), the browser
//! front (splat-web), the native CLI (splat-render) and the fuzz target build on it.

pub mod camera;
pub mod constants;
pub mod gaussians;
pub mod ply;
pub mod scene;
pub mod wsplat;
