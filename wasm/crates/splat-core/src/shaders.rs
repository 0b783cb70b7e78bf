//! The shader registry: every WGSL source the renderer compiles (and the naga test validates), assembled from
//! the files in `shaders/` (constants, the view uniform and the pose table are prepended to each program).

use crate::view::DrawPath;

pub const SHADER_CONSTANTS: &str = include_str!("shaders/constants.wgsl");
pub const SHADER_VIEW: &str = include_str!("shaders/view.wgsl");
pub const SHADER_POSES: &str = include_str!("shaders/poses.wgsl");
pub const SHADER_SPLAT: &str = include_str!("shaders/splat.wgsl");
pub const SHADER_SPLAT_STORAGE: &str = include_str!("shaders/splat_storage.wgsl");
pub const SHADER_SPLAT_INSTANCED: &str = include_str!("shaders/splat_instanced.wgsl");
pub const SHADER_BLIT: &str = include_str!("shaders/blit.wgsl");
pub const SHADER_RADIX_SORT: &str = include_str!("shaders/radix_sort.wgsl");
const ITEMS_LINE: &str = "const ITEMS: u32 = 16u;";

/// Full WGSL source of the splat draw for a path (what the renderer compiles and the naga test validates).
pub fn splat_shader_source(path: DrawPath) -> String {
    let tail = match path {
        DrawPath::Storage => SHADER_SPLAT_STORAGE,
        DrawPath::Instanced => SHADER_SPLAT_INSTANCED,
    };
    [SHADER_CONSTANTS, SHADER_VIEW, SHADER_POSES, SHADER_SPLAT, tail].join("\n")
}

/// The sort shader for `items` keys per thread (the packed 16-bit rank counters hold up to 65535 per block).
pub fn sort_shader_source(items: u32) -> String {
    assert!((1..=255).contains(&items), "items per thread {items} outside 1..=255");
    assert!(SHADER_RADIX_SORT.contains(ITEMS_LINE), "radix_sort.wgsl declares ITEMS as {ITEMS_LINE:?}");
    let sort = SHADER_RADIX_SORT.replacen(ITEMS_LINE, &format!("const ITEMS: u32 = {items}u;"), 1);
    [SHADER_CONSTANTS, SHADER_VIEW, SHADER_POSES, &sort].join("\n")
}
