//! The self-describing bit-packed record layout of a HEAD (`static_layout`, `dynamic_layout`): its fields, their
//! bits, and one record back to a Gaussian.

use super::{err, ErrorKind, WsplatError, MAX_POS_BITS_V2};
use crate::gaussians::Gaussian;
use serde_json::Value;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Field {
    Px,
    Py,
    Pz,
    Qi,
    Qa,
    Qb,
    Qc,
    Qx,
    Qy,
    Qz,
    Sx,
    Sy,
    Sz,
    S,
    O,
    R,
    G,
    B,
}

/// Range of the canonical rotation fields qx qy qz: sin(pi/8) (see `Layout::decode`).
pub const Q_CANON: f64 = 0.38268343236508984;

impl Field {
    pub(super) fn name(self) -> &'static str {
        ["px", "py", "pz", "qi", "qa", "qb", "qc", "qx", "qy", "qz", "sx", "sy", "sz", "s", "o", "r", "g", "b"][self as usize]
    }

    pub(super) fn parse(name: &str) -> Option<Field> {
        Some(match name {
            "px" => Field::Px,
            "py" => Field::Py,
            "pz" => Field::Pz,
            "qi" => Field::Qi,
            "qa" => Field::Qa,
            "qb" => Field::Qb,
            "qc" => Field::Qc,
            "qx" => Field::Qx,
            "qy" => Field::Qy,
            "qz" => Field::Qz,
            "sx" => Field::Sx,
            "sy" => Field::Sy,
            "sz" => Field::Sz,
            "s" => Field::S,
            "o" => Field::O,
            "r" => Field::R,
            "g" => Field::G,
            "b" => Field::B,
            _ => return None,
        })
    }
}

/// A stored integer `x` of `n` bits as a fraction of its range: `x / (2^n - 1)`.
fn unit(x: f64, n: u32) -> f64 {
    x / ((1u64 << n) - 1) as f64
}

/// A self-describing bit-packed record layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    pub(super) fields: Vec<(Field, u32, u32)>, // field, bit offset, bits
    pub record_bytes: usize,
    pub(super) isotropic: bool,
    pub(super) canonical: bool,
}

impl Layout {
    pub(super) fn from_json(v: &Value, what: &str, offset: u64) -> Result<Layout, WsplatError> {
        let bad = |m: String| err::<Layout>(ErrorKind::BadLayout, offset, format!("HEAD.{what}: {m}"));
        let Some(list) = v.as_array() else { return bad("expected a list of [field, bits]".into()) };
        let mut fields = Vec::new();
        let mut bit = 0u32;
        for item in list {
            let pair = item.as_array().filter(|p| p.len() == 2);
            let (Some(name), Some(bits)) = (pair.and_then(|p| p[0].as_str()), pair.and_then(|p| p[1].as_u64())) else {
                return bad(format!("entry {item} is not [field, bits]"));
            };
            let Some(f) = Field::parse(name) else { return bad(format!("unknown field {name:?}")) };
            if !(1..=24).contains(&bits) {
                return bad(format!("field {name}: bits {bits} not in 1..24"));
            }
            if f == Field::Qi && bits != 2 {
                return bad(format!("field qi must have 2 bits, got {bits}"));
            }
            if matches!(f, Field::Qx | Field::Qy | Field::Qz) && bits < 2 {
                return bad(format!("field {name} needs at least 2 bits, got {bits}"));
            }
            if fields.iter().any(|&(g, _, _)| g == f) {
                return bad(format!("field {name} appears twice"));
            }
            fields.push((f, bit, bits as u32));
            bit += bits as u32;
        }
        let has = |f: Field| fields.iter().any(|&(g, _, _)| g == f);
        let all = |fs: &[Field]| fs.iter().all(|&f| has(f));
        let any = |fs: &[Field]| fs.iter().any(|&f| has(f));
        let scales = [Field::Sx, Field::Sy, Field::Sz];
        let three = [Field::Qi, Field::Qa, Field::Qb, Field::Qc];
        let canon = [Field::Qx, Field::Qy, Field::Qz];
        if !all(&[Field::Px, Field::Py, Field::Pz]) {
            return bad("must contain px py pz".into());
        }
        if !all(&[Field::O, Field::R, Field::G, Field::B]) {
            return bad("must contain o r g b".into());
        }
        let isotropic = has(Field::S);
        let canonical = any(&canon);
        if isotropic && (any(&scales) || any(&three) || canonical) {
            return bad("s excludes sx sy sz, qi qa qb qc and qx qy qz".into());
        }
        let one_rotation = (all(&three) && !canonical) || (all(&canon) && !any(&three));
        if !(isotropic || (all(&scales) && one_rotation)) {
            return bad("needs s, or all of sx sy sz with one rotation: all of qi qa qb qc or all of qx qy qz".into());
        }
        let record_bytes = bit.div_ceil(8) as usize;
        if record_bytes > 16 {
            return bad(format!("record size {record_bytes} bytes exceeds 16"));
        }
        Ok(Layout { fields, record_bytes, isotropic, canonical })
    }

    /// v2 stores px py pz as one Morton code: the same bits, at most MAX_POS_BITS_V2.
    pub(super) fn check_v2(self, what: &str, offset: u64) -> Result<Layout, WsplatError> {
        let b = |f: Field| self.fields.iter().find(|x| x.0 == f).map_or(0, |x| x.2);
        if b(Field::Px) != b(Field::Py) || b(Field::Px) != b(Field::Pz) || b(Field::Px) > MAX_POS_BITS_V2 {
            return err(ErrorKind::BadLayout, offset, format!("HEAD.{what}: v2: px py pz need the same bits, at most {MAX_POS_BITS_V2}"));
        }
        Ok(self)
    }

    /// (name, bits) of every field, in layout order.
    pub fn field_bits(&self) -> Vec<(&'static str, u32)> {
        self.fields.iter().map(|&(f, _, b)| (f.name(), b)).collect()
    }

    pub(super) fn pos_bits(&self) -> u32 {
        self.fields.iter().find(|x| x.0 == Field::Px).map_or(0, |x| x.2)
    }

    /// v2's byte planes after the boxes: (label, field index or None for `pos`, byte index).
    pub(super) fn v2_planes(&self) -> Vec<(String, Option<usize>, u32)> {
        let width = |bits: u32| bits.div_ceil(8);
        let label = |name: &str, w: u32, k: u32| if w == 1 { name.to_string() } else { format!("{name}[{k}]") };
        let wp = width(3 * self.pos_bits());
        let mut out: Vec<_> = (0..wp).map(|k| (label("pos", wp, k), None, k)).collect();
        for (i, &(f, _, bits)) in self.fields.iter().enumerate() {
            if matches!(f, Field::Px | Field::Py | Field::Pz) {
                continue;
            }
            let w = width(bits);
            out.extend((0..w).map(|k| (label(f.name(), w, k), Some(i), k)));
        }
        out
    }

    /// v4's SCOL planes: v2's planes of the colour fields r, g, b, in layout order.
    pub(super) fn colour_planes(&self) -> Vec<(String, Option<usize>, u32)> {
        let colour = |i: usize| matches!(self.fields[i].0, Field::R | Field::G | Field::B);
        self.v2_planes().into_iter().filter(|(_, f, _)| f.is_some_and(colour)).collect()
    }

    /// A record's colour from its stored integers (`values`: one per field, in layout order), as `decode` gives it.
    pub(super) fn colour(&self, values: &[u64]) -> [f32; 3] {
        let mut c = [0f32; 3];
        for (&(f, _, n), &x) in self.fields.iter().zip(values) {
            let k = match f {
                Field::R => 0,
                Field::G => 1,
                Field::B => 2,
                _ => continue,
            };
            c[k] = unit(x as f64, n) as f32;
        }
        c
    }

    pub(super) fn decode(&self, rec: &[u8], pos_lo: [f32; 3], pos_hi: [f32; 3], lsc: [f32; 2]) -> Gaussian {
        let mut word = [0u8; 16];
        word[..rec.len()].copy_from_slice(rec);
        let bits = u128::from_le_bytes(word);
        let mut g = Gaussian { quat: [1.0, 0.0, 0.0, 0.0], ..Default::default() };
        let mut small = [0f64; 3];
        let mut qi = 0usize;
        for &(f, off, n) in &self.fields {
            let x = ((bits >> off) & ((1u128 << n) - 1)) as f64;
            let t = unit(x, n);
            let lerp = |lo: f32, hi: f32| (lo as f64 + (hi as f64 - lo as f64) * t) as f32;
            let scale = || (lsc[0] as f64 + (lsc[1] as f64 - lsc[0] as f64) * t).exp() as f32;
            match f {
                Field::Px => g.mean[0] = lerp(pos_lo[0], pos_hi[0]),
                Field::Py => g.mean[1] = lerp(pos_lo[1], pos_hi[1]),
                Field::Pz => g.mean[2] = lerp(pos_lo[2], pos_hi[2]),
                Field::Qi => qi = x as usize,
                Field::Qa => small[0] = (t * 2.0 - 1.0) / std::f64::consts::SQRT_2,
                Field::Qb => small[1] = (t * 2.0 - 1.0) / std::f64::consts::SQRT_2,
                Field::Qc => small[2] = (t * 2.0 - 1.0) / std::f64::consts::SQRT_2,
                // Canonical rotation: m = 2^n - 2 steps (an exact zero), the all-ones code clamps to m.
                Field::Qx | Field::Qy | Field::Qz => {
                    let m = ((1u64 << n) - 2) as f64;
                    let k = match f {
                        Field::Qx => 0,
                        Field::Qy => 1,
                        _ => 2,
                    };
                    small[k] = Q_CANON * (2.0 * x.min(m) / m - 1.0);
                }
                Field::Sx => g.scale[0] = scale(),
                Field::Sy => g.scale[1] = scale(),
                Field::Sz => g.scale[2] = scale(),
                Field::S => g.scale = [scale(); 3],
                Field::O => g.opacity = t as f32,
                Field::R => g.color[0] = t as f32,
                Field::G => g.color[1] = t as f32,
                Field::B => g.color[2] = t as f32,
            }
        }
        if self.canonical {
            let w = (1.0 - small.iter().map(|v| v * v).sum::<f64>()).max(0.0).sqrt();
            g.quat = [w as f32, small[0] as f32, small[1] as f32, small[2] as f32];
        } else if !self.isotropic {
            let big = (1.0 - small.iter().map(|v| v * v).sum::<f64>()).max(0.0).sqrt();
            let mut it = small.iter();
            for k in 0..4 {
                g.quat[k] = if k == qi { big } else { *it.next().unwrap() } as f32;
            }
        }
        g
    }
}
