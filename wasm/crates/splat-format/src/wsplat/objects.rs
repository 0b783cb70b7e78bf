//! v3's object records (web/docs/wsplat-v3.md): an OBJC chunk (one agent's canonical Gaussians in its box frame, v2
//! STAT sections) and a POSE chunk (a run of frames: a present bitmask and a 16-byte pose per present object), the
//! smallest-three rotation code, and baking posed objects into a frame's Gaussians on the CPU.

use super::layout::Layout;
use super::v2::{decode_records_v2, Chunk};
use super::{err, f32_at, u32_at, ErrorKind, WsplatError, BLOCK_HEADER, MAX_RATIO};
use crate::camera::Mat4;
use crate::gaussians::{quat_mul, quat_to_matrix, Gaussian};

pub const OBJC_HEADER: usize = 28;
pub const POSE_HEADER: usize = 12;
pub const POSE_BYTES: usize = 16;

/// One agent object: its canonical Gaussians in its box frame (x forward, y left, z up; origin at the box centre). An
/// OBJC chunk whose index names an object defined before carries more Gaussians of it (appended).
#[derive(Clone, Debug, PartialEq)]
pub struct AgentObject {
    pub index: usize,
    pub agent_id: u32,
    pub cls: u32,
    pub size: [f32; 3],
    pub gaussians: Vec<Gaussian>,
}

/// A rigid pose box -> world: the translation (box centre in world, m) and the unit quaternion (w, x, y, z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub t: [f32; 3],
    pub q: [f64; 4],
}

impl Pose {
    pub fn matrix(&self) -> Mat4 {
        let r = quat_to_matrix(self.q);
        let t = self.t;
        [
            [r[0][0], r[0][1], r[0][2], t[0] as f64],
            [r[1][0], r[1][1], r[1][2], t[1] as f64],
            [r[2][0], r[2][1], r[2][2], t[2] as f64],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }
}

/// A POSE chunk: frames `first ..` with, per frame, every object defined so far: `Some(pose)` where present.
#[derive(Clone, Debug, PartialEq)]
pub struct Poses {
    pub first: usize,
    pub frames: Vec<Vec<Option<Pose>>>,
}

/// The smallest-three code of a unit quaternion (the spec's "rotation code").
pub fn code_quat(code: u32) -> [f64; 4] {
    const M: f64 = std::f64::consts::FRAC_1_SQRT_2;
    let k = (code >> 30) as usize;
    let mut q = [0.0f64; 4];
    let mut sum = 0.0;
    let mut slot = 0;
    for (j, qj) in q.iter_mut().enumerate() {
        if j == k {
            continue;
        }
        let c = ((code >> (10 * (2 - slot))) & 1023) as f64;
        *qj = (2.0 * c / 1023.0 - 1.0) * M;
        sum += *qj * *qj;
        slot += 1;
    }
    q[k] = (1.0 - sum).max(0.0).sqrt();
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    q.map(|x| x / n)
}

/// An OBJC payload. `known`: (agent_id, cls, size) of each object defined before it (an index among them appends
/// Gaussians to that object, the next index defines a new one); `limit`: a whole file's HEAD.num_objects (None:
/// streamed).
pub(super) fn decode_objc(
    payload: &[u8],
    payload_off: u64,
    known: &[(u32, u32, [f32; 3])],
    limit: Option<u64>,
    layout: &Layout,
    block_size: usize,
) -> Result<AgentObject, WsplatError> {
    if payload.len() < OBJC_HEADER {
        return err(ErrorKind::BadPayload, payload_off, format!("OBJC.count: payload shorter than its {OBJC_HEADER}-byte header"));
    }
    let index = u32_at(payload, 0) as usize;
    if index > known.len() {
        return err(ErrorKind::BadPayload, payload_off, format!("OBJC.index: {index}, {} objects defined before it", known.len()));
    }
    if index == known.len() && limit.is_some_and(|n| index as u64 >= n) {
        return err(ErrorKind::CountMismatch, payload_off, format!("OBJC.index: more objects than HEAD.num_objects ({})", limit.unwrap()));
    }
    let size = [f32_at(payload, 12), f32_at(payload, 16), f32_at(payload, 20)];
    if !size.iter().all(|s| s.is_finite() && *s >= 0.0) {
        return err(ErrorKind::BadPayload, payload_off + 12, "OBJC.size: must be finite and >= 0");
    }
    let (agent_id, cls) = (u32_at(payload, 4), u32_at(payload, 8));
    if known.get(index).is_some_and(|k| *k != (agent_id, cls, size)) {
        return err(ErrorKind::BadPayload, payload_off + 4, format!("OBJC.agent_id: object {index}: agent, class or size not the object's"));
    }
    let count = u32_at(payload, 24) as usize;
    let object = |gaussians| AgentObject { index, agent_id, cls, size, gaussians };
    if count == 0 {
        if payload.len() != OBJC_HEADER {
            return err(ErrorKind::BadPayload, payload_off + OBJC_HEADER as u64, "OBJC.length: bytes after an empty object");
        }
        return Ok(object(Vec::new()));
    }
    let raw = count.div_ceil(block_size) as u64 * BLOCK_HEADER as u64 + count as u64 * layout.v2_planes().len() as u64;
    if raw > MAX_RATIO * payload.len() as u64 {
        return err(ErrorKind::BadPayload, payload_off + 24, format!("OBJC.count: {count} records decode to {raw} bytes > {MAX_RATIO} x the chunk"));
    }
    let chunk = Chunk { payload, payload_off, start: 24, count, block_size, layout };
    Ok(object(decode_records_v2(chunk, "OBJC")?))
}

/// A POSE payload: `posed` marks the frames earlier POSE chunks posed (updated); `defined`: the objects so far.
pub(super) fn decode_pose(payload: &[u8], payload_off: u64, posed: &mut [bool], defined: usize) -> Result<Poses, WsplatError> {
    let at = |p: usize| payload_off + p as u64;
    if payload.len() < POSE_HEADER {
        return err(ErrorKind::BadPayload, at(0), format!("POSE.first: payload shorter than its {POSE_HEADER}-byte header"));
    }
    let (first, frames, count) = (u32_at(payload, 0) as usize, u32_at(payload, 4) as usize, u32_at(payload, 8) as usize);
    let t = posed.len();
    if frames < 1 || first.saturating_add(frames) > t {
        return err(ErrorKind::BadPayload, at(4), format!("POSE.frames: {first}+{frames} not in 1..{t}"));
    }
    if let Some(f) = (first..first + frames).find(|&f| posed[f]) {
        return err(ErrorKind::BadPayload, at(0), format!("POSE.first: frame {f} already posed by an earlier POSE chunk"));
    }
    if count != defined {
        return err(ErrorKind::CountMismatch, at(8), format!("POSE.count: {count} objects, {defined} defined so far"));
    }
    let nb = count.div_ceil(8);
    let mut pos = POSE_HEADER;
    let mut out = Vec::with_capacity(frames.min(payload.len()));
    for f in first..first + frames {
        if nb > payload.len() - pos {
            return err(ErrorKind::BadPayload, at(pos), format!("POSE.present: frame {f}: past the chunk's end"));
        }
        let bits = &payload[pos..pos + nb];
        let bit = |i: usize| bits[i / 8] >> (i % 8) & 1 == 1;
        if (count..nb * 8).any(bit) {
            return err(ErrorKind::BadPayload, at(pos), format!("POSE.present: frame {f}: a bit past {count} set"));
        }
        pos += nb;
        let k = (0..count).filter(|&i| bit(i)).count();
        if POSE_BYTES * k > payload.len() - pos {
            return err(ErrorKind::BadPayload, at(pos), format!("POSE.pose: frame {f}: {k} poses past the chunk's end"));
        }
        let mut row = Vec::with_capacity(count);
        for i in 0..count {
            if !bit(i) {
                row.push(None);
                continue;
            }
            let tr = [f32_at(payload, pos), f32_at(payload, pos + 4), f32_at(payload, pos + 8)];
            if !tr.iter().all(|x| x.is_finite()) {
                return err(ErrorKind::BadPayload, at(pos), format!("POSE.pose: frame {f}: translation not finite"));
            }
            row.push(Some(Pose { t: tr, q: code_quat(u32_at(payload, pos + 12)) }));
            pos += POSE_BYTES;
        }
        out.push(row);
    }
    if pos != payload.len() {
        return err(ErrorKind::BadPayload, at(pos), format!("POSE.length: {} bytes after the last frame", payload.len() - pos));
    }
    posed[first..first + frames].iter_mut().for_each(|p| *p = true);
    Ok(Poses { first, frames: out })
}

/// The object's canonical Gaussians posed by `pose` (mean R mu + t, rotation q * q_mu; scale, opacity, colour kept).
pub fn pose_gaussians(gaussians: &[Gaussian], pose: &Pose) -> Vec<Gaussian> {
    let r = quat_to_matrix(pose.q);
    gaussians
        .iter()
        .map(|g| {
            let m = g.mean.map(f64::from);
            let mean = [0, 1, 2].map(|i| (r[i][0] * m[0] + r[i][1] * m[1] + r[i][2] * m[2] + pose.t[i] as f64) as f32);
            let q = quat_mul(pose.q, g.quat.map(f64::from)).map(|x| x as f32);
            Gaussian { mean, quat: q, ..*g }
        })
        .collect()
}
