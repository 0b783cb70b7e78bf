//! The HEAD chunk's JSON (and a streamed file's END! totals), checked field by field.

use super::layout::Layout;
use super::{ErrorKind, WsplatError, MAX_FRAMES};
use crate::camera::{mat4_from_json, Mat4, RigCamera};
use serde_json::Value;

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
    /// The file's version (1 to 4).
    pub version: u32,
    /// v3: the layout of the objects' canonical Gaussians (None before v3).
    pub object_layout: Option<Layout>,
    /// v3: the OBJC chunks of the file (a streamed file: 0 until its END! arrives with them).
    pub num_objects: u64,
    /// v2: the codec of the DYNA chunks (v1: Zstd, which stands for its bit-packed records).
    pub dynamic_codec: DynamicCodec,
}

impl Header {
    pub(super) fn from_json(v: &Value, offset: u64, version: u32) -> Result<Header, WsplatError> {
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
        if version >= 2 && v.get("codec").and_then(Value::as_str) != Some("zstd") {
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
        if version >= 2 {
            static_layout = static_layout.check_v2("static_layout", offset)?;
            dynamic_layout = dynamic_layout.check_v2("dynamic_layout", offset)?;
        }
        let (mut object_layout, mut num_objects) = (None, 0);
        if version >= 3 {
            object_layout = Some(Layout::from_json(get("object_layout")?, "object_layout", offset)?.check_v2("object_layout", offset)?);
            let n = get("num_objects")?;
            num_objects = match (streamed, n.as_u64()) {
                (true, _) if n.is_null() => 0,
                (false, Some(n)) => n,
                _ => {
                    return Err(bad(format!(
                        "num_objects: {}",
                        if streamed { "must be null in a streamed file" } else { "expected an integer >= 0" }
                    )))
                }
            };
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
            object_layout,
            num_objects,
            dynamic_codec,
        })
    }
}

/// num_static, num_dynamic[T] and bounds: of a HEAD, or of a streamed file's END!.
pub(super) struct Totals {
    pub(super) num_static: u64,
    pub(super) num_dynamic: Vec<u64>,
    pub(super) bounds_min: [f64; 3],
    pub(super) bounds_max: [f64; 3],
}

impl Totals {
    /// Errors are "field: message".
    pub(super) fn from_json(v: &Value, t: usize) -> Result<Totals, String> {
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
