//! Progressive .wsplat v1 to v4 decoder (web/docs/wsplat-v1.md, wsplat-v2.md, wsplat-v3.md, wsplat-v4.md; the agent
//! objects, OBJC and POSE chunks, in `objects`; v4's colour update of the statics, SCOL, in `colours`). Feed bytes as
//! they arrive
//! (`push`); each complete chunk becomes an `Event`. v2 chunks hold zstd-coded byte planes (ruzstd), each
//! decompressed into exactly the size its count implies, after the count was bounded by the chunk's bytes; a v2 file
//! whose HEAD says `dynamic_codec: "range"` holds its DYNA records in one range-coded stream per chunk
//! (`dyna_range`), decoded with models carried from the file's earlier DYNA chunks (so chunks decode in file order,
//! as `push` does). Never reads past the bytes present, buffers only the incomplete chunk, and
//! allocates decoded records only for chunks whose bytes (and CRC) have arrived. Every error names the byte
//! offset and the field, with a kind from the spec's list.
//!
//! Here: the spec's limits and its error kinds. `decoder`: bytes to events, v1 records; `header`: the HEAD JSON;
//! `layout`: a bit-packed record layout; `v2`: v2 sections; `dyna_range`: the range coder; `encode` (feature
//! `encode`): a minimal encoder for tests and fixtures.

mod colours;
mod decoder;
pub mod dyna_range;
#[cfg(feature = "encode")]
pub mod encode;
mod header;
mod layout;
pub mod objects;
mod v2;

pub use decoder::{Decoder, Event, Progress};
pub use header::{DynamicCodec, Header};
pub use layout::{Layout, Q_CANON};

pub const MAGIC: &[u8; 8] = b"WSPLAT\r\n";
pub const VERSION: u32 = 1;
/// The versions this decoder reads.
pub const VERSIONS: [u32; 4] = [1, 2, 3, 4];
/// A v2 chunk decodes to at most MAX_RATIO x its payload bytes (checked before anything is decompressed).
pub const MAX_RATIO: u64 = 64;
/// v2: px py pz share their bits, at most this many (the Morton code fits 63 bits).
pub const MAX_POS_BITS_V2: u32 = 21;
pub const MAX_CHUNK: u32 = 64 << 20;
pub const MAX_HEAD: u32 = 1 << 20;
pub const MAX_FRAMES: usize = 1024;
pub(crate) const BLOCK_HEADER: usize = 32;

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

pub(crate) fn err<T>(kind: ErrorKind, offset: u64, message: impl Into<String>) -> Result<T, WsplatError> {
    Err(WsplatError { kind, offset, message: message.into() })
}

pub(crate) fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

pub(crate) fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}
