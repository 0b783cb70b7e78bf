// Draw path with compute: records stay put in a storage buffer; the GPU sort writes the draw order.
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> order: array<u32>;

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VsOut {
    let s = splats[order[ii]];
    return splat_vertex(vec3<f32>(s.mx, s.my, s.mz), s.shape0, s.shape1, s.rgba, vi);
}
