// The per-view uniform shared by the splat draw and the sort (mirrors `renderer::ViewUniform`).
struct View {
    // Rows of world_to_camera (rotation in xyz, translation in w).
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    // fx, fy, cx, cy
    intrinsics: vec4<f32>,
    // image width, height; viewport origin in framebuffer pixels
    size: vec2<f32>,
    origin: vec2<f32>,
    // number of Gaussians, sort blocks, flags (bit 0: the spec's full square quads instead of the tight
    // rectangles; a profiling knob, the image is the same), Gaussians in the draw order (instanced path)
    count: u32,
    num_blocks: u32,
    flags: u32,
    drawn: u32,
    // Record indices [skip.x, skip.y) are left out of this view's sort and draw (the frame budget: the static
    // records past the importance-ordered prefix while the camera moves); empty when x >= y.
    skip: vec2<u32>,
    pad: vec2<u32>,
}

// Quads per instance of the splat draw: one indexed instance draws QUAD_BATCH Gaussians (vertices 4 j .. 4 j + 3
// are Gaussian j's corners), so a draw of n Gaussians is ceil(n / QUAD_BATCH) instances (mirrors
// `view::QUAD_BATCH`; the GPU sort writes its indirect draw in these units).
const QUAD_BATCH: u32 = 128u;

fn skipped(v: View, index: u32) -> bool {
    return index >= v.skip.x && index < v.skip.y;
}

// One Gaussian as resident on the GPU: 24 bytes (mirrors `gaussians::PackedSplat`).
struct Splat {
    mx: f32,
    my: f32,
    mz: f32,
    // Shape: log-scales x, y, z as 11-bit unorm over [LOG_SCALE_LO, LOG_SCALE_HI]; rotation as smallest-three
    // (three 9-bit components in [-1/sqrt2, 1/sqrt2], 2-bit index of the dropped largest one, w x y z order).
    // shape0 = lsx | lsy << 11 | qa << 22; shape1 = lsz | qb << 11 | qc << 20 | qi << 29.
    shape0: u32,
    shape1: u32,
    // r g b opacity as unorm8 (r in the low byte)
    rgba: u32,
}

fn camera_z(v: View, m: vec3<f32>) -> f32 {
    return dot(v.row2.xyz, m) + v.row2.w;
}
