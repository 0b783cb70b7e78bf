//! The progressive decoder: bytes in as they arrive, one `Event` per complete chunk, and a chunk's payload to its
//! records (v1 bit-packed records here, v2 sections in `v2`).

use super::colours::decode_scol;
use super::dyna_range;
use super::header::{DynamicCodec, Header, Totals};
use super::layout::Layout;
use super::objects::{decode_objc, decode_pose, AgentObject, Poses};
use super::v2::{decode_dyna_range, decode_records_v2, Chunk};
use super::{err, f32_at, u32_at, ErrorKind, WsplatError, BLOCK_HEADER, MAGIC, MAX_CHUNK, MAX_HEAD, MAX_RATIO, VERSIONS};
use crate::gaussians::Gaussian;
use serde_json::Value;

/// What a complete chunk yields.
#[derive(Debug)]
pub enum Event {
    Header(Box<Header>),
    Static(Vec<Gaussian>),
    Dynamic {
        frame: usize,
        gaussians: Vec<Gaussian>,
    },
    /// v3: an agent object's canonical Gaussians (box frame); an index defined before: more Gaussians of that object.
    Object(AgentObject),
    /// v3: a run of frames' poses of the objects defined so far.
    Poses(Poses),
    /// v4: new colours of statics `first..first + colours.len()` (decoded order: every Static event's Gaussians in
    /// turn); the reader rewrites them (positions, shapes and opacities stay).
    StaticColours {
        first: usize,
        colours: Vec<[f32; 3]>,
    },
    End,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    Magic,
    Head,
    Static,
    Dynamic,
    /// after the HEAD of a streamed file: any chunk but HEAD (v4: SCOL only here)
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
    /// v3: (agent_id, cls, size) of the objects defined so far, and the frames a POSE chunk posed.
    objects: Vec<(u32, u32, [f32; 3])>,
    posed: Vec<bool>,
}

impl Default for Decoder {
    fn default() -> Self {
        Decoder::new()
    }
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
            objects: Vec::new(),
            posed: Vec::new(),
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
            let object_tag = self.version >= 3 && matches!(&tag, b"OBJC" | b"POSE");
            let colour_tag = self.version >= 4 && &tag == b"SCOL";
            if !matches!(&tag, b"HEAD" | b"STAT" | b"DYNA" | b"END!") && !object_tag && !colour_tag {
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
                    self.posed = vec![false; h.frame_times.len()];
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
                (b"OBJC", Stage::Static | Stage::Stream) => {
                    let h = self.header.as_ref().unwrap();
                    let limit = (!h.streamed).then_some(h.num_objects);
                    let layout = h.object_layout.as_ref().unwrap();
                    let o = decode_objc(payload, payload_off, &self.objects, limit, layout, h.block_size)?;
                    if o.index == self.objects.len() {
                        self.objects.push((o.agent_id, o.cls, o.size));
                    }
                    events.push(Event::Object(o));
                }
                (b"POSE", Stage::Static | Stage::Dynamic | Stage::Stream) => {
                    let poses = decode_pose(payload, payload_off, &mut self.posed, self.objects.len())?;
                    if self.stage == Stage::Static {
                        self.stage = Stage::Dynamic;
                    }
                    events.push(Event::Poses(poses));
                }
                (b"SCOL", Stage::Stream) => {
                    let h = self.header.as_ref().unwrap();
                    let (first, colours) = decode_scol(payload, payload_off, self.static_count, &h.static_layout)?;
                    events.push(Event::StaticColours { first, colours });
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
                        if h.version >= 3 {
                            h.num_objects = v.get("num_objects").and_then(Value::as_u64).ok_or_else(|| WsplatError {
                                kind: ErrorKind::BadPayload,
                                offset: payload_off,
                                message: "END!.num_objects: expected an integer >= 0".into(),
                            })?;
                        }
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
                    if h.version >= 3 && self.objects.len() as u64 != h.num_objects {
                        return err(
                            ErrorKind::CountMismatch,
                            off,
                            format!("END!: {} objects, {src}.num_objects says {}", self.objects.len(), h.num_objects),
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
    let blocks = count.div_ceil(block_size);
    if version >= 2 {
        // A v2 chunk decodes to at most MAX_RATIO x its bytes (its boxes and byte planes), checked before anything.
        let raw = blocks as u64 * BLOCK_HEADER as u64 + count as u64 * layout.v2_planes().len() as u64;
        if raw > MAX_RATIO * payload.len() as u64 {
            return err(
                ErrorKind::BadPayload,
                payload_off + start as u64,
                format!("{name}.count: {count} records decode to {raw} bytes > {MAX_RATIO} x the chunk's {}", payload.len()),
            );
        }
        let chunk = Chunk { payload, payload_off, start, count, block_size, layout };
        if let Some(models) = models {
            return decode_dyna_range(chunk, models).map(|g| (g, count));
        }
        return decode_records_v2(chunk, name).map(|g| (g, count));
    }
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
