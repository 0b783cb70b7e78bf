// Draw path without storage buffers (WebGL2): the records stay resident in two integer textures (records.rs:
// texel i = record i, RECORD_TEX_WIDTH texels per row); per re-sort the CPU uploads only the draw order, one u32
// record index per Gaussian, into a third texture.
const RECORD_TEX_WIDTH: u32 = 2048u;

@group(0) @binding(1) var records_a: texture_2d<u32>; // mean x, y, z (f32 bits), rgba
@group(0) @binding(2) var records_b: texture_2d<u32>; // shape0, shape1
@group(0) @binding(3) var draw_order: texture_2d<u32>; // texel k: the record drawn k-th
@group(0) @binding(4) var<uniform> pose_table: PoseTable;

fn texel_of(i: u32) -> vec2<i32> {
    return vec2<i32>(i32(i % RECORD_TEX_WIDTH), i32(i / RECORD_TEX_WIDTH));
}

// Instance ii draws the Gaussians ii * QUAD_BATCH + j (j < QUAD_BATCH) of the draw order; vertex 4 j + corner is
// corner `corner` of Gaussian j (the index buffer makes the triangles 0 1 2 and 2 1 3 of each quad, as the strip
// of the spec's square).
@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VsOut {
    let slot = ii * QUAD_BATCH + vi / 4u;
    if slot >= view.drawn { return culled(); }
    let index = textureLoad(draw_order, texel_of(slot), 0).x;
    let a = textureLoad(records_a, texel_of(index), 0);
    let b = textureLoad(records_b, texel_of(index), 0);
    let g = place(index, bitcast<vec3<f32>>(a.xyz), unpack_shape(b.x, b.y));
    if !g.present { return culled(); }
    return splat_vertex(g.mean, g.factor, a.w, vi % 4u);
}
