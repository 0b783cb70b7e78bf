//! Gaussians on the CPU (the spec's inputs), sanitizing (splatting-math.md "Sanitizing") and the 24-byte
//! GPU record `PackedSplat` that `shaders/view.wgsl` mirrors.

use crate::constants::{ALPHA_MIN, LOG_SCALE_HI, LOG_SCALE_LO, QUAT_EPS, SCALE_MAX, SCALE_MIN};
use bytemuck::{Pod, Zeroable};

/// One Gaussian as the spec defines it: mean (m, world), quaternion (w, x, y, z), scale (linear std, m),
/// opacity in [0, 1], colour RGB in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Gaussian {
    pub mean: [f32; 3],
    pub quat: [f32; 4],
    pub scale: [f32; 3],
    pub opacity: f32,
    pub color: [f32; 3],
}

/// The resident GPU record: 24 bytes per Gaussian: f32 mean; the shape as 11-bit log-scales and a smallest-three
/// quaternion with 9-bit components (the shader builds the covariance factor R diag(s) from it, which keeps
/// needle Gaussians exact where an f16 covariance would not); RGBA8 colour + opacity.
/// shape[0] = lsx | lsy << 11 | qa << 22; shape[1] = lsz | qb << 11 | qc << 20 | qi << 29.
/// Mirrors `struct Splat` in `shaders/view.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PackedSplat {
    pub mean: [f32; 3],
    pub shape: [u32; 2],
    pub rgba: u32,
}

pub const PACKED_SPLAT_BYTES: usize = std::mem::size_of::<PackedSplat>();
/// Quantization steps of the shape fields (2^11 - 1 log-scale steps, 2^9 - 1 quaternion steps).
const SCALE_STEPS: f64 = 2047.0;
const QUAT_STEPS: f64 = 511.0;

/// Rotation matrix (row-major) of a unit quaternion (w, x, y, z).
pub fn quat_to_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// Hamilton product a * b of quaternions (w, x, y, z): the rotation b, then a.
pub fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    let [aw, ax, ay, az] = a;
    let [bw, bx, by, bz] = b;
    [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]
}

impl Gaussian {
    /// The spec's sanitizing: `None` if the Gaussian is dropped (non-finite input or opacity < 1/255),
    /// otherwise unit quaternion (identity if |q| < QUAT_EPS), clamped scale, opacity and colour.
    pub fn sanitized(&self) -> Option<Gaussian> {
        let finite = self.mean.iter().chain(&self.quat).chain(&self.scale).chain(&self.color).all(|v| v.is_finite()) && self.opacity.is_finite();
        if !finite {
            return None;
        }
        let opacity = self.opacity.clamp(0.0, 1.0);
        if opacity < ALPHA_MIN {
            return None;
        }
        let n = self.quat.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>().sqrt();
        let quat = if n < QUAT_EPS as f64 { [1.0, 0.0, 0.0, 0.0] } else { self.quat.map(|v| (v as f64 / n) as f32) };
        Some(Gaussian {
            mean: self.mean,
            quat,
            scale: self.scale.map(|s| s.clamp(SCALE_MIN, SCALE_MAX)),
            opacity,
            color: self.color.map(|c| c.clamp(0.0, 1.0)),
        })
    }

    /// World covariance R diag(s^2) R^T (row-major) of an already sanitized Gaussian.
    pub fn covariance(&self) -> [[f64; 3]; 3] {
        let r = quat_to_matrix(self.quat.map(|v| v as f64));
        let s2 = self.scale.map(|s| (s as f64) * (s as f64));
        let mut c = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] = (0..3).map(|k| r[i][k] * s2[k] * r[j][k]).sum();
            }
        }
        c
    }

    /// Sanitize and pack; `None` when the spec drops the Gaussian.
    pub fn pack(&self) -> Option<PackedSplat> {
        let g = self.sanitized()?;
        let span = (LOG_SCALE_HI - LOG_SCALE_LO) as f64;
        let ls = g.scale.map(|v| ((((v as f64).ln() - LOG_SCALE_LO as f64) / span).clamp(0.0, 1.0) * SCALE_STEPS).round() as u32);
        // Smallest-three: drop the largest-magnitude component (made positive), keep the other three in order.
        let qi = (0..4).max_by(|&a, &b| g.quat[a].abs().total_cmp(&g.quat[b].abs())).unwrap();
        let sign = if g.quat[qi] < 0.0 { -1.0 } else { 1.0 };
        let rest: Vec<u32> = (0..4)
            .filter(|&k| k != qi)
            .map(|k| {
                let v = (sign * g.quat[k] as f64 * std::f64::consts::SQRT_2).clamp(-1.0, 1.0);
                (((v + 1.0) / 2.0) * QUAT_STEPS).round() as u32
            })
            .collect();
        Some(PackedSplat {
            mean: g.mean,
            shape: [ls[0] | (ls[1] << 11) | (rest[0] << 22), ls[2] | (rest[1] << 11) | (rest[2] << 20) | ((qi as u32) << 29)],
            rgba: rgb8(g.color) | (unorm8(g.opacity) << 24),
        })
    }
}

/// A value in [0, 1] as 8 bits (clamped).
fn unorm8(v: f32) -> u32 {
    (v * 255.0).round().clamp(0.0, 255.0) as u32
}

/// A colour as the packed record's low 24 bits (R, G, B), clamped to [0, 1] as sanitizing does.
fn rgb8(c: [f32; 3]) -> u32 {
    let c = c.map(|v| unorm8(v.clamp(0.0, 1.0)));
    c[0] | (c[1] << 8) | (c[2] << 16)
}

impl PackedSplat {
    /// The record with a new colour (what `Gaussian::pack` gives the Gaussian with that colour; opacity kept).
    pub fn recoloured(self, color: [f32; 3]) -> PackedSplat {
        PackedSplat { rgba: (self.rgba & 0xff00_0000) | rgb8(color), ..self }
    }

    /// Decode scale and unit quaternion (w, x, y, z) as the shader does.
    pub fn scale_quat(&self) -> ([f32; 3], [f32; 4]) {
        let [s0, s1] = self.shape;
        let span = LOG_SCALE_HI - LOG_SCALE_LO;
        let scale = [s0 & 0x7ff, (s0 >> 11) & 0x7ff, s1 & 0x7ff].map(|x| (x as f32 / SCALE_STEPS as f32 * span + LOG_SCALE_LO).exp());
        let small = [(s0 >> 22) & 0x1ff, (s1 >> 11) & 0x1ff, (s1 >> 20) & 0x1ff]
            .map(|x| (x as f32 / QUAT_STEPS as f32 * 2.0 - 1.0) * std::f32::consts::FRAC_1_SQRT_2);
        let big = (1.0 - small.iter().map(|v| v * v).sum::<f32>()).max(0.0).sqrt();
        let qi = (s1 >> 29) as usize;
        let mut q = [0.0; 4];
        let mut it = small.iter();
        for (k, slot) in q.iter_mut().enumerate() {
            *slot = if k == qi { big } else { *it.next().unwrap() };
        }
        (scale, q)
    }

    /// The covariance the shader renders (R diag(s^2) R^T of the decoded shape).
    pub fn covariance(&self) -> [[f64; 3]; 3] {
        let (scale, quat) = self.scale_quat();
        Gaussian { mean: self.mean, quat, scale, opacity: 1.0, color: [0.0; 3] }.covariance()
    }
    pub fn opacity(&self) -> f32 {
        (self.rgba >> 24) as f32 / 255.0
    }
}

/// Pack a list, dropping what the spec drops. Returns the records and the number dropped.
pub fn pack_all(gs: &[Gaussian]) -> (Vec<PackedSplat>, usize) {
    let out: Vec<PackedSplat> = gs.iter().filter_map(Gaussian::pack).collect();
    let dropped = gs.len() - out.len();
    (out, dropped)
}

fn json_number(v: &serde_json::Value, what: &str) -> Result<f32, String> {
    match v {
        serde_json::Value::Number(n) => Ok(n.as_f64().unwrap_or(f64::NAN) as f32),
        serde_json::Value::String(s) => match s.as_str() {
            "NaN" => Ok(f32::NAN),
            "Infinity" => Ok(f32::INFINITY),
            "-Infinity" => Ok(f32::NEG_INFINITY),
            _ => Err(format!("{what}: expected a number, got string {s:?}")),
        },
        _ => Err(format!("{what}: expected a number")),
    }
}

fn json_rows<const K: usize>(obj: &serde_json::Value, key: &str) -> Result<Vec<[f32; K]>, String> {
    let rows = obj.get(key).and_then(|v| v.as_array()).ok_or_else(|| format!("gaussians: missing list {key}"))?;
    rows.iter()
        .enumerate()
        .map(|(i, row)| {
            let what = format!("gaussians.{key}[{i}]");
            let mut out = [0f32; K];
            match (K, row) {
                (1, r) if !r.is_array() => out[0] = json_number(r, &what)?,
                (_, serde_json::Value::Array(xs)) if xs.len() == K => {
                    for (k, x) in xs.iter().enumerate() {
                        out[k] = json_number(x, &what)?;
                    }
                }
                _ => return Err(format!("{what}: expected {K} numbers")),
            }
            Ok(out)
        })
        .collect()
}

/// Gaussians from the shared raster-vector JSON (`{"means", "quats", "scales", "opacities", "colors"}`); the
/// strings "NaN", "Infinity", "-Infinity" stand for non-finite numbers.
pub fn gaussians_from_json(obj: &serde_json::Value) -> Result<Vec<Gaussian>, String> {
    let means = json_rows::<3>(obj, "means")?;
    let quats = json_rows::<4>(obj, "quats")?;
    let scales = json_rows::<3>(obj, "scales")?;
    let opacities = json_rows::<1>(obj, "opacities")?;
    let colors = json_rows::<3>(obj, "colors")?;
    let n = means.len();
    if [quats.len(), scales.len(), opacities.len(), colors.len()].iter().any(|&l| l != n) {
        return Err(format!("gaussians: lists differ in length (means has {n})"));
    }
    Ok((0..n).map(|i| Gaussian { mean: means[i], quat: quats[i], scale: scales[i], opacity: opacities[i][0], color: colors[i] }).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_is_24_bytes() {
        assert_eq!(PACKED_SPLAT_BYTES, 24);
    }

    #[test]
    fn covariance_round_trips_over_the_whole_scale_range() {
        for &(s, q) in &[
            ([1e-6f32, 1e-6, 1e-6], [1.0f32, 0.0, 0.0, 0.0]),
            ([1e3, 1e3, 1e3], [1.0, 0.0, 0.0, 0.0]),
            ([1e3, 1e-6, 0.5], [0.9, 0.1, -0.3, 0.2]),
            ([0.05, 0.02, 0.3], [0.3, -0.5, 0.7, 0.1]),
        ] {
            let g = Gaussian { mean: [0.0; 3], quat: q, scale: s, opacity: 0.5, color: [0.2; 3] }.sanitized().unwrap();
            let want = g.covariance();
            let got = g.pack().unwrap().covariance();
            let m = want[0][0].max(want[1][1]).max(want[2][2]);
            for i in 0..3 {
                for j in 0..3 {
                    let err = (got[i][j] - want[i][j]).abs() / m;
                    assert!(err < 1e-2, "scale {s:?}: cov[{i}][{j}] {} vs {} (rel {err})", got[i][j], want[i][j]);
                }
            }
        }
    }

    #[test]
    fn sanitizing_follows_the_spec() {
        let base = Gaussian { mean: [1.0, 2.0, 3.0], quat: [0.0; 4], scale: [0.0, 2e3, 1.0], opacity: 2.0, color: [-1.0, 0.5, 9.0] };
        let g = base.sanitized().unwrap();
        assert_eq!(g.quat, [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(g.scale, [SCALE_MIN, SCALE_MAX, 1.0]);
        assert_eq!(g.opacity, 1.0);
        assert_eq!(g.color, [0.0, 0.5, 1.0]);
        assert!(Gaussian { opacity: 0.5 / 255.0, ..base }.sanitized().is_none());
        assert!(Gaussian { mean: [f32::NAN, 0.0, 0.0], ..base }.sanitized().is_none());
        assert!(Gaussian { quat: [f32::INFINITY, 0.0, 0.0, 0.0], ..base }.sanitized().is_none());
    }
}
