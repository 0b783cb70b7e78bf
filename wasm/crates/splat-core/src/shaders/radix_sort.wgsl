// GPU LSD radix sort of the draw order by camera depth (prepended: constants.wgsl, view.wgsl, poses.wgsl).
// Classic reduce-then-scan, 8 passes of 4 bits: histogram per block -> one exclusive scan -> stable scatter.
// No decoupled look-back / onesweep: no workgroup ever waits on another (those hang some GPUs).
// Keys are never stored: every pass recomputes the depth key of an index from the splat buffer, so the sort
// needs one extra u32 per Gaussian (the ping-pong half) beyond the draw order.
// Ties keep input order (stable), so equal depths draw lower indices first, as the spec demands.

const WG: u32 = 256u;
const ITEMS: u32 = 16u;         // consecutive items per thread (the renderer picks it per adapter: gpu_sort::items_per_thread)
const BLOCK: u32 = WG * ITEMS;   // elements per block
const RADIX: u32 = 16u;

struct Pass { shift: u32, p0: u32, p1: u32, p2: u32 }

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read_write> src: array<u32>;
@group(0) @binding(3) var<storage, read_write> dst: array<u32>;
@group(0) @binding(4) var<storage, read_write> hist: array<u32>;
// Indexed indirect draw args: index_count (one instance of QUAD_BATCH quads), instance_count (= ceil(visible /
// QUAD_BATCH)), first_index, base_vertex, first_instance; then the visible count itself.
@group(0) @binding(5) var<storage, read_write> draw_args: array<atomic<u32>, 8>;
@group(0) @binding(6) var<uniform> pass_info: Pass;
@group(0) @binding(7) var<uniform> pose_table: PoseTable;

// Visible depths are positive floats, whose bit patterns order like the values; culled ones (behind the near plane,
// or left out by the frame budget) sort last.
fn depth_key(index: u32) -> u32 {
    if skipped(view, index) { return 0xffffffffu; }
    let s = splats[index];
    let m = placed_mean(index, vec3<f32>(s.mx, s.my, s.mz)); // an object's posed mean (poses.wgsl)
    let z = camera_z(view, m.xyz);
    if m.w != 0.0 && z > NEAR { return bitcast<u32>(z); }
    return 0xffffffffu;
}

@compute @workgroup_size(1)
fn reset_args() {
    atomicStore(&draw_args[0], 6u * QUAD_BATCH);
    for (var i = 1u; i < 8u; i++) { atomicStore(&draw_args[i], 0u); }
}

// src[i] = i and count the visible Gaussians.
@compute @workgroup_size(256)
fn init_order(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * 65535u * WG;
    if i >= view.count { return; }
    src[i] = i;
    if depth_key(i) != 0xffffffffu { atomicAdd(&draw_args[5], 1u); }
}

// The indirect draw's instances: ceil(visible / QUAD_BATCH).
@compute @workgroup_size(1)
fn finish_args() {
    atomicStore(&draw_args[1], (atomicLoad(&draw_args[5]) + QUAD_BATCH - 1u) / QUAD_BATCH);
}

var<workgroup> digit_counts: array<atomic<u32>, 16>;

@compute @workgroup_size(256)
fn histogram(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    if lid < RADIX { atomicStore(&digit_counts[lid], 0u); }
    workgroupBarrier();
    let block = wid.x;
    for (var k = 0u; k < ITEMS; k++) {
        let i = block * BLOCK + lid * ITEMS + k;
        if i < view.count {
            let d = (depth_key(src[i]) >> pass_info.shift) & 15u;
            atomicAdd(&digit_counts[d], 1u);
        }
    }
    workgroupBarrier();
    if lid < RADIX { hist[lid * view.num_blocks + block] = atomicLoad(&digit_counts[lid]); }
}

var<workgroup> scan_sums: array<u32, 256>;

// One workgroup: exclusive scan of hist (digit-major, 16 * num_blocks entries) in place.
@compute @workgroup_size(256)
fn scan(@builtin(local_invocation_index) lid: u32) {
    let n = RADIX * view.num_blocks;
    let chunk = (n + WG - 1u) / WG;
    let begin = min(lid * chunk, n);
    let end = min(begin + chunk, n);
    var total = 0u;
    for (var i = begin; i < end; i++) { total += hist[i]; }
    scan_sums[lid] = total;
    workgroupBarrier();
    for (var off = 1u; off < WG; off = off << 1u) {
        var add = 0u;
        if lid >= off { add = scan_sums[lid - off]; }
        workgroupBarrier();
        scan_sums[lid] += add;
        workgroupBarrier();
    }
    var running = scan_sums[lid] - total; // exclusive prefix of this thread's chunk
    for (var i = begin; i < end; i++) {
        let h = hist[i];
        hist[i] = running;
        running += h;
    }
}

// Per thread: the 16 digit counts of its ITEMS items packed as 16-bit fields in 8 words; scanned across the
// workgroup they give each item's stable rank among equal digits in the block.
var<workgroup> packed_counts: array<u32, 2048>;

@compute @workgroup_size(256)
fn scatter(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let block = wid.x;
    var vals: array<u32, ITEMS>;
    var digits: array<u32, ITEMS>;
    var mine: array<u32, 8>;
    for (var w = 0u; w < 8u; w++) { mine[w] = 0u; }
    for (var k = 0u; k < ITEMS; k++) {
        let i = block * BLOCK + lid * ITEMS + k;
        digits[k] = 0xffffffffu;
        if i < view.count {
            vals[k] = src[i];
            let d = (depth_key(vals[k]) >> pass_info.shift) & 15u;
            digits[k] = d;
            mine[d >> 1u] += 1u << (16u * (d & 1u));
        }
    }
    for (var w = 0u; w < 8u; w++) { packed_counts[lid * 8u + w] = mine[w]; }
    workgroupBarrier();
    // Inclusive Hillis-Steele scan over threads (all fields at once: sums stay below 2^16).
    for (var off = 1u; off < WG; off = off << 1u) {
        var add: array<u32, 8>;
        for (var w = 0u; w < 8u; w++) {
            add[w] = 0u;
            if lid >= off { add[w] = packed_counts[(lid - off) * 8u + w]; }
        }
        workgroupBarrier();
        for (var w = 0u; w < 8u; w++) { packed_counts[lid * 8u + w] += add[w]; }
        workgroupBarrier();
    }
    var seen: array<u32, 8>; // exclusive prefix for this thread, advanced as its items are placed
    for (var w = 0u; w < 8u; w++) { seen[w] = packed_counts[lid * 8u + w] - mine[w]; }
    for (var k = 0u; k < ITEMS; k++) {
        let d = digits[k];
        if d == 0xffffffffu { continue; }
        let word = d >> 1u;
        let sh = 16u * (d & 1u);
        let rank = (seen[word] >> sh) & 0xffffu;
        seen[word] += 1u << sh;
        dst[hist[d * view.num_blocks + block] + rank] = vals[k];
    }
}
