// Gaussian splat quads (web/docs/splatting-math.md). Prepended: constants.wgsl, view.wgsl, poses.wgsl. Appended: one of
// splat_storage.wgsl (WebGPU/Vulkan: sorted index into a storage buffer) or splat_instanced.wgsl (WebGL2:
// the records themselves arrive sorted as instance attributes).

@group(0) @binding(0) var<uniform> view: View;

struct VsOut {
    @builtin(position) position: vec4<f32>,
    @location(0) @interpolate(flat) center: vec2<f32>,
    @location(1) @interpolate(flat) conic: vec3<f32>,
    @location(2) @interpolate(flat) color: vec4<f32>,
}

fn unorm8(x: u32, byte: u32) -> f32 {
    return f32((x >> (8u * byte)) & 0xffu) / 255.0;
}

fn culled() -> VsOut {
    var o: VsOut;
    o.position = vec4<f32>(2.0, 2.0, 2.0, 1.0); // outside the clip volume: the quad vanishes
    o.center = vec2<f32>(0.0);
    o.conic = vec3<f32>(0.0);
    o.color = vec4<f32>(0.0);
    return o;
}

// M = R(q) diag(s), the factor of the world covariance (Sigma = M M^T), from the packed shape words.
fn unpack_shape(shape0: u32, shape1: u32) -> mat3x3<f32> {
    let span = LOG_SCALE_HI - LOG_SCALE_LO;
    let s = exp(vec3<f32>(f32(shape0 & 0x7ffu), f32((shape0 >> 11u) & 0x7ffu), f32(shape1 & 0x7ffu)) / 2047.0 * span
        + vec3<f32>(LOG_SCALE_LO));
    let small = (vec3<f32>(f32((shape0 >> 22u) & 0x1ffu), f32((shape1 >> 11u) & 0x1ffu), f32((shape1 >> 20u) & 0x1ffu))
        / 511.0 * 2.0 - 1.0) * 0.70710678;
    let big = sqrt(max(0.0, 1.0 - dot(small, small)));
    let qi = shape1 >> 29u;
    var q = vec4<f32>(big, small);                              // (w, x, y, z) with w largest
    if qi == 1u { q = vec4<f32>(small.x, big, small.y, small.z); }
    if qi == 2u { q = vec4<f32>(small.x, small.y, big, small.z); }
    if qi == 3u { q = vec4<f32>(small.x, small.y, small.z, big); }
    let w = q.x; let x = q.y; let y = q.z; let z = q.w;
    // Columns of R(q) scaled by s.
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)) * s.x,
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)) * s.y,
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)) * s.z);
}

// Project one Gaussian (mean and covariance factor in the scene, `place`) and emit corner `corner` (0..3, triangle
// strip) of its screen-space quad.
fn splat_vertex(mean: vec3<f32>, factor: mat3x3<f32>, rgba: u32, corner: u32) -> VsOut {
    let w = mat3x3<f32>(
        vec3<f32>(view.row0.x, view.row1.x, view.row2.x),
        vec3<f32>(view.row0.y, view.row1.y, view.row2.y),
        vec3<f32>(view.row0.z, view.row1.z, view.row2.z));
    let p = w * mean + vec3<f32>(view.row0.w, view.row1.w, view.row2.w);
    if !(p.z > NEAR) { return culled(); }
    let fx = view.intrinsics.x; let fy = view.intrinsics.y;
    let width = view.size.x; let height = view.size.y;

    let wm = w * factor; // camera-space factor: Sigma_c = wm wm^T
    let lim_x = CLAMP * 0.5 * width / fx;
    let lim_y = CLAMP * 0.5 * height / fy;
    let tx = p.z * clamp(p.x / p.z, -lim_x, lim_x);
    let ty = p.z * clamp(p.y / p.z, -lim_y, lim_y);
    let iz = 1.0 / p.z;
    // Rows of T = J wm (2x3); J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]].
    let j0 = vec3<f32>(fx * iz, 0.0, -fx * tx * iz * iz);
    let j1 = vec3<f32>(0.0, fy * iz, -fy * ty * iz * iz);
    let t0 = j0 * wm;
    let t1 = j1 * wm;
    let a0 = dot(t0, t0);
    let c0 = dot(t1, t1);
    let a = a0 + DILATION;
    let b = dot(t0, t1);
    let c = c0 + DILATION;
    // det(cov2d) by Cauchy-Binet: |t0 x t1|^2 + DILATION (a0 + c0) + DILATION^2; equal to a c - b^2 without its
    // catastrophic cancellation for needle Gaussians (as the reference computes it).
    let cr = cross(t0, t1);
    let det = dot(cr, cr) + DILATION * (a0 + c0) + DILATION * DILATION;
    if !(det > DET_MIN) { return culled(); }
    let mid = 0.5 * (a + c);
    let lambda_max = mid + sqrt(max(EIG_FLOOR, mid * mid - det));
    let radius = min(ceil(EXTENT_SIGMA * sqrt(lambda_max)), RADIUS_MAX);
    let center = vec2<f32>(fx * p.x * iz + view.intrinsics.z, fy * p.y * iz + view.intrinsics.w);
    if center.x + radius < 0.0 || center.x - radius > width || center.y + radius < 0.0 || center.y - radius > height {
        return culled();
    }
    // The quad. The spec's support is the square of half-size `radius`; where the radius is not capped, every
    // pixel the fragment can keep lies in the ellipse {d <= k} with k = min(D_MAX, 2 ln(o / ALPHA_MIN)) (beyond
    // it alpha = o exp(-d/2) < ALPHA_MIN: the spec's skip), and that ellipse lies inside the square. So the quad
    // is the rectangle along the ellipse's axes that holds it (half-widths: the ellipse's support
    // sqrt(k u^T cov2d u) along each axis u, plus a margin for rounding): the same pixels survive, fewer run.
    var axis0 = vec2<f32>(radius, 0.0);
    var axis1 = vec2<f32>(0.0, radius);
    if (view.flags & 1u) == 0u && EXTENT_SIGMA * sqrt(lambda_max) <= RADIUS_MAX {
        let k = min(D_MAX, 2.0 * log(unorm8(rgba, 3u) / ALPHA_MIN) + 1e-3);
        // Major axis of cov2d = [[a, b], [b, c]]: the better conditioned of two eigenvector formulas (any unit
        // direction is correct here, the support makes the rectangle hold the ellipse; the axis only makes it tight).
        let l1 = mid + sqrt(max(0.0, mid * mid - det));
        var e = vec2<f32>(b, l1 - a);
        let e2 = vec2<f32>(l1 - c, b);
        if dot(e2, e2) > dot(e, e) { e = e2; }
        let n2 = dot(e, e);
        e = select(vec2<f32>(1.0, 0.0), e * inverseSqrt(n2), n2 > 0.0);
        let f = vec2<f32>(-e.y, e.x);
        let h0 = sqrt(max(0.0, k * (a * e.x * e.x + 2.0 * b * e.x * e.y + c * e.y * e.y))) + 0.01;
        let h1 = sqrt(max(0.0, k * (a * f.x * f.x + 2.0 * b * f.x * f.y + c * f.y * f.y))) + 0.01;
        axis0 = e * h0;
        axis1 = f * h1;
    }
    let pixel = center + (f32(corner & 1u) * 2.0 - 1.0) * axis0 + (f32(corner >> 1u) * 2.0 - 1.0) * axis1;
    var o: VsOut;
    o.position = vec4<f32>(pixel.x / width * 2.0 - 1.0, 1.0 - pixel.y / height * 2.0, 0.0, 1.0);
    o.center = center;
    o.conic = vec3<f32>(c, -b, a) / det;
    o.color = vec4<f32>(unorm8(rgba, 0u), unorm8(rgba, 1u), unorm8(rgba, 2u), unorm8(rgba, 3u));
    return o;
}

// Premultiplied output; the pipeline blends front to back (src * (1 - dst.a) + dst).
@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    let d = in.position.xy - view.origin - in.center; // position.xy is the pixel centre (i + 0.5, j + 0.5)
    let m = in.conic.x * d.x * d.x + 2.0 * in.conic.y * d.x * d.y + in.conic.z * d.y * d.y;
    if !(m <= D_MAX) { discard; }
    let alpha = min(ALPHA_MAX, in.color.a * exp(-0.5 * m));
    if alpha < ALPHA_MIN { discard; }
    return vec4<f32>(in.color.rgb * alpha, alpha);
}
