// Draw path without storage buffers (WebGL2): the CPU sort uploads the records in draw order.
@vertex
fn vs_main(
    @builtin(vertex_index) vi: u32,
    @location(0) mean: vec3<f32>,
    @location(1) shape: vec2<u32>,
    @location(2) rgba: u32,
) -> VsOut {
    return splat_vertex(mean, shape.x, shape.y, rgba, vi);
}
