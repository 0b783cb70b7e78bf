// Draw path with compute: records stay put in a storage buffer; the GPU sort writes the draw order and the indirect
// draw (ceil(visible / QUAD_BATCH) instances of QUAD_BATCH quads, view.wgsl).
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> order: array<u32>;
@group(0) @binding(3) var<uniform> pose_table: PoseTable;

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VsOut {
    let slot = ii * QUAD_BATCH + vi / 4u;
    if slot >= view.count { return culled(); }
    // Past the visible count the last instance reads Gaussians the sort put last: behind the near plane (culled
    // in splat_vertex) or left out by the frame budget (culled here).
    let index = order[slot];
    if skipped(view, index) { return culled(); }
    let s = splats[index];
    let g = place(index, vec3<f32>(s.mx, s.my, s.mz), unpack_shape(s.shape0, s.shape1));
    if !g.present { return culled(); }
    return splat_vertex(g.mean, g.factor, s.rgba, vi % 4u);
}
