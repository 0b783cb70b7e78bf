// Draw path without storage buffers (WebGL2): the records stay resident in two integer textures (records.rs:
// texel i = record i, RECORD_TEX_WIDTH texels per row); per re-sort the CPU uploads only the draw order, one u32
// record index per instance.
const RECORD_TEX_WIDTH: u32 = 2048u;

@group(0) @binding(1) var records_a: texture_2d<u32>; // mean x, y, z (f32 bits), rgba
@group(0) @binding(2) var records_b: texture_2d<u32>; // shape0, shape1

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @location(0) index: u32) -> VsOut {
    let texel = vec2<i32>(i32(index % RECORD_TEX_WIDTH), i32(index / RECORD_TEX_WIDTH));
    let a = textureLoad(records_a, texel, 0);
    let b = textureLoad(records_b, texel, 0);
    return splat_vertex(bitcast<vec3<f32>>(a.xyz), b.x, b.y, a.w, vi);
}
