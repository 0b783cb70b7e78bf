//! The adaptive context-modelling range coder of .wsplat v2's dynamic records (HEAD `dynamic_codec: "range"`;
//! web/docs/wsplat-v2.md, "Range-coded dynamic records"). The model is the spec's (its Python home:
//! server/worldsplat/gaussians/context_coder.py): per DYNA chunk, the Morton deltas' bit lengths (adaptive) and the
//! bits below their leading one (raw), then for each non-position layout field the residual of its top
//! `ADAPTIVE_BITS` bits against the previous record's (adaptive, in the context of an earlier field's residual for
//! the same record, `CONTEXT`) and its low bits (raw). Adaptive count tables
//! start at zero at the file's first DYNA chunk and carry over to every later one; a count table becomes a 24-bit
//! frequency table by an exact integer rule (`Kt`), so both implementations code with the same table. The coder is
//! constriction's queue range coder (u32 words, u64 state, 24-bit precision), which the Python encoder uses too.

use constriction::stream::model::{DecoderModel, DefaultUniformModel, EncoderModel, EntropyModel};
use constriction::stream::queue::{DefaultRangeDecoder, DefaultRangeEncoder};
use constriction::stream::{Decode, Encode};
use std::num::NonZeroU32;

pub const PRECISION: usize = 24;
const TOTAL: u64 = 1 << PRECISION;
/// A field's top bits coded adaptively (alphabet <= 64); the rest are raw.
pub const ADAPTIVE_BITS: u32 = 6;
/// Raw bits per uniform symbol, at most.
pub const RAW_PIECE: u32 = 16;
/// A context whose counts add up to this is halved.
pub const RESCALE_AT: u32 = 1 << 16;
/// (field, the field it is coded in the context of).
pub const CONTEXT: [(&str, &str); 7] = [("sy", "sx"), ("sz", "sy"), ("g", "r"), ("b", "g"), ("qy", "qx"), ("qz", "qy"), ("o", "sz")];

/// A coded (non-position) layout field.
#[derive(Clone, Debug, PartialEq)]
pub struct CodedField {
    pub name: &'static str,
    pub bits: u32,
    pub adaptive: u32,
    /// Index (into the coded fields) of the field whose residual selects the count table.
    pub context: Option<usize>,
    pub context_bits: u32,
}

/// The non-position fields of a layout ([(name, bits)] in layout order) with their contexts: a field's context is
/// used only when that field comes earlier in the layout.
pub fn coded_fields(layout: &[(&'static str, u32)]) -> Vec<CodedField> {
    let mut out: Vec<CodedField> = Vec::new();
    for &(name, bits) in layout {
        if matches!(name, "px" | "py" | "pz") {
            continue;
        }
        let ctx = CONTEXT.iter().find(|c| c.0 == name).and_then(|c| out.iter().position(|f| f.name == c.1));
        let context_bits = ctx.map_or(0, |i| out[i].adaptive);
        out.push(CodedField { name, bits, adaptive: bits.min(ADAPTIVE_BITS), context: ctx, context_bits });
    }
    out
}

/// Count tables: one row of `k` counts per context.
#[derive(Clone, Debug, PartialEq)]
struct Table {
    k: usize,
    counts: Vec<u32>,
}

impl Table {
    fn new(contexts: usize, k: usize) -> Table {
        Table { k, counts: vec![0; contexts * k] }
    }
    fn row(&self, ctx: usize) -> Kt<'_> {
        Kt::new(&self.counts[ctx * self.k..(ctx + 1) * self.k])
    }
    fn update(&mut self, ctx: usize, s: usize) {
        let row = &mut self.counts[ctx * self.k..(ctx + 1) * self.k];
        row[s] += 1;
        if row.iter().sum::<u32>() >= RESCALE_AT {
            row.iter_mut().for_each(|c| *c >>= 1);
        }
    }
}

/// The adaptive models of a file's DYNA chunks (kept by a decoder from its first DYNA chunk to its last).
#[derive(Clone, Debug, PartialEq)]
pub struct Models {
    pub fields: Vec<CodedField>,
    pos: Table,
    tables: Vec<Table>,
}

impl Models {
    /// Empty models for a dynamic layout ([(name, bits)], px py pz of equal bits <= 21): at most 28,928 counts
    /// (113 KB) for any layout, 2,324 for the default anisotropic one.
    pub fn new(layout: &[(&'static str, u32)]) -> Models {
        let pb = layout.iter().find(|f| f.0 == "px").map_or(0, |f| f.1);
        let fields = coded_fields(layout);
        let tables = fields.iter().map(|f| Table::new(if f.context.is_some() { 1 << f.context_bits } else { 1 }, 1 << f.adaptive)).collect();
        Models { fields, pos: Table::new(1, 3 * pb as usize + 1), tables }
    }
}

/// One count row as constriction's entropy model: symbol i weighs 2 count_i + 1; with W the total weight and C_i the
/// weight before i, i's interval starts at floor(C_i (2^24 - K) / W) + i (exact integers) and the last ends at 2^24.
#[derive(Clone, Copy)]
struct Kt<'a> {
    counts: &'a [u32],
    weight: u64,
}

impl<'a> Kt<'a> {
    fn new(counts: &'a [u32]) -> Kt<'a> {
        Kt { counts, weight: counts.iter().map(|&c| 2 * c as u64 + 1).sum() }
    }
    fn left(&self, i: usize, before: u64) -> u64 {
        before * (TOTAL - self.counts.len() as u64) / self.weight + i as u64
    }
    /// (left cumulative, frequency) of symbol s.
    fn interval(&self, s: usize) -> (u64, u64) {
        let before: u64 = self.counts[..s].iter().map(|&c| 2 * c as u64 + 1).sum();
        let left = self.left(s, before);
        let right = if s + 1 == self.counts.len() { TOTAL } else { self.left(s + 1, before + 2 * self.counts[s] as u64 + 1) };
        (left, right - left)
    }
}

impl EntropyModel<PRECISION> for Kt<'_> {
    type Symbol = usize;
    type Probability = u32;
}

impl EncoderModel<PRECISION> for Kt<'_> {
    fn left_cumulative_and_probability(&self, symbol: impl std::borrow::Borrow<usize>) -> Option<(u32, NonZeroU32)> {
        let s = *symbol.borrow();
        if s >= self.counts.len() {
            return None;
        }
        let (left, f) = self.interval(s);
        Some((left as u32, NonZeroU32::new(f as u32)?))
    }
}

impl DecoderModel<PRECISION> for Kt<'_> {
    fn quantile_function(&self, quantile: u32) -> (usize, u32, NonZeroU32) {
        let q = quantile as u64;
        let k = self.counts.len();
        let (mut before, mut left) = (0u64, 0u64);
        for i in 0..k {
            let w = 2 * self.counts[i] as u64 + 1;
            let right = if i + 1 == k { TOTAL } else { self.left(i + 1, before + w) };
            if q < right {
                return (i, left as u32, NonZeroU32::new((right - left) as u32).expect("every frequency is >= 1"));
            }
            (before, left) = (before + w, right);
        }
        unreachable!("quantile {quantile} >= 2^24")
    }
}

/// Why a stream does not decode.
#[derive(Clone, Debug, PartialEq)]
pub enum StreamError {
    /// A symbol out of range: the decoder's point left the coded interval (what, record).
    Symbol(String, usize),
    /// The symbols need more words than the stream holds (beyond the one word past its end that reads as 0).
    Truncated { need: usize, held: usize },
    /// Word `word` after the last symbol is not 0.
    Padding { word: usize, value: u32 },
}

impl std::fmt::Display for StreamError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StreamError::Symbol(what, r) => write!(f, "symbol {what} of record {r} out of range (not a stream of this chunk)"),
            StreamError::Truncated { need, held } => write!(f, "the symbols need {need} words, the stream holds {held}"),
            StreamError::Padding { word, value } => write!(f, "word {word} after the last symbol is {value}, not 0"),
        }
    }
}

/// constriction's decoder plus the number of words it reads: 2 to start, one per renormalization (the coder's range,
/// tracked with the same integer steps).
struct Reader {
    dec: DefaultRangeDecoder,
    range: u64,
    reads: usize,
}

impl Reader {
    fn step(&mut self, freq: u64) {
        self.range = (self.range >> PRECISION) * freq;
        if self.range < 1 << 32 {
            self.range <<= 32;
            self.reads += 1;
        }
    }
    fn adaptive(&mut self, table: &mut Table, ctx: usize, what: &str, r: usize) -> Result<usize, StreamError> {
        let model = table.row(ctx);
        let s = self.dec.decode_symbol(model).map_err(|_| StreamError::Symbol(what.to_string(), r))?;
        let (_, f) = model.interval(s);
        self.step(f);
        table.update(ctx, s);
        Ok(s)
    }
    fn raw(&mut self, nbits: u32, what: &str, r: usize) -> Result<u64, StreamError> {
        let (mut left, mut v) = (nbits, 0u64);
        while left > 0 {
            let m = left.min(RAW_PIECE);
            let piece = self.dec.decode_symbol(DefaultUniformModel::new(1 << m)).map_err(|_| StreamError::Symbol(format!("{what} raw"), r))?;
            self.step(TOTAL >> m);
            v = (v << m) | piece as u64;
            left -= m;
        }
        Ok(v)
    }
}

/// The words of one DYNA chunk's stream -> (Morton deltas, the stored integer of every coded field, one Vec per
/// `models.fields` entry), in file order, updating `models`. Allocates `count` integers per field: the caller bounds
/// `count` by the chunk's bytes first.
#[allow(clippy::type_complexity)]
pub fn decode_chunk(models: &mut Models, words: Vec<u32>, count: usize) -> Result<(Vec<u64>, Vec<Vec<u64>>), StreamError> {
    let held = words.len();
    let dec = DefaultRangeDecoder::from_compressed(words.clone()).unwrap_or_else(|e| match e {});
    let mut rd = Reader { dec, range: u64::MAX, reads: 2 };
    let mut lengths = Vec::with_capacity(count);
    for r in 0..count {
        lengths.push(rd.adaptive(&mut models.pos, 0, "pos", r)? as u32);
    }
    let mut deltas = Vec::with_capacity(count);
    for (r, &n) in lengths.iter().enumerate() {
        deltas.push(match n {
            0 => 0,
            n => (1u64 << (n - 1)) | rd.raw(n - 1, "pos", r)?,
        });
    }
    let mut values: Vec<Vec<u64>> = Vec::with_capacity(models.fields.len());
    let mut residuals: Vec<Vec<u32>> = Vec::with_capacity(models.fields.len());
    for i in 0..models.fields.len() {
        let f = models.fields[i].clone();
        let mut res = Vec::with_capacity(count);
        let ctx: Vec<usize> = match f.context {
            Some(c) => residuals[c].iter().map(|&t| t as usize).collect(),
            None => vec![0; count],
        };
        for (r, &c) in ctx.iter().enumerate() {
            res.push(rd.adaptive(&mut models.tables[i], c, f.name, r)? as u32);
        }
        let (low, mask) = (f.bits - f.adaptive, (1u64 << f.adaptive) - 1);
        let mut top = 0u64;
        let mut v: Vec<u64> = res
            .iter()
            .map(|&t| {
                top = (top + t as u64) & mask;
                top << low
            })
            .collect();
        if low > 0 {
            for (r, x) in v.iter_mut().enumerate() {
                *x |= rd.raw(low, f.name, r)?;
            }
        }
        residuals.push(res);
        values.push(v);
    }
    if rd.reads > held + 1 {
        return Err(StreamError::Truncated { need: rd.reads, held });
    }
    if let Some(j) = (rd.reads..held).find(|&j| words[j] != 0) {
        return Err(StreamError::Padding { word: j, value: words[j] });
    }
    Ok((deltas, values))
}

/// The encoder of the same stream (the project's encoder is the Python one; this one is for tests, which check that
/// both write the same words, and the fuzz corpus).
pub fn encode_chunk(models: &mut Models, deltas: &[u64], values: &[Vec<u64>]) -> Vec<u32> {
    let mut enc = DefaultRangeEncoder::new();
    let raw = |enc: &mut DefaultRangeEncoder, v: u64, nbits: u32| {
        let mut left = nbits;
        while left > 0 {
            let m = left.min(RAW_PIECE);
            let piece = ((v >> (left - m)) & ((1 << m) - 1)) as usize;
            enc.encode_symbol(piece, DefaultUniformModel::new(1 << m)).expect("a piece below 2^m");
            left -= m;
        }
    };
    let lengths: Vec<u32> = deltas.iter().map(|d| 64 - d.leading_zeros()).collect();
    for &n in &lengths {
        enc.encode_symbol(n as usize, models.pos.row(0)).expect("a bit length <= 3 bits(px)");
        models.pos.update(0, n as usize);
    }
    for (&d, &n) in deltas.iter().zip(&lengths) {
        raw(&mut enc, d, n.saturating_sub(1));
    }
    // the residual of a field's top bits against the previous record's (the chunk's first record against 0)
    let residual = |fields: &[CodedField], j: usize, r: usize| {
        let f = &fields[j];
        let top = |r: usize| values[j][r] >> (f.bits - f.adaptive);
        let prev = if r == 0 { 0 } else { top(r - 1) };
        (top(r).wrapping_sub(prev) & ((1 << f.adaptive) - 1)) as usize
    };
    for (i, field_values) in values.iter().enumerate() {
        let f = models.fields[i].clone();
        for r in 0..deltas.len() {
            let ctx = f.context.map_or(0, |c| residual(&models.fields, c, r));
            let s = residual(&models.fields, i, r);
            enc.encode_symbol(s, models.tables[i].row(ctx)).expect("a residual below 2^a");
            models.tables[i].update(ctx, s);
        }
        let low = f.bits - f.adaptive;
        for &v in field_values {
            raw(&mut enc, v, low);
        }
    }
    enc.into_compressed().unwrap_or_else(|e| match e {})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frequencies_sum_to_2_24_and_invert() {
        for counts in [vec![0u32, 0], vec![5, 0, 0, 9000, 1], vec![65535; 64], (0..64).collect()] {
            let m = Kt::new(&counts);
            let mut at = 0;
            for s in 0..counts.len() {
                let (l, f) = m.interval(s);
                assert_eq!(l, at);
                assert!(f >= 1);
                for q in [l, l + f / 2, l + f - 1] {
                    let (s2, l2, f2) = m.quantile_function(q as u32);
                    assert_eq!((s2, l2 as u64, f2.get() as u64), (s, l, f));
                }
                at += f;
            }
            assert_eq!(at, TOTAL);
        }
    }

    #[test]
    fn chunks_round_trip_with_models_carried() {
        let layout: &[(&'static str, u32)] = &[
            ("px", 21),
            ("py", 21),
            ("pz", 21),
            ("sx", 3),
            ("sy", 9),
            ("sz", 24),
            ("o", 1),
            ("qx", 2),
            ("qy", 2),
            ("qz", 2),
            ("r", 5),
            ("g", 5),
            ("b", 5),
        ];
        let mut x = 0x9e3779b97f4a7c15u64;
        let mut rnd = |n: u32| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            if n == 64 {
                x
            } else {
                x & ((1u64 << n) - 1)
            }
        };
        let (mut enc, mut dec) = (Models::new(layout), Models::new(layout));
        for count in [1usize, 200, 37] {
            let deltas: Vec<u64> = (0..count).map(|_| rnd(63) >> rnd(6)).collect();
            let values: Vec<Vec<u64>> = enc.fields.clone().iter().map(|f| (0..count).map(|_| rnd(f.bits)).collect()).collect();
            let words = encode_chunk(&mut enc, &deltas, &values);
            let before = dec.clone();
            assert_eq!(decode_chunk(&mut dec, words.clone(), count), Ok((deltas.clone(), values.clone())));
            assert_eq!(enc, dec);
            let n = words.len();
            let padded = [words.clone(), vec![0, 0]].concat();
            assert_eq!(decode_chunk(&mut before.clone(), padded.clone(), count), Ok((deltas.clone(), values.clone())));
            let tail = [padded, vec![3]].concat();
            assert_eq!(decode_chunk(&mut before.clone(), tail, count), Err(StreamError::Padding { word: n + 2, value: 3 }));
            if n >= 2 {
                let short = decode_chunk(&mut before.clone(), words[..n - 2].to_vec(), count);
                assert!(matches!(short, Err(StreamError::Truncated { .. } | StreamError::Symbol(..))), "{short:?}");
            }
        }
    }
}
