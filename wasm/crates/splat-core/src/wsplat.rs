//! Progressive .wsplat v1 + v2 decoder (web/docs/wsplat-v1.md, web/docs/wsplat-v2.md). Feed bytes as they arrive
//! (`push`); each complete chunk becomes an `Event`. v2 chunks hold zstd-coded byte planes (ruzstd), each
//! decompressed into exactly the size its count implies, after the count was bounded by the chunk's bytes; a v2 file
//! whose HEAD says `dynamic_codec: "range"` holds its DYNA records in one range-coded stream per chunk
//! (`dyna_range`), decoded with models carried from the file's earlier DYNA chunks (so chunks decode in file order,
//! as `push` does). Never reads past the bytes present, buffers only the incomplete chunk, and
//! allocates decoded records only for chunks whose bytes (and CRC) have arrived. Every error names the byte
//! offset and the field, with a kind from the spec's list.

use crate::camera::{mat4_from_json, Mat4, RigCamera};
use crate::dyna_range::{self, StreamError};
use crate::gaussians::Gaussian;
use serde_json::Value;

pub const MAGIC: &[u8; 8] = b"WSPLAT\r\n";
pub const VERSION: u32 = 1;
/// The versions this decoder reads.
pub const VERSIONS: [u32; 2] = [1, 2];
/// A v2 chunk decodes to at most MAX_RATIO x its payload bytes (checked before anything is decompressed).
pub const MAX_RATIO: u64 = 64;
/// v2: px py pz share their bits, at most this many (the Morton code fits 63 bits).
pub const MAX_POS_BITS_V2: u32 = 21;
pub const MAX_CHUNK: u32 = 64 << 20;
pub const MAX_HEAD: u32 = 1 << 20;
pub const MAX_FRAMES: usize = 1024;
const BLOCK_HEADER: usize = 32;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    BadMagic,
    BadVersion,
    Truncated,
    ChunkTooLarge,
    BadCrc,
    BadTag,
    BadOrder,
    BadHeader,
    BadLayout,
    BadPayload,
    CountMismatch,
    TrailingData,
}

impl ErrorKind {
    /// The spec's name (shared vectors use these).
    pub fn name(self) -> &'static str {
        match self {
            ErrorKind::BadMagic => "bad_magic",
            ErrorKind::BadVersion => "bad_version",
            ErrorKind::Truncated => "truncated",
            ErrorKind::ChunkTooLarge => "chunk_too_large",
            ErrorKind::BadCrc => "bad_crc",
            ErrorKind::BadTag => "bad_tag",
            ErrorKind::BadOrder => "bad_order",
            ErrorKind::BadHeader => "bad_header",
            ErrorKind::BadLayout => "bad_layout",
            ErrorKind::BadPayload => "bad_payload",
            ErrorKind::CountMismatch => "count_mismatch",
            ErrorKind::TrailingData => "trailing_data",
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct WsplatError {
    pub kind: ErrorKind,
    pub offset: u64,
    pub message: String,
}

impl std::fmt::Display for WsplatError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "wsplat {} at offset {}: {}", self.kind.name(), self.offset, self.message)
    }
}

impl std::error::Error for WsplatError {}

fn err<T>(kind: ErrorKind, offset: u64, message: impl Into<String>) -> Result<T, WsplatError> {
    Err(WsplatError { kind, offset, message: message.into() })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Field {
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
    fn name(self) -> &'static str {
        ["px", "py", "pz", "qi", "qa", "qb", "qc", "qx", "qy", "qz", "sx", "sy", "sz", "s", "o", "r", "g", "b"][self as usize]
    }

    fn parse(name: &str) -> Option<Field> {
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

/// A self-describing bit-packed record layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    fields: Vec<(Field, u32, u32)>, // field, bit offset, bits
    pub record_bytes: usize,
    isotropic: bool,
    canonical: bool,
}

impl Layout {
    fn from_json(v: &Value, what: &str, offset: u64) -> Result<Layout, WsplatError> {
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
    fn check_v2(self, what: &str, offset: u64) -> Result<Layout, WsplatError> {
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

    fn pos_bits(&self) -> u32 {
        self.fields.iter().find(|x| x.0 == Field::Px).map_or(0, |x| x.2)
    }

    /// v2's byte planes after the boxes: (label, field index or None for `pos`, byte index).
    fn v2_planes(&self) -> Vec<(String, Option<usize>, u32)> {
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

    fn decode(&self, rec: &[u8], pos_lo: [f32; 3], pos_hi: [f32; 3], lsc: [f32; 2]) -> Gaussian {
        let mut word = [0u8; 16];
        word[..rec.len()].copy_from_slice(rec);
        let bits = u128::from_le_bytes(word);
        let mut g = Gaussian { quat: [1.0, 0.0, 0.0, 0.0], ..Default::default() };
        let mut small = [0f64; 3];
        let mut qi = 0usize;
        for &(f, off, n) in &self.fields {
            let x = ((bits >> off) & ((1u128 << n) - 1)) as f64;
            let t = x / ((1u64 << n) - 1) as f64;
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

/// How a v2 file's DYNA chunks are coded (HEAD `dynamic_codec`; absent: zstd, as its STAT chunks).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DynamicCodec {
    Zstd,
    /// One range-coded stream per chunk, models carried from chunk to chunk (`dyna_range`).
    Range,
}

/// The HEAD chunk.
#[derive(Clone, Debug)]
pub struct Header {
    pub scenario_id: String,
    pub mode: String,
    pub model_version: String,
    pub caption: String,
    /// Totals: from HEAD, or (a streamed file) 0 until its END! arrives with them.
    pub num_static: u64,
    pub num_dynamic: Vec<u64>,
    /// A streamed file (HEAD `num_static`, `num_dynamic`, `bounds` null): totals and bounds come in END!, and STAT
    /// may follow DYNA (web/docs/wsplat-v1.md, "Streamed files").
    pub streamed: bool,
    pub frame_times: Vec<f64>,
    pub fps: f64,
    pub bounds_min: [f64; 3],
    pub bounds_max: [f64; 3],
    pub rig: Vec<RigCamera>,
    pub ego_to_world: Vec<Mat4>,
    pub block_size: usize,
    pub static_layout: Layout,
    pub dynamic_layout: Layout,
    /// The file's version (1 or 2).
    pub version: u32,
    /// v2: the codec of the DYNA chunks (v1: Zstd, which stands for its bit-packed records).
    pub dynamic_codec: DynamicCodec,
}

impl Header {
    fn from_json(v: &Value, offset: u64, version: u32) -> Result<Header, WsplatError> {
        let bad = |m: String| WsplatError { kind: ErrorKind::BadHeader, offset, message: format!("HEAD.{m}") };
        if !v.is_object() {
            return Err(bad("payload is not a JSON object".into()));
        }
        let get = |k: &str| v.get(k).ok_or_else(|| bad(format!("{k}: missing")));
        let string = |k: &str| get(k)?.as_str().map(str::to_string).ok_or_else(|| bad(format!("{k}: expected a string")));
        let uint = |k: &str| get(k)?.as_u64().ok_or_else(|| bad(format!("{k}: expected an integer >= 0")));
        let num = |k: &str, x: &Value| x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| bad(format!("{k}: expected finite numbers")));
        if get("format")?.as_str() != Some("wsplat") {
            return Err(bad("format: must be \"wsplat\"".into()));
        }
        if get("version")?.as_u64() != Some(version as u64) {
            return Err(bad(format!("version: must be {version} (the file's version)")));
        }
        if version == 2 && v.get("codec").and_then(Value::as_str) != Some("zstd") {
            return Err(bad("codec: must be \"zstd\"".into()));
        }
        let dynamic_codec = match (version, v.get("dynamic_codec")) {
            (1, _) | (_, None) => DynamicCodec::Zstd,
            (_, Some(c)) if c.as_str() == Some("zstd") => DynamicCodec::Zstd,
            (_, Some(c)) if c.as_str() == Some("range") => DynamicCodec::Range,
            _ => return Err(bad("dynamic_codec: must be \"zstd\" or \"range\" (absent: zstd)".into())),
        };
        let frame_times: Vec<f64> = get("frame_times")?
            .as_array()
            .ok_or_else(|| bad("frame_times: expected a list".into()))?
            .iter()
            .map(|x| num("frame_times", x))
            .collect::<Result<_, _>>()?;
        let t = frame_times.len();
        if !(1..=MAX_FRAMES).contains(&t) {
            return Err(bad(format!("frame_times: length {t} not in 1..{MAX_FRAMES}")));
        }
        if frame_times.windows(2).any(|w| w[1] < w[0]) {
            return Err(bad("frame_times: must be non-decreasing".into()));
        }
        let streamed = v.get("num_static").is_some_and(Value::is_null);
        let totals = if streamed {
            for k in ["num_dynamic", "bounds"] {
                if !get(k)?.is_null() {
                    return Err(bad(format!("{k}: must be null in a streamed file (num_static is null)")));
                }
            }
            Totals { num_static: 0, num_dynamic: vec![0; t], bounds_min: [0.0; 3], bounds_max: [0.0; 3] }
        } else {
            Totals::from_json(v, t).map_err(&bad)?
        };
        let fps = num("fps", get("fps")?)?;
        if fps <= 0.0 {
            return Err(bad("fps: must be > 0".into()));
        }
        let rig = get("rig")?
            .as_array()
            .ok_or_else(|| bad("rig: expected a list".into()))?
            .iter()
            .enumerate()
            .map(|(i, c)| RigCamera::from_json(c, &format!("rig[{i}]")).map_err(&bad))
            .collect::<Result<Vec<_>, _>>()?;
        let ego_to_world = get("ego_to_world")?
            .as_array()
            .ok_or_else(|| bad("ego_to_world: expected a list".into()))?
            .iter()
            .map(|m| mat4_from_json(m, "ego_to_world").map_err(&bad))
            .collect::<Result<Vec<_>, _>>()?;
        if ego_to_world.len() != t {
            return Err(bad(format!("ego_to_world: length {} != {t} frames", ego_to_world.len())));
        }
        let block_size = uint("block_size")?;
        if !(1..=65536).contains(&block_size) {
            return Err(bad(format!("block_size: {block_size} not in 1..65536")));
        }
        if get("sh_degree")?.as_u64() != Some(0) {
            return Err(bad("sh_degree: must be 0".into()));
        }
        let mut static_layout = Layout::from_json(get("static_layout")?, "static_layout", offset)?;
        let mut dynamic_layout = Layout::from_json(get("dynamic_layout")?, "dynamic_layout", offset)?;
        if version == 2 {
            static_layout = static_layout.check_v2("static_layout", offset)?;
            dynamic_layout = dynamic_layout.check_v2("dynamic_layout", offset)?;
        }
        Ok(Header {
            scenario_id: string("scenario_id")?,
            mode: string("mode")?,
            model_version: string("model_version")?,
            caption: string("caption")?,
            num_static: totals.num_static,
            num_dynamic: totals.num_dynamic,
            streamed,
            frame_times,
            fps,
            bounds_min: totals.bounds_min,
            bounds_max: totals.bounds_max,
            rig,
            ego_to_world,
            block_size: block_size as usize,
            static_layout,
            dynamic_layout,
            version,
            dynamic_codec,
        })
    }
}

/// num_static, num_dynamic[T] and bounds: of a HEAD, or of a streamed file's END!.
struct Totals {
    num_static: u64,
    num_dynamic: Vec<u64>,
    bounds_min: [f64; 3],
    bounds_max: [f64; 3],
}

impl Totals {
    /// Errors are "field: message".
    fn from_json(v: &Value, t: usize) -> Result<Totals, String> {
        let num_static = v.get("num_static").and_then(Value::as_u64).ok_or("num_static: expected an integer >= 0")?;
        let num_dynamic: Vec<u64> = v
            .get("num_dynamic")
            .and_then(Value::as_array)
            .ok_or("num_dynamic: expected a list")?
            .iter()
            .map(|x| x.as_u64().ok_or("num_dynamic: expected integers >= 0"))
            .collect::<Result<_, _>>()?;
        if num_dynamic.len() != t {
            return Err(format!("num_dynamic: length {} != {t} frames", num_dynamic.len()));
        }
        let vec3 = |k: &str| -> Result<[f64; 3], String> {
            let a = v.get("bounds").and_then(|b| b.get(k)).and_then(Value::as_array).filter(|a| a.len() == 3);
            let a = a.ok_or_else(|| format!("bounds.{k}: expected 3 numbers"))?;
            let n = |x: &Value| x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| format!("bounds.{k}: expected finite numbers"));
            Ok([n(&a[0])?, n(&a[1])?, n(&a[2])?])
        };
        Ok(Totals { num_static, num_dynamic, bounds_min: vec3("min")?, bounds_max: vec3("max")? })
    }
}

/// What a complete chunk yields.
#[derive(Debug)]
pub enum Event {
    Header(Box<Header>),
    Static(Vec<Gaussian>),
    Dynamic { frame: usize, gaussians: Vec<Gaussian> },
    End,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    Magic,
    Head,
    Static,
    Dynamic,
    /// after the HEAD of a streamed file: STAT, DYNA or END!
    Stream,
    Done,
}

/// Progress so far (bytes consumed, Gaussians decoded).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Progress {
    pub bytes: u64,
    pub static_decoded: u64,
    pub static_total: u64,
    pub dynamic_decoded: u64,
    pub dynamic_total: u64,
    pub done: bool,
}

pub struct Decoder {
    pending: Vec<u8>,
    base: u64, // absolute offset of pending[0]
    stage: Stage,
    header: Option<Header>,
    static_count: u64,
    dynamic_counts: Vec<u64>,
    failed: Option<WsplatError>,
    version: u32,
    /// A range-coded file's models, carried from one DYNA chunk to the next (created with its HEAD).
    models: Option<dyna_range::Models>,
}

impl Default for Decoder {
    fn default() -> Self {
        Decoder::new()
    }
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

impl Decoder {
    pub fn new() -> Decoder {
        Decoder {
            pending: Vec::new(),
            base: 0,
            stage: Stage::Magic,
            header: None,
            static_count: 0,
            dynamic_counts: Vec::new(),
            failed: None,
            version: 0,
            models: None,
        }
    }

    pub fn header(&self) -> Option<&Header> {
        self.header.as_ref()
    }

    pub fn progress(&self) -> Progress {
        let h = self.header.as_ref();
        Progress {
            bytes: self.base,
            static_decoded: self.static_count,
            static_total: h.map_or(0, |h| h.num_static),
            dynamic_decoded: self.dynamic_counts.iter().sum(),
            dynamic_total: h.map_or(0, |h| h.num_dynamic.iter().sum()),
            done: self.stage == Stage::Done,
        }
    }

    /// Append bytes and decode every chunk they complete. After an error the decoder stays failed.
    pub fn push(&mut self, bytes: &[u8]) -> Result<Vec<Event>, WsplatError> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        let result = self.push_inner(bytes);
        if let Err(e) = &result {
            self.failed = Some(e.clone());
            self.pending = Vec::new();
        }
        result
    }

    /// The stream ended: an error if it stopped before `END!`.
    pub fn finish(&mut self) -> Result<(), WsplatError> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        if self.stage != Stage::Done {
            let e = WsplatError {
                kind: ErrorKind::Truncated,
                offset: self.base,
                message: format!("stream ended {} bytes into an incomplete {}", self.pending.len(), self.expecting()),
            };
            self.failed = Some(e.clone());
            return Err(e);
        }
        Ok(())
    }

    fn expecting(&self) -> &'static str {
        match self.stage {
            Stage::Magic => "file header (magic + version)",
            Stage::Head => "HEAD chunk",
            Stage::Static | Stage::Dynamic | Stage::Stream => "chunk (no END! yet)",
            Stage::Done => "nothing",
        }
    }

    fn push_inner(&mut self, bytes: &[u8]) -> Result<Vec<Event>, WsplatError> {
        if self.stage == Stage::Done {
            if bytes.is_empty() {
                return Ok(Vec::new());
            }
            return err(ErrorKind::TrailingData, self.base, format!("{} bytes after END!", bytes.len()));
        }
        self.pending.extend_from_slice(bytes);
        let mut events = Vec::new();
        let mut at = 0usize;
        loop {
            let avail = &self.pending[at..];
            let off = self.base + at as u64;
            if self.stage == Stage::Magic {
                let n = avail.len().min(8);
                if avail[..n] != MAGIC[..n] {
                    return err(ErrorKind::BadMagic, 0, "magic: not a .wsplat file (expected \"WSPLAT\\r\\n\")");
                }
                if avail.len() < 12 {
                    break;
                }
                let version = u32_at(avail, 8);
                if !VERSIONS.contains(&version) {
                    return err(ErrorKind::BadVersion, 8, format!("version: {version}, this decoder reads {VERSIONS:?}"));
                }
                self.version = version;
                at += 12;
                self.stage = Stage::Head;
                continue;
            }
            if self.stage == Stage::Done {
                if !avail.is_empty() {
                    return err(ErrorKind::TrailingData, off, format!("{} bytes after END!", avail.len()));
                }
                break;
            }
            if avail.len() < 8 {
                // Validate a partial tag early so garbage fails fast.
                break;
            }
            let tag: [u8; 4] = avail[..4].try_into().unwrap();
            let len = u32_at(avail, 4);
            if !matches!(&tag, b"HEAD" | b"STAT" | b"DYNA" | b"END!") {
                return err(ErrorKind::BadTag, off, format!("chunk tag: {:?} is not HEAD, STAT, DYNA or END!", String::from_utf8_lossy(&tag)));
            }
            if len > MAX_CHUNK {
                return err(ErrorKind::ChunkTooLarge, off + 4, format!("chunk length: {len} bytes exceeds {MAX_CHUNK}"));
            }
            let total = 12 + len as usize;
            if avail.len() < total {
                break; // wait for the rest of the chunk (buffered, proportional to bytes present)
            }
            let payload = &avail[8..8 + len as usize];
            let crc = u32_at(avail, 8 + len as usize);
            let mut hasher = crc32fast::Hasher::new();
            hasher.update(&avail[..8 + len as usize]);
            let want = hasher.finalize();
            if crc != want {
                return err(ErrorKind::BadCrc, off + 8 + len as u64, format!("chunk crc: stored {crc:#010x}, computed {want:#010x}"));
            }
            let payload_off = off + 8;
            match (&tag, self.stage) {
                (b"HEAD", Stage::Head) => {
                    if len > MAX_HEAD {
                        return err(ErrorKind::BadHeader, off + 4, format!("HEAD length: {len} bytes exceeds {MAX_HEAD}"));
                    }
                    let v: Value = serde_json::from_slice(payload).map_err(|e| WsplatError {
                        kind: ErrorKind::BadHeader,
                        offset: payload_off,
                        message: format!("HEAD: invalid JSON: {e}"),
                    })?;
                    let h = Header::from_json(&v, payload_off, self.version)?;
                    self.dynamic_counts = vec![0; h.frame_times.len()];
                    if h.dynamic_codec == DynamicCodec::Range {
                        self.models = Some(dyna_range::Models::new(&h.dynamic_layout.field_bits()));
                    }
                    self.stage = if h.streamed { Stage::Stream } else { Stage::Static };
                    self.header = Some(h.clone());
                    events.push(Event::Header(Box::new(h)));
                }
                (b"STAT", Stage::Static | Stage::Stream) => {
                    let h = self.header.as_ref().unwrap();
                    let (gs, _) = decode_records(payload, payload_off, 0, h.block_size, &h.static_layout, h.version, None)?;
                    self.static_count += gs.len() as u64;
                    if !h.streamed && self.static_count > h.num_static {
                        return err(
                            ErrorKind::CountMismatch,
                            payload_off,
                            format!("STAT count: {} static Gaussians exceed HEAD.num_static {}", self.static_count, h.num_static),
                        );
                    }
                    events.push(Event::Static(gs));
                }
                (b"DYNA", Stage::Static | Stage::Dynamic | Stage::Stream) => {
                    let h = self.header.as_ref().unwrap();
                    if payload.len() < 4 {
                        return err(ErrorKind::BadPayload, payload_off, "DYNA frame: payload shorter than 4 bytes");
                    }
                    let frame = u32_at(payload, 0) as usize;
                    if frame >= h.frame_times.len() {
                        return err(ErrorKind::BadPayload, payload_off, format!("DYNA frame: {frame} >= {} frames", h.frame_times.len()));
                    }
                    let (gs, _) = decode_records(payload, payload_off, 4, h.block_size, &h.dynamic_layout, h.version, self.models.as_mut())?;
                    self.dynamic_counts[frame] += gs.len() as u64;
                    if !h.streamed && self.dynamic_counts[frame] > h.num_dynamic[frame] {
                        return err(
                            ErrorKind::CountMismatch,
                            payload_off + 4,
                            format!("DYNA count: frame {frame} exceeds HEAD.num_dynamic[{frame}] = {}", h.num_dynamic[frame]),
                        );
                    }
                    if !h.streamed {
                        self.stage = Stage::Dynamic;
                    }
                    events.push(Event::Dynamic { frame, gaussians: gs });
                }
                (b"END!", Stage::Static | Stage::Dynamic | Stage::Stream) => {
                    let h = self.header.as_mut().unwrap();
                    let src = if h.streamed { "END!" } else { "HEAD" };
                    if h.streamed {
                        // the totals and bounds of a streamed file: JSON in END!, checked against the chunks below
                        if len > MAX_HEAD {
                            return err(ErrorKind::BadPayload, payload_off, format!("END! length: {len} bytes exceeds {MAX_HEAD}"));
                        }
                        let bad = |m: String| WsplatError { kind: ErrorKind::BadPayload, offset: payload_off, message: format!("END!: {m}") };
                        let v: Value = serde_json::from_slice(payload).map_err(|e| bad(format!("a streamed file's totals: invalid JSON: {e}")))?;
                        if !v.is_object() {
                            return Err(bad("not a JSON object".into()));
                        }
                        let t = Totals::from_json(&v, h.frame_times.len()).map_err(bad)?;
                        (h.num_static, h.num_dynamic, h.bounds_min, h.bounds_max) = (t.num_static, t.num_dynamic, t.bounds_min, t.bounds_max);
                    } else if len != 0 {
                        return err(ErrorKind::BadPayload, payload_off, format!("END! payload: {len} bytes, must be empty"));
                    }
                    if self.static_count != h.num_static {
                        return err(
                            ErrorKind::CountMismatch,
                            off,
                            format!("END!: {} static Gaussians, {src}.num_static says {}", self.static_count, h.num_static),
                        );
                    }
                    if let Some(f) = (0..h.num_dynamic.len()).find(|&f| self.dynamic_counts[f] != h.num_dynamic[f]) {
                        return err(
                            ErrorKind::CountMismatch,
                            off,
                            format!(
                                "END!: frame {f} has {} dynamic Gaussians, {src}.num_dynamic[{f}] says {}",
                                self.dynamic_counts[f], h.num_dynamic[f]
                            ),
                        );
                    }
                    self.stage = Stage::Done;
                    events.push(Event::End);
                }
                _ => {
                    return err(
                        ErrorKind::BadOrder,
                        off,
                        format!(
                            "chunk order: {} not allowed {}",
                            String::from_utf8_lossy(&tag),
                            match self.stage {
                                Stage::Head => "before HEAD",
                                Stage::Static => "here (after HEAD/STAT)",
                                Stage::Dynamic => "after DYNA",
                                Stage::Stream => "here (streamed file)",
                                _ => "here",
                            }
                        ),
                    );
                }
            }
            at += total;
        }
        self.pending.drain(..at);
        self.base += at as u64;
        Ok(events)
    }
}

/// Decode `count` + blocks starting at `start` of a STAT/DYNA payload (`models`: a range-coded file's DYNA chunk).
fn decode_records(
    payload: &[u8],
    payload_off: u64,
    start: usize,
    block_size: usize,
    layout: &Layout,
    version: u32,
    models: Option<&mut dyna_range::Models>,
) -> Result<(Vec<Gaussian>, usize), WsplatError> {
    let name = if start == 0 { "STAT" } else { "DYNA" };
    if payload.len() < start + 4 {
        return err(ErrorKind::BadPayload, payload_off + start as u64, format!("{name}.count: payload too short"));
    }
    let count = u32_at(payload, start) as usize;
    if count == 0 {
        return err(ErrorKind::BadPayload, payload_off + start as u64, format!("{name}.count: must be >= 1"));
    }
    if version == 2 {
        check_ratio(payload, payload_off, start, count, block_size, layout, name)?;
        if let Some(models) = models {
            return decode_dyna_range(payload, payload_off, start, count, block_size, layout, models).map(|g| (g, count));
        }
        return decode_records_v2(payload, payload_off, start, count, block_size, layout, name).map(|g| (g, count));
    }
    let blocks = count.div_ceil(block_size);
    let want = (start as u64 + 4) + blocks as u64 * BLOCK_HEADER as u64 + count as u64 * layout.record_bytes as u64;
    if payload.len() as u64 != want {
        return err(
            ErrorKind::BadPayload,
            payload_off + start as u64,
            format!("{name}.count: {count} records need a {want}-byte payload, got {}", payload.len()),
        );
    }
    let mut out = Vec::with_capacity(count); // bounded: the payload holding them is present
    let mut at = start + 4;
    for b in 0..blocks {
        let lo = [f32_at(payload, at), f32_at(payload, at + 4), f32_at(payload, at + 8)];
        let hi = [f32_at(payload, at + 12), f32_at(payload, at + 16), f32_at(payload, at + 20)];
        let lsc = [f32_at(payload, at + 24), f32_at(payload, at + 28)];
        let ok =
            (0..3).all(|k| lo[k].is_finite() && hi[k].is_finite() && lo[k] <= hi[k]) && lsc[0].is_finite() && lsc[1].is_finite() && lsc[0] <= lsc[1];
        if !ok {
            return err(ErrorKind::BadPayload, payload_off + at as u64, format!("{name} block {b}: box must be finite with lo <= hi"));
        }
        at += BLOCK_HEADER;
        let n = block_size.min(count - b * block_size);
        for _ in 0..n {
            out.push(layout.decode(&payload[at..at + layout.record_bytes], lo, hi, lsc));
            at += layout.record_bytes;
        }
    }
    Ok((out, count))
}

/// One v2 section: `filter u8, length u32, zstd frame` at `pos`, decompressed into exactly `size` bytes.
/// `max_filter`: 0 for the boxes, 3 for r / b planes that have a g byte to subtract, else 1. Returns the plane with
/// the delta filter undone (filters 2 and 3 still minus g), the filter and the next section's position.
fn v2_section(payload: &[u8], payload_off: u64, pos: usize, size: usize, label: &str, max_filter: u8) -> Result<(Vec<u8>, u8, usize), WsplatError> {
    let at = payload_off + pos as u64;
    let bad = |off: u64, m: String| err::<(Vec<u8>, u8, usize)>(ErrorKind::BadPayload, off, format!("{label}{m}"));
    if pos + 5 > payload.len() {
        return bad(at, ": section header past the end of the chunk".into());
    }
    let filter = payload[pos];
    if filter > max_filter {
        return bad(at, format!(".filter: {filter} (0: none, 1: delta, 2/3: minus g (+ delta); here at most {max_filter})"));
    }
    let len = u32_at(payload, pos + 1) as usize;
    if len > payload.len() - pos - 5 {
        return bad(at + 1, format!(".length: {len} bytes, the chunk has {}", payload.len() - pos - 5));
    }
    let frame_at = at + 5;
    let mut src: &[u8] = &payload[pos + 5..pos + 5 + len];
    // zstd never needs a window larger than the content: the section's size up to a power of two, >= 1 KiB.
    let window = (size.next_power_of_two().max(1 << 10)) as u64;
    let mut dec = match ruzstd::decoding::StreamingDecoder::new_with_max_window_size(&mut src, window) {
        Ok(d) => d,
        Err(e) => return bad(frame_at, format!(": not a zstd frame (or its window > {window} bytes): {e}")),
    };
    if dec.decoder.content_size() != size as u64 {
        return bad(frame_at, format!(": zstd frame declares {} bytes, the section is {size}", dec.decoder.content_size()));
    }
    let mut out = Vec::with_capacity(size); // bounded: size <= MAX_RATIO x the chunk's bytes
    use std::io::Read;
    if let Err(e) = (&mut dec).take(size as u64 + 1).read_to_end(&mut out) {
        return bad(frame_at, format!(": zstd: {e}"));
    }
    drop(dec);
    if out.len() != size || !src.is_empty() {
        return bad(frame_at, ": zstd frame is not exactly one whole section".into());
    }
    if filter == 1 || filter == 3 {
        let mut acc = 0u8;
        for b in out.iter_mut() {
            acc = acc.wrapping_add(*b);
            *b = acc;
        }
    }
    Ok((out, filter, pos + 5 + len))
}

/// v2: a chunk decodes to at most MAX_RATIO x its bytes (its boxes and v2's byte planes), checked before anything.
fn check_ratio(
    payload: &[u8],
    payload_off: u64,
    start: usize,
    count: usize,
    block_size: usize,
    layout: &Layout,
    name: &str,
) -> Result<(), WsplatError> {
    let raw = count.div_ceil(block_size) as u64 * BLOCK_HEADER as u64 + count as u64 * layout.v2_planes().len() as u64;
    if raw > MAX_RATIO * payload.len() as u64 {
        return err(
            ErrorKind::BadPayload,
            payload_off + start as u64,
            format!("{name}.count: {count} records decode to {raw} bytes > {MAX_RATIO} x the chunk's {}", payload.len()),
        );
    }
    Ok(())
}

fn box_at(boxes: &[u8], b: usize) -> ([f32; 3], [f32; 3], [f32; 2]) {
    let f = |k: usize| f32_at(boxes, b * BLOCK_HEADER + 4 * k);
    ([f(0), f(1), f(2)], [f(3), f(4), f(5)], [f(6), f(7)])
}

/// Every box finite with lo <= hi, else an error at `at` naming the block.
fn check_boxes(boxes: &[u8], blocks: usize, at: u64, name: &str) -> Result<(), WsplatError> {
    for b in 0..blocks {
        let (lo, hi, lsc) = box_at(boxes, b);
        let ok =
            (0..3).all(|k| lo[k].is_finite() && hi[k].is_finite() && lo[k] <= hi[k]) && lsc[0].is_finite() && lsc[1].is_finite() && lsc[0] <= lsc[1];
        if !ok {
            return err(ErrorKind::BadPayload, at, format!("{name}.boxes: block {b}: box must be finite with lo <= hi"));
        }
    }
    Ok(())
}

/// The records of a v2 chunk from their Morton deltas (`deltas(r)`, each block's first from 0) and the stored integer
/// of every other field (`values`, count x fields, px py pz filled here): block by block, the Morton sums checked
/// against 2^(3 bits) - 1 (an error at `pos_at`, `{name}.pos`).
#[allow(clippy::too_many_arguments)]
fn v2_gaussians(
    layout: &Layout,
    boxes: &[u8],
    count: usize,
    block_size: usize,
    values: &mut [u64],
    deltas: impl Fn(usize) -> u64,
    pos_at: u64,
    name: &str,
) -> Result<Vec<Gaussian>, WsplatError> {
    let nf = layout.fields.len();
    let pb = layout.pos_bits();
    let limit = (1u64 << (3 * pb)) - 1;
    let idx = |f: Field| layout.fields.iter().position(|x| x.0 == f).unwrap();
    let (ix, iy, iz) = (idx(Field::Px), idx(Field::Py), idx(Field::Pz));
    let mut out = Vec::with_capacity(count);
    for b in 0..count.div_ceil(block_size) {
        let (lo, hi, lsc) = box_at(boxes, b);
        let mut code = 0u64;
        for r in b * block_size..count.min((b + 1) * block_size) {
            let delta = deltas(r);
            code = match code.checked_add(delta) {
                Some(c) if delta <= limit && c <= limit => c,
                _ => return err(ErrorKind::BadPayload, pos_at, format!("{name}.pos: block {b}: Morton deltas add up past 2^{} - 1", 3 * pb)),
            };
            let (mut x, mut y, mut z) = (0u64, 0u64, 0u64);
            for i in 0..pb {
                x |= ((code >> (3 * i)) & 1) << i;
                y |= ((code >> (3 * i + 1)) & 1) << i;
                z |= ((code >> (3 * i + 2)) & 1) << i;
            }
            let v = &mut values[r * nf..(r + 1) * nf];
            (v[ix], v[iy], v[iz]) = (x, y, z);
            let mut word = 0u128;
            for (j, &(_, off, _)) in layout.fields.iter().enumerate() {
                word |= (v[j] as u128) << off;
            }
            out.push(layout.decode(&word.to_le_bytes()[..layout.record_bytes], lo, hi, lsc));
        }
    }
    Ok(out)
}

/// A range-coded DYNA chunk (web/docs/wsplat-v2.md, "Range-coded dynamic records") after its count: the boxes,
/// the stream's length in words, the words; decoded with the file's `models` (updated). The count was bounded by
/// the chunk's bytes (`check_ratio`) and every size is checked against the bytes present before anything is decoded.
fn decode_dyna_range(
    payload: &[u8],
    payload_off: u64,
    start: usize,
    count: usize,
    block_size: usize,
    layout: &Layout,
    models: &mut dyna_range::Models,
) -> Result<Vec<Gaussian>, WsplatError> {
    let blocks = count.div_ceil(block_size);
    let boxes_at = start + 4;
    let at = |p: usize| payload_off + p as u64;
    if (payload.len() - boxes_at) / BLOCK_HEADER < blocks {
        return err(ErrorKind::BadPayload, at(boxes_at), format!("DYNA.boxes: {blocks} boxes past the end of the chunk"));
    }
    let words_at = boxes_at + blocks * BLOCK_HEADER;
    if words_at + 4 > payload.len() {
        return err(ErrorKind::BadPayload, at(words_at), "DYNA.words: the stream's length past the end of the chunk");
    }
    let nwords = u32_at(payload, words_at) as usize;
    let stream_at = words_at + 4;
    let left = payload.len() - stream_at;
    if nwords > left / 4 {
        return err(ErrorKind::BadPayload, at(words_at), format!("DYNA.words: {nwords} words, the chunk has {left} bytes after it"));
    }
    if 4 * nwords < left {
        return err(ErrorKind::BadPayload, at(stream_at + 4 * nwords), format!("DYNA.length: {} bytes after the stream", left - 4 * nwords));
    }
    let boxes = &payload[boxes_at..words_at];
    check_boxes(boxes, blocks, at(boxes_at), "DYNA")?;
    let words: Vec<u32> = payload[stream_at..].chunks_exact(4).map(|w| u32::from_le_bytes(w.try_into().unwrap())).collect();
    let (deltas, coded) = dyna_range::decode_chunk(models, words, count).map_err(|e| {
        let off = match e {
            StreamError::Symbol(..) => stream_at,
            StreamError::Truncated { .. } => payload.len(),
            StreamError::Padding { word, .. } => stream_at + 4 * word,
        };
        WsplatError { kind: ErrorKind::BadPayload, offset: at(off), message: format!("DYNA.stream: {e}") }
    })?;
    let nf = layout.fields.len();
    let mut values = vec![0u64; count * nf];
    let layout_index: Vec<usize> = (0..nf).filter(|&j| !matches!(layout.fields[j].0, Field::Px | Field::Py | Field::Pz)).collect();
    for (v, &j) in coded.iter().zip(&layout_index) {
        for (r, &x) in v.iter().enumerate() {
            values[r * nf + j] = x;
        }
    }
    v2_gaussians(layout, boxes, count, block_size, &mut values, |r| deltas[r], at(stream_at), "DYNA")
}

/// A v2 chunk's sections (web/docs/wsplat-v2.md): boxes, the Morton-delta planes, one plane per field byte.
fn decode_records_v2(
    payload: &[u8],
    payload_off: u64,
    start: usize,
    count: usize,
    block_size: usize,
    layout: &Layout,
    name: &str,
) -> Result<Vec<Gaussian>, WsplatError> {
    let blocks = count.div_ceil(block_size);
    let planes = layout.v2_planes();
    let mut pos = start + 4;
    let boxes_at = payload_off + pos as u64;
    let (boxes, _, next) = v2_section(payload, payload_off, pos, blocks * BLOCK_HEADER, &format!("{name}.boxes"), 0)?;
    pos = next;
    let mut data: Vec<Vec<u8>> = Vec::with_capacity(planes.len());
    let mut field_at: Vec<u64> = Vec::with_capacity(planes.len());
    let g_bytes = layout.fields.iter().find(|x| x.0 == Field::G).map_or(0, |x| x.2.div_ceil(8));
    let mut minus_g = Vec::new(); // (plane, byte index) of r / b planes stored minus g
    for (p, (label, field, k)) in planes.iter().enumerate() {
        field_at.push(payload_off + pos as u64);
        let rb = field.is_some_and(|i| matches!(layout.fields[i].0, Field::R | Field::B));
        let max_filter = if rb && *k < g_bytes { 3 } else { 1 };
        let (d, filter, next) = v2_section(payload, payload_off, pos, count, &format!("{name}.{label}"), max_filter)?;
        if filter >= 2 {
            minus_g.push((p, *k));
        }
        data.push(d);
        pos = next;
    }
    for (p, k) in minus_g {
        let gp = planes.iter().position(|(_, f, kk)| f.is_some_and(|i| layout.fields[i].0 == Field::G) && *kk == k).unwrap();
        let g = data[gp].clone();
        for (x, gv) in data[p].iter_mut().zip(g) {
            *x = x.wrapping_add(gv);
        }
    }
    if pos != payload.len() {
        return err(ErrorKind::BadPayload, payload_off + pos as u64, format!("{name}.length: {} bytes after the last section", payload.len() - pos));
    }
    // checked in this order (as every decoder does): boxes, field values, Morton deltas
    check_boxes(&boxes, blocks, boxes_at, name)?;
    // the stored integer of every field per record (positions from the Morton deltas, per block)
    let nf = layout.fields.len();
    let mut values = vec![0u64; count * nf];
    let pos_at = field_at[0];
    for (p, (_, field, k)) in planes.iter().enumerate() {
        if let Some(i) = field {
            let bits = layout.fields[*i].2;
            for (r, &b) in data[p].iter().enumerate() {
                values[r * nf + i] |= (b as u64) << (8 * k);
            }
            if *k + 1 == bits.div_ceil(8) {
                if let Some(r) = (0..count).find(|&r| values[r * nf + i] >> bits != 0) {
                    let first = field_at[p - *k as usize];
                    let f = layout.fields[*i].0.name();
                    return err(ErrorKind::BadPayload, first, format!("{name}.{f}: record {r}: value {} >= 2^{bits}", values[r * nf + i]));
                }
            }
        }
    }
    let wp = (3 * layout.pos_bits()).div_ceil(8) as usize;
    let delta = |r: usize| (0..wp).fold(0u64, |acc, k| acc | (data[k][r] as u64) << (8 * k));
    v2_gaussians(layout, &boxes, count, block_size, &mut values, delta, pos_at, name)
}

/// A minimal encoder (one STAT chunk per `static_chunk` Gaussians, one DYNA chunk per frame) with fixed layouts:
/// for tests, the property test and the fuzz corpus. The project's encoder is the Python one.
pub mod encode {
    use super::*;
    use serde_json::json;

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
        let rig: Vec<Value> = crate::camera::default_rig(160, 90)
            .iter()
            .map(|c| {
                json!({"name": c.name, "width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                             "camera_to_ego": crate::camera::mat4_to_json(&c.camera_to_ego)})
            })
            .collect();
        let ego: Vec<Value> = (0..t).map(|f| crate::camera::mat4_to_json(&crate::camera::translation(f as f64 * 0.5, 0.0, 0.0))).collect();
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
}
