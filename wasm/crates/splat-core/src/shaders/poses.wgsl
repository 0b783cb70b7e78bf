// Agent objects posed on the GPU (mirrors `poses::PoseTable`, web/docs/viewer.md): records [first, end) are the
// objects' canonical Gaussians (box frame), object after object; per frame each object's pose box -> scene (the rows
// of [R | t]) and whether it is present. Each draw program declares `pose_table` at its own binding.
const MAX_OBJECTS: u32 = 255u;
const NO_OBJECT: u32 = 0xffffffffu;

struct ObjectPose {
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    // start, end (records counted from `first`), present (1) or absent (0), unused
    range: vec4<u32>,
}

struct PoseTable {
    objects: u32,
    first: u32,
    end: u32,
    pad: u32,
    poses: array<ObjectPose, MAX_OBJECTS>,
}

// The object whose records hold record `index` (the last one starting at or before it), or NO_OBJECT.
fn object_of(index: u32) -> u32 {
    if index < pose_table.first || index >= pose_table.end { return NO_OBJECT; }
    let rel = index - pose_table.first;
    var lo = 0u;
    var hi = pose_table.objects;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if pose_table.poses[mid].range.x <= rel { lo = mid; } else { hi = mid; }
    }
    return lo;
}

fn pose_rotation(o: ObjectPose) -> mat3x3<f32> {
    // Columns of R from the rows of [R | t].
    return mat3x3<f32>(
        vec3<f32>(o.row0.x, o.row1.x, o.row2.x),
        vec3<f32>(o.row0.y, o.row1.y, o.row2.y),
        vec3<f32>(o.row0.z, o.row1.z, o.row2.z));
}

fn pose_translation(o: ObjectPose) -> vec3<f32> {
    return vec3<f32>(o.row0.w, o.row1.w, o.row2.w);
}

// A record in the scene: mean and covariance factor (Sigma = M M^T); an object's posed (R mu + t, R M).
struct Placed {
    mean: vec3<f32>,
    factor: mat3x3<f32>,
    present: bool,
}

fn place(index: u32, mean: vec3<f32>, factor: mat3x3<f32>) -> Placed {
    let k = object_of(index);
    if k == NO_OBJECT { return Placed(mean, factor, true); }
    let o = pose_table.poses[k];
    let r = pose_rotation(o);
    return Placed(r * mean + pose_translation(o), r * factor, o.range.z != 0u);
}

// The mean alone (the sort's depth key); `w` is 0 for a record whose object is absent this frame.
fn placed_mean(index: u32, mean: vec3<f32>) -> vec4<f32> {
    let k = object_of(index);
    if k == NO_OBJECT { return vec4<f32>(mean, 1.0); }
    let o = pose_table.poses[k];
    return vec4<f32>(pose_rotation(o) * mean + pose_translation(o), f32(o.range.z != 0u));
}
