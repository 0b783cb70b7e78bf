//! A v2 chunk's payload to its records (web/docs/wsplat-v2.md): zstd-coded sections of byte planes, the Morton
//! deltas of the positions, and range-coded DYNA records (`dyna_range`).

use super::dyna_range::{self, StreamError};
use super::layout::{Field, Layout};
use super::{err, f32_at, u32_at, ErrorKind, WsplatError, BLOCK_HEADER};
use crate::gaussians::Gaussian;

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

/// A v2 STAT or DYNA chunk's records: `count` of them (already read and bounded) after the count at `start` of a
/// payload that begins at `payload_off` in the file.
#[derive(Clone, Copy)]
pub(super) struct Chunk<'a> {
    pub payload: &'a [u8],
    pub payload_off: u64,
    pub start: usize,
    pub count: usize,
    pub block_size: usize,
    pub layout: &'a Layout,
}

/// A range-coded DYNA chunk (web/docs/wsplat-v2.md, "Range-coded dynamic records") after its count: the boxes,
/// the stream's length in words, the words; decoded with the file's `models` (updated). The count was bounded by
/// the chunk's bytes (`decode_records`) and every size is checked against the bytes present before anything is decoded.
pub(super) fn decode_dyna_range(chunk: Chunk, models: &mut dyna_range::Models) -> Result<Vec<Gaussian>, WsplatError> {
    let Chunk { payload, payload_off, start, count, block_size, layout } = chunk;
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
pub(super) fn decode_records_v2(chunk: Chunk, name: &str) -> Result<Vec<Gaussian>, WsplatError> {
    let Chunk { payload, payload_off, start, count, block_size, layout } = chunk;
    let blocks = count.div_ceil(block_size);
    let planes = layout.v2_planes();
    let pos = start + 4;
    let boxes_at = payload_off + pos as u64;
    let (boxes, _, next) = v2_section(payload, payload_off, pos, blocks * BLOCK_HEADER, &format!("{name}.boxes"), 0)?;
    let (data, field_at) = decode_planes(payload, payload_off, next, &planes, count, layout, name)?;
    // checked in this order (as every decoder does): boxes, field values, Morton deltas
    check_boxes(&boxes, blocks, boxes_at, name)?;
    let mut values = plane_values(&planes, &data, &field_at, count, layout, name)?;
    let wp = (3 * layout.pos_bits()).div_ceil(8) as usize;
    let delta = |r: usize| (0..wp).fold(0u64, |acc, k| acc | (data[k][r] as u64) << (8 * k));
    v2_gaussians(layout, &boxes, count, block_size, &mut values, delta, field_at[0], name)
}

/// v2 sections from `pos` to the chunk's end, one of `count` bytes per plane of `planes` (`Layout::v2_planes`, or
/// a part of them), each filter undone (r / b minus g once every section is in). Returns the planes and the file
/// offset of each section.
pub(super) fn decode_planes(
    payload: &[u8],
    payload_off: u64,
    mut pos: usize,
    planes: &[(String, Option<usize>, u32)],
    count: usize,
    layout: &Layout,
    name: &str,
) -> Result<(Vec<Vec<u8>>, Vec<u64>), WsplatError> {
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
    Ok((data, field_at))
}

/// The stored integer of every field with planes (count x fields, in layout order; the others 0), each checked to be
/// below 2^bits (an error at the field's first section, naming the record).
pub(super) fn plane_values(
    planes: &[(String, Option<usize>, u32)],
    data: &[Vec<u8>],
    field_at: &[u64],
    count: usize,
    layout: &Layout,
    name: &str,
) -> Result<Vec<u64>, WsplatError> {
    let nf = layout.fields.len();
    let mut values = vec![0u64; count * nf];
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
    Ok(values)
}
