//! A minimal .wsplat v1 encoder (one STAT chunk per `static_chunk` Gaussians, one DYNA chunk per frame) with fixed
//! layouts: for the decoder's tests, `splat-render fixture4d` and the fuzz corpus (feature `encode`; the product's
//! encoder is the Python one, `worldsplat.gaussians.wsplat`).

use super::{MAGIC, VERSION};
use crate::camera::{default_rig, mat4_to_json, translation};
use crate::gaussians::Gaussian;
use serde_json::{json, Value};

pub const STATIC_LAYOUT: &[(&str, u32)] = &[
    ("px", 15),
    ("py", 15),
    ("pz", 15),
    ("qi", 2),
    ("qa", 9),
    ("qb", 9),
    ("qc", 9),
    ("sx", 6),
    ("sy", 6),
    ("sz", 6),
    ("o", 8),
    ("r", 8),
    ("g", 8),
    ("b", 8),
];
pub const DYNAMIC_LAYOUT: &[(&str, u32)] = &[("px", 16), ("py", 16), ("pz", 16), ("s", 8), ("o", 6), ("r", 6), ("g", 6), ("b", 6)];

fn chunk(out: &mut Vec<u8>, tag: &[u8; 4], payload: &[u8]) {
    let start = out.len();
    out.extend_from_slice(tag);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    let crc = crc32fast::hash(&out[start..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

fn quantize(v: f64, lo: f64, hi: f64, bits: u32) -> u128 {
    let n = ((1u64 << bits) - 1) as f64;
    let t = if hi > lo { ((v - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.0 };
    (t * n).round() as u128
}

fn records(gs: &[Gaussian], layout: &[(&str, u32)], block_size: usize, out: &mut Vec<u8>) {
    let bytes = layout.iter().map(|l| l.1).sum::<u32>().div_ceil(8) as usize;
    for block in gs.chunks(block_size) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        let (mut llo, mut lhi) = (f32::INFINITY, f32::NEG_INFINITY);
        for g in block {
            for k in 0..3 {
                lo[k] = lo[k].min(g.mean[k]);
                hi[k] = hi[k].max(g.mean[k]);
                llo = llo.min(g.scale[k].ln());
                lhi = lhi.max(g.scale[k].ln());
            }
        }
        for v in lo.iter().chain(&hi).chain([&llo, &lhi]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for g in block {
            let g = g.sanitized().unwrap_or(*g);
            let qi = (0..4).max_by(|&a, &b| g.quat[a].abs().total_cmp(&g.quat[b].abs())).unwrap();
            let sign = if g.quat[qi] < 0.0 { -1.0 } else { 1.0 };
            let small: Vec<f64> = (0..4).filter(|&k| k != qi).map(|k| sign * g.quat[k] as f64 * std::f64::consts::SQRT_2).collect();
            let mut word = 0u128;
            let mut bit = 0;
            for &(f, n) in layout {
                let x = match f {
                    "px" => quantize(g.mean[0] as f64, lo[0] as f64, hi[0] as f64, n),
                    "py" => quantize(g.mean[1] as f64, lo[1] as f64, hi[1] as f64, n),
                    "pz" => quantize(g.mean[2] as f64, lo[2] as f64, hi[2] as f64, n),
                    "qi" => qi as u128,
                    "qa" => quantize(small[0], -1.0, 1.0, n),
                    "qb" => quantize(small[1], -1.0, 1.0, n),
                    "qc" => quantize(small[2], -1.0, 1.0, n),
                    "sx" => quantize((g.scale[0] as f64).ln(), llo as f64, lhi as f64, n),
                    "sy" => quantize((g.scale[1] as f64).ln(), llo as f64, lhi as f64, n),
                    "sz" => quantize((g.scale[2] as f64).ln(), llo as f64, lhi as f64, n),
                    "s" => quantize((g.scale[0] as f64).ln(), llo as f64, lhi as f64, n),
                    "o" => quantize(g.opacity as f64, 0.0, 1.0, n),
                    "r" => quantize(g.color[0] as f64, 0.0, 1.0, n),
                    "g" => quantize(g.color[1] as f64, 0.0, 1.0, n),
                    _ => quantize(g.color[2] as f64, 0.0, 1.0, n),
                };
                word |= x << bit;
                bit += n;
            }
            out.extend_from_slice(&word.to_le_bytes()[..bytes]);
        }
    }
}

/// Encode a scene: statics in chunks of `static_chunk`, `dynamic[f]` as frame f's DYNA chunk (if non-empty).
pub fn encode(statics: &[Gaussian], dynamic: &[Vec<Gaussian>], fps: f64, block_size: usize, static_chunk: usize) -> Vec<u8> {
    let t = dynamic.len().max(1);
    let rig: Vec<Value> = default_rig(160, 90)
        .iter()
        .map(|c| {
            json!({"name": c.name, "width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                         "camera_to_ego": mat4_to_json(&c.camera_to_ego)})
        })
        .collect();
    let ego: Vec<Value> = (0..t).map(|f| mat4_to_json(&translation(f as f64 * 0.5, 0.0, 0.0))).collect();
    let layout = |l: &[(&str, u32)]| json!(l.iter().map(|(f, b)| json!([f, b])).collect::<Vec<_>>());
    let head = json!({
        "format": "wsplat", "version": 1, "scenario_id": "test", "mode": "test", "model_version": "0", "caption": "a test scene",
        "num_static": statics.len(), "num_dynamic": (0..t).map(|f| dynamic.get(f).map_or(0, |d| d.len())).collect::<Vec<_>>(),
        "frame_times": (0..t).map(|f| f as f64 / fps).collect::<Vec<_>>(), "fps": fps,
        "bounds": {"min": [-50.0, -50.0, -5.0], "max": [50.0, 50.0, 20.0]}, "rig": rig, "ego_to_world": ego,
        "block_size": block_size, "static_layout": layout(STATIC_LAYOUT), "dynamic_layout": layout(DYNAMIC_LAYOUT), "sh_degree": 0,
    });
    let mut out = MAGIC.to_vec();
    out.extend_from_slice(&VERSION.to_le_bytes());
    chunk(&mut out, b"HEAD", head.to_string().as_bytes());
    for part in statics.chunks(static_chunk.max(1)) {
        let mut p = (part.len() as u32).to_le_bytes().to_vec();
        records(part, STATIC_LAYOUT, block_size, &mut p);
        chunk(&mut out, b"STAT", &p);
    }
    for (f, d) in dynamic.iter().enumerate() {
        if d.is_empty() {
            continue;
        }
        let mut p = (f as u32).to_le_bytes().to_vec();
        p.extend_from_slice(&(d.len() as u32).to_le_bytes());
        records(d, DYNAMIC_LAYOUT, block_size, &mut p);
        chunk(&mut out, b"DYNA", &p);
    }
    chunk(&mut out, b"END!", &[]);
    out
}
