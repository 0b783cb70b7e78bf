//! Reader for the standard 3DGS PLY vertex layout (binary little-endian): x y z, f_dc_0..2 (SH degree 0),
//! opacity as a logit, scale_0..2 as log, rot_0..3 (w x y z). Colour = 0.5 + SH_C0 * f_dc. Other properties
//! (normals, f_rest_*) are skipped. Errors name the field and its byte offset, as the server's reader
//! (`ply: offset N: FIELD: message`): the header line, `element vertex`, the vertex cut short (`vertex[i]`) or the
//! first non-finite property value (`y[3]`); the vertex count is checked against the bytes present before anything is
//! read, so a huge declared count allocates nothing.

use crate::gaussians::Gaussian;

pub const SH_C0: f32 = 0.282_094_8;

#[derive(Clone, Copy)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Option<Ty> {
        Some(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }
    fn read(self, b: &[u8]) -> f32 {
        match self {
            Ty::I8 => b[0] as i8 as f32,
            Ty::U8 => b[0] as f32,
            Ty::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
            Ty::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
            Ty::I32 => i32::from_le_bytes(b[..4].try_into().unwrap()) as f32,
            Ty::U32 => u32::from_le_bytes(b[..4].try_into().unwrap()) as f32,
            Ty::F32 => f32::from_le_bytes(b[..4].try_into().unwrap()),
            Ty::F64 => f64::from_le_bytes(b[..8].try_into().unwrap()) as f32,
        }
    }
}

pub fn is_ply(bytes: &[u8]) -> bool {
    bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n")
}

/// `ply: offset N: FIELD: message`, the form of the server's reader (FormatError).
fn err(offset: usize, field: &str, msg: impl std::fmt::Display) -> String {
    format!("ply: offset {offset}: {field}: {msg}")
}

pub fn read_ply(bytes: &[u8]) -> Result<Vec<Gaussian>, String> {
    if !is_ply(bytes) {
        return Err(err(0, "header", "missing 'ply' magic line"));
    }
    let end = bytes.windows(11).position(|w| w == b"end_header\n").ok_or_else(|| err(0, "header", "no end_header line"))? + 11;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|e| err(e.valid_up_to(), "header", "not ASCII"))?;
    let mut count: Option<(usize, usize)> = None; // (count, offset of its line)
    let mut props: Vec<(String, Ty)> = Vec::new();
    let mut in_vertex = false;
    let mut at = 0;
    for (n, raw) in header.split('\n').enumerate() {
        let line_at = at;
        at += raw.len() + 1;
        if n == 0 {
            continue;
        }
        let w: Vec<&str> = raw.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] if *f != "binary_little_endian" => {
                return Err(err(line_at, "format", format!("{f} unsupported (binary_little_endian only)")));
            }
            ["element", name, c] => {
                in_vertex = *name == "vertex";
                if in_vertex {
                    count = Some((c.parse().map_err(|_| err(line_at, "element vertex", format!("bad vertex count {c:?}")))?, line_at));
                } else if count.is_none() {
                    return Err(err(line_at, "element", format!("element {name} before vertex is unsupported")));
                }
            }
            ["property", "list", ..] if in_vertex => return Err(err(line_at, "property", "list properties unsupported")),
            ["property", ty, name] if in_vertex => {
                let t = Ty::parse(ty).ok_or_else(|| err(line_at, "property", format!("unknown type {ty}")))?;
                props.push((name.to_string(), t));
            }
            _ => {}
        }
    }
    let (count, count_at) = count.ok_or_else(|| err(0, "element vertex", "no vertex element"))?;
    let stride: usize = props.iter().map(|p| p.1.size()).sum();
    let need = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"];
    let mut at = Vec::new();
    for name in need {
        let mut off = 0;
        let mut found = None;
        for (p, t) in &props {
            if p == name {
                found = Some((off, *t));
            }
            off += t.size();
        }
        at.push(found.ok_or_else(|| err(0, "property", format!("missing vertex property {name}")))?);
    }
    let body = &bytes[end..];
    let want = count.checked_mul(stride).ok_or_else(|| err(count_at, "element vertex", format!("{count} vertices overflow")))?;
    if body.len() < want {
        let whole = body.len() / stride.max(1);
        return Err(err(end + whole * stride, &format!("vertex[{whole}]"), format!("{count} vertices need {want} bytes, file has {}", body.len())));
    }
    for (k, name) in need.iter().enumerate() {
        let (off, ty) = at[k];
        if let Some(i) = (0..count).find(|i| !ty.read(&body[i * stride + off..]).is_finite()) {
            let v = ty.read(&body[i * stride + off..]);
            return Err(err(end + i * stride + off, &format!("{name}[{i}]"), format!("not finite ({v})")));
        }
    }
    let sigmoid = |x: f32| 1.0 / (1.0 + (-x).exp());
    Ok(body[..want]
        .chunks_exact(stride.max(1))
        .map(|v| {
            let f = |k: usize| at[k].1.read(&v[at[k].0..]);
            Gaussian {
                mean: [f(0), f(1), f(2)],
                color: [0.5 + SH_C0 * f(3), 0.5 + SH_C0 * f(4), 0.5 + SH_C0 * f(5)],
                opacity: sigmoid(f(6)),
                scale: [f(7).exp(), f(8).exp(), f(9).exp()],
                quat: [f(10), f(11), f(12), f(13)],
            }
        })
        .collect())
}

/// Write the standard layout (for tests and tools).
pub fn write_ply(gs: &[Gaussian]) -> Vec<u8> {
    let names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"];
    let mut out = format!("ply\nformat binary_little_endian 1.0\nelement vertex {}\n", gs.len());
    for n in names {
        out += &format!("property float {n}\n");
    }
    out += "end_header\n";
    let mut bytes = out.into_bytes();
    for g in gs {
        let o = g.opacity.clamp(1e-6, 1.0 - 1e-6);
        let vals = [
            g.mean[0],
            g.mean[1],
            g.mean[2],
            (g.color[0] - 0.5) / SH_C0,
            (g.color[1] - 0.5) / SH_C0,
            (g.color[2] - 0.5) / SH_C0,
            (o / (1.0 - o)).ln(),
            g.scale[0].ln(),
            g.scale[1].ln(),
            g.scale[2].ln(),
            g.quat[0],
            g.quat[1],
            g.quat[2],
            g.quat[3],
        ];
        for v in vals {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let g = Gaussian { mean: [1.0, -2.0, 3.0], quat: [0.9, 0.1, 0.2, 0.3], scale: [0.1, 0.2, 0.3], opacity: 0.7, color: [0.1, 0.5, 0.9] };
        let back = read_ply(&write_ply(&[g, g])).unwrap();
        assert_eq!(back.len(), 2);
        for (a, b) in back[1].scale.iter().zip(g.scale) {
            assert!((a - b).abs() < 1e-5);
        }
        assert!((back[0].opacity - 0.7).abs() < 1e-5 && (back[0].color[2] - 0.9).abs() < 1e-5);
        let bytes = write_ply(&[g]);
        let cut = read_ply(&bytes[..bytes.len() - 1]).unwrap_err();
        let body_at = bytes.len() - 56;
        assert!(cut.contains("need") && cut.starts_with(&format!("ply: offset {body_at}: vertex[0]:")), "{cut}");
        // a vertex count far beyond the bytes: refused at the body, nothing allocated for it
        let two = write_ply(&[g, g]);
        let head = String::from_utf8_lossy(&two[..two.len() - 112]).replace("element vertex 2", "element vertex 4000000000000");
        let huge = [head.as_bytes(), &two[two.len() - 112..]].concat();
        let huge_at = huge.len(); // after the two whole vertices there
        let e = read_ply(&huge).unwrap_err();
        assert!(e.starts_with(&format!("ply: offset {huge_at}: vertex[2]:")), "{e}");
        // a non-finite value names the property, the vertex and its byte offset (y of vertex 1)
        let mut nan = two.clone();
        let y1 = two.len() - 56 + 4;
        nan[y1..y1 + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        let e = read_ply(&nan).unwrap_err();
        assert!(e.starts_with(&format!("ply: offset {y1}: y[1]: not finite")), "{e}");
        let mut inf = two.clone();
        let s0 = two.len() - 112 + 4 * 7; // scale_0 of vertex 0 (x y z, 3 f_dc, opacity before it)
        inf[s0..s0 + 4].copy_from_slice(&f32::INFINITY.to_le_bytes());
        assert!(read_ply(&inf).unwrap_err().contains("scale_0[0]: not finite"));
        let ascii = String::from_utf8_lossy(&bytes).replace("binary_little_endian", "ascii").into_bytes();
        assert!(read_ply(&ascii).unwrap_err().contains("ascii"));
        let no_op = String::from_utf8_lossy(&bytes[..bytes.len() - 56]).replace("property float opacity\n", "").into_bytes();
        assert!(read_ply(&no_op).unwrap_err().contains("opacity"));
    }
}
