//! v4's SCOL chunk (web/docs/wsplat-v4.md): new colours of a run of statics decoded before, in decoded order, stored
//! as the static layout stores colour (its r, g, b bits as v2 byte planes).

use super::layout::Layout;
use super::v2::{decode_planes, plane_values};
use super::{err, u32_at, ErrorKind, WsplatError, MAX_RATIO};

pub const SCOL_HEADER: usize = 8;

/// A SCOL payload, `decoded` statics before it: (first, the colours of statics first..first + count). Checks the
/// header's length, count >= 1, the range, the bound (MAX_RATIO), then the sections as v2's.
pub(super) fn decode_scol(payload: &[u8], payload_off: u64, decoded: u64, layout: &Layout) -> Result<(usize, Vec<[f32; 3]>), WsplatError> {
    if payload.len() < SCOL_HEADER {
        return err(ErrorKind::BadPayload, payload_off, format!("SCOL.first: payload shorter than its {SCOL_HEADER}-byte header"));
    }
    let (first, count) = (u32_at(payload, 0) as u64, u32_at(payload, 4) as u64);
    let count_at = payload_off + 4;
    if count == 0 {
        return err(ErrorKind::BadPayload, count_at, "SCOL.count: must be >= 1");
    }
    if first + count > decoded {
        return err(ErrorKind::CountMismatch, count_at, format!("SCOL.count: statics {first}..{}, {decoded} decoded before", first + count));
    }
    let planes = layout.colour_planes();
    let raw = count * planes.len() as u64;
    if raw > MAX_RATIO * payload.len() as u64 {
        return err(ErrorKind::BadPayload, count_at, format!("SCOL.count: {count} colours decode to {raw} bytes > {MAX_RATIO} x the chunk"));
    }
    let count = count as usize; // bounded by the bytes present
    let (data, field_at) = decode_planes(payload, payload_off, SCOL_HEADER, &planes, count, layout, "SCOL")?;
    let values = plane_values(&planes, &data, &field_at, count, layout, "SCOL")?;
    let nf = layout.fields.len();
    Ok((first as usize, values.chunks_exact(nf).map(|v| layout.colour(v)).collect()))
}
