"""The adaptive context-modelling range coder of .wsplat v2's dynamic records (HEAD `dynamic_codec: "range"`;
web/docs/wsplat-v2.md, "Range-coded dynamic records", is the normative text).

One home for the model: which symbols a DYNA chunk's records become, which field is coded in the context of which,
the adaptive count tables (they start empty at a file's first DYNA chunk and carry over to every later one), and
the exact integer rule that turns a count table into a 24-bit frequency table, so that every implementation codes
with the same table. The coder is constriction's queue range coder (32-bit words, 64-bit state, 24-bit precision):
`constriction.stream.queue.RangeEncoder` here, `constriction::stream::queue::DefaultRangeDecoder` in the wasm
decoder. `wsplat` writes and reads the chunks with it; `bench.dyna_context` measures what it costs.

Symbols of one chunk, records in file order (block by block, Morton order inside each block, as v2 stores them):
1. `pos`: per record, the bit length n (0 .. 3 bits(px)) of its Morton delta: adaptive, one context;
2. per record with n >= 2, the n - 1 bits of the delta below its leading one: raw;
3. per other layout field f, in layout order: per record the residual of its top a = min(bits, ADAPTIVE_BITS) bits
   against the previous record's ((t - t_previous) mod 2^a, the chunk's first record against 0), adaptive, in the
   context of the same record's residual of CONTEXT[f] when that field comes earlier in the layout (else one
   context); then, for a field wider than ADAPTIVE_BITS, per record its low bits: raw.
(Records of a chunk follow the Morton curve, so neighbours are near each other: on the oracle scene's surface lifts
the residuals of scale and colour take half the bits of the values; on the generated scene a little less, and the
context field's residual predicts a residual as its value predicts a value: bench.dyna_context.)
Raw bits are coded in pieces of at most RAW_PIECE bits, high piece first, each a uniform symbol over 2^m.
"""

from __future__ import annotations

from dataclasses import dataclass

import constriction
import numpy as np

PRECISION = 24  # the range coder's probability precision: frequency tables sum to 2^24
TOTAL = 1 << PRECISION
ADAPTIVE_BITS = 6  # a field's top bits coded adaptively (alphabet <= 64); the rest raw
RAW_PIECE = 16  # raw bits per uniform symbol, at most
RESCALE_AT = 1 << 16  # a context whose counts add up to this is halved (counts stay small and the model adapts)
# the field each field is coded in the context of (the dependence bench.dyna_context measured on the generated
# scene: the three log-scales of a Gaussian, its colour channels, its rotation components, its opacity and size)
CONTEXT = {"sy": "sx", "sz": "sy", "g": "r", "b": "g", "qy": "qx", "qz": "qy", "o": "sz"}
POSITION_FIELDS = ("px", "py", "pz")
PIECE = 4096  # symbols per vectorized encode step (memory: PIECE x alphabet)

_Categorical = constriction.stream.model.Categorical
_Uniform = constriction.stream.model.Uniform
_RangeEncoder = constriction.stream.queue.RangeEncoder
_RangeDecoder = constriction.stream.queue.RangeDecoder


class StreamError(ValueError):
    """A stream that does not decode: `what` is 'symbol' (a symbol out of range: the decoder's point left the
    coded interval), 'truncated' (the symbols need more words than the stream holds) or 'padding' (a word after
    the last symbol is not 0; `word` is its index)."""

    def __init__(self, what: str, message: str, word: int = 0):
        self.what, self.word = what, word
        super().__init__(message)


def frequencies(counts: np.ndarray) -> np.ndarray:
    """Count tables (..., K) -> their 24-bit frequency tables (..., K), int64, every entry >= 1, each summing to
    2^24 (Krichevsky-Trofimov: symbol i weighs 2 count_i + 1). With W the sum of the weights and C_i the sum of the
    weights before symbol i, symbol i's interval starts at floor(C_i (2^24 - K) / W) + i (exact integers); the
    last one ends at 2^24. (constriction's `from_floating_point_probabilities_fast` in exact arithmetic.)"""
    c = np.asarray(counts, dtype=np.int64)
    k = c.shape[-1]
    w = 2 * c + 1
    cum = np.cumsum(w, axis=-1)
    left = (cum - w) * (TOTAL - k) // cum[..., -1:] + np.arange(k)
    right = np.concatenate([left[..., 1:], np.full(left.shape[:-1] + (1,), TOTAL, dtype=np.int64)], axis=-1)
    return right - left


@dataclass(frozen=True)
class Field:
    """A coded layout field: the residual of its `adaptive` top bits coded adaptively, `bits - adaptive` low bits raw;
    `context` the field whose residual (`context_bits` bits) selects its count table (None: one table)."""

    name: str
    bits: int
    adaptive: int
    context: str | None
    context_bits: int


def coded_fields(fields, context: bool = True) -> list[Field]:
    """The non-position fields of a layout ([(name, bits)]) in layout order, with their contexts (`context` False:
    every field order 0, a variant bench.dyna_context measures)."""
    top: dict[str, int] = {}
    out = []
    for name, bits in fields:
        if name in POSITION_FIELDS:
            continue
        a = min(int(bits), ADAPTIVE_BITS)
        ctx = CONTEXT.get(name) if context else None
        ctx = ctx if ctx in top else None  # only a field coded before this one
        out.append(Field(name, int(bits), a, ctx, top.get(ctx, 0)))
        top[name] = a
    return out


class Models:
    """The adaptive count tables of a file's DYNA chunks: one for the Morton delta's bit length, one per coded field
    (a row per context value). They start at zero at the file's first DYNA chunk and carry over from chunk to
    chunk in file order, so an encoder and a decoder each keep one for the whole file."""

    def __init__(self, fields, context: bool = True):
        self.fields = coded_fields(fields, context)
        self.pos_bits = int(dict(fields)["px"])
        self.tables = {"pos": np.zeros((1, 3 * self.pos_bits + 1), dtype=np.int64)}
        for f in self.fields:
            self.tables[f.name] = np.zeros((1 << f.context_bits if f.context else 1, 1 << f.adaptive), np.int64)

    def update(self, name: str, ctx: int, s: int) -> None:
        row = self.tables[name][ctx]
        row[s] += 1
        if row.sum() >= RESCALE_AT:
            row >>= 1


# ---------------------------------------------------------------------------------------------- encoder
def _groups(ctx: np.ndarray):
    for v in np.unique(ctx):
        yield int(v), np.flatnonzero(ctx == v)


def _adaptive_steps(table: np.ndarray, ctx: np.ndarray, sym: np.ndarray):
    """The frequency table of every symbol of a sequence coded adaptively with `table` (updated as it goes), in
    steps: yields (start, end, rows) with rows[i] the table symbol start + i is coded with. A step ends early at
    the symbol whose update rescales its context."""
    n, start = len(sym), 0
    while start < n:
        end = min(n, start + PIECE)
        c = ctx[start:end]
        occ = np.zeros(end - start, dtype=np.int64)  # earlier symbols of the same context in this step
        for _, idx in _groups(c):
            occ[idx] = np.arange(len(idx))
        hit = np.flatnonzero(table.sum(1)[c] + occ + 1 >= RESCALE_AT)
        if len(hit):
            end = start + int(hit[0]) + 1
            c = c[: end - start]
        s = sym[start:end]
        before = table[c]
        for _, idx in _groups(c):
            onehot = np.zeros((len(idx), table.shape[1]), dtype=np.int64)
            onehot[np.arange(len(idx)), s[idx]] = 1
            before[idx] += np.cumsum(onehot, 0) - onehot
        yield start, end, frequencies(before)
        np.add.at(table, (c, s), 1)
        if len(hit):
            table[c[-1]] >>= 1
        start = end


def _raw_pieces(values: np.ndarray, nbits: np.ndarray):
    """Raw `nbits`-bit values -> their pieces in stream order (record by record, high piece first): (piece values,
    piece widths m <= RAW_PIECE, the record of each piece, the bits below each piece in its record)."""
    nbits = np.asarray(nbits, dtype=np.int64)
    npieces = (nbits + RAW_PIECE - 1) // RAW_PIECE
    rec = np.repeat(np.arange(len(nbits)), npieces)
    j = np.arange(len(rec)) - np.repeat(np.cumsum(npieces) - npieces, npieces)  # piece index inside its record
    left = nbits[rec] - RAW_PIECE * j  # bits not yet coded before this piece
    m = np.minimum(left, RAW_PIECE)
    shift = (left - m).astype(np.uint64)
    vals = (np.asarray(values, dtype=np.uint64)[rec] >> shift) & ((np.uint64(1) << m.astype(np.uint64)) - np.uint64(1))
    return vals, m, rec, shift


def _bit_length(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.uint64)
    n = np.zeros(len(x), dtype=np.int64)
    for b in range(64):
        n += (x >> np.uint64(b)) > 0
    return n


class _Encoder:
    def __init__(self, cost: dict | None):
        self.enc, self.cost = _RangeEncoder(), cost

    def adaptive(self, name: str, table: np.ndarray, ctx: np.ndarray, sym: np.ndarray) -> None:
        for start, end, rows in _adaptive_steps(table, ctx, sym):
            s = sym[start:end]
            self.enc.encode(s.astype(np.int32), _Categorical(perfect=False), (rows - 1).astype(np.float64))
            if self.cost is not None:
                p = rows[np.arange(len(s)), s]
                self.cost[name] = self.cost.get(name, 0.0) + float(np.sum(PRECISION - np.log2(p)))

    def raw(self, name: str, values: np.ndarray, nbits: np.ndarray) -> None:
        vals, m, _, _ = _raw_pieces(values, nbits)
        if len(vals):
            self.enc.encode(vals.astype(np.int32), _Uniform(), (1 << m).astype(np.int32))
        if self.cost is not None:
            self.cost[name] = self.cost.get(name, 0.0) + float(m.sum())


def encode_chunk(models: Models, delta: np.ndarray, values: dict[str, np.ndarray], cost: dict | None = None):
    """One DYNA chunk's records (Morton deltas, the stored integer of every field, in file order) -> the words of its
    range-coded stream (uint32), updating `models`. `cost`: adds each part's ideal code length in bits under the
    models (keys `pos`, `pos raw`, each field name; a field's raw low bits under `NAME raw`)."""
    e = _Encoder(cost)
    n = _bit_length(delta)
    zero = np.zeros(len(n), dtype=np.int64)
    e.adaptive("pos", models.tables["pos"], zero, n)
    e.raw("pos raw", delta, np.maximum(n - 1, 0))
    residuals: dict[str, np.ndarray] = {}
    for f in models.fields:
        v = np.asarray(values[f.name], dtype=np.uint64)
        low = f.bits - f.adaptive
        top = (v >> np.uint64(low)).astype(np.int64)
        residuals[f.name] = (top - np.concatenate([[0], top[:-1]])) & ((1 << f.adaptive) - 1)
        ctx = residuals[f.context] if f.context else zero
        e.adaptive(f.name, models.tables[f.name], ctx, residuals[f.name])
        if low:
            e.raw(f"{f.name} raw", v, np.full(len(v), low))
    return e.enc.get_compressed().astype(np.uint32)


# ---------------------------------------------------------------------------------------------- decoder
class _Decoder:
    """constriction's decoder plus the count of words it reads (2 to start, one per renormalization: the range of
    the coder, tracked here with the same integer steps)."""

    def __init__(self, words: np.ndarray):
        self.dec = _RangeDecoder(np.ascontiguousarray(words, dtype=np.uint32))
        self.range, self.reads = (1 << 64) - 1, 2

    def _step(self, freq: int) -> None:
        self.range = (self.range >> PRECISION) * freq
        if self.range < 1 << 32:
            self.range <<= 32
            self.reads += 1

    def adaptive(self, models: Models, name: str, ctx: np.ndarray) -> np.ndarray:
        table = models.tables[name]
        out = np.zeros(len(ctx), dtype=np.int64)
        for i, c in enumerate(ctx.tolist()):
            f = frequencies(table[c])
            try:
                s = self.dec.decode(_Categorical((f - 1).astype(np.float64), perfect=False))
            except AssertionError:
                raise StreamError(
                    "symbol", f"symbol {name} of record {i} out of range (not a stream of this chunk)"
                ) from None
            self._step(int(f[s]))
            out[i] = s
            models.update(name, c, s)
        return out

    def raw(self, name: str, nbits: np.ndarray) -> np.ndarray:
        """Values of `nbits` raw bits each (uint64)."""
        _, m, rec, shift = _raw_pieces(np.zeros(len(nbits), dtype=np.uint64), nbits)
        out = np.zeros(len(nbits), dtype=np.uint64)
        if not len(m):
            return out
        try:
            vals = self.dec.decode(_Uniform(), (1 << m).astype(np.int32))
        except AssertionError:
            raise StreamError("symbol", f"raw bits of {name} out of range (not a stream of this chunk)") from None
        for w in m.tolist():
            self._step(TOTAL >> w)
        np.bitwise_or.at(out, rec, np.asarray(vals, dtype=np.uint64) << shift)
        return out


def decode_chunk(models: Models, words: np.ndarray, count: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The words of one DYNA chunk's stream -> (Morton deltas, the stored integer of every coded field), both
    uint64 in file order, updating `models`. Raises StreamError: a symbol out of range, more words needed than the
    stream holds (at most one word past its end reads as 0), or a word after the last symbol that is not 0."""
    d = _Decoder(words)
    zero = np.zeros(count, dtype=np.int64)
    n = d.adaptive(models, "pos", zero)
    below = d.raw("pos", np.maximum(n - 1, 0))
    lead = np.where(n > 0, np.uint64(1) << np.maximum(n - 1, 0).astype(np.uint64), np.uint64(0))
    delta = lead | below
    values: dict[str, np.ndarray] = {}
    residuals: dict[str, np.ndarray] = {}
    for f in models.fields:
        ctx = residuals[f.context] if f.context else zero
        residuals[f.name] = d.adaptive(models, f.name, ctx)
        top = np.cumsum(residuals[f.name]) & ((1 << f.adaptive) - 1)  # the running sum mod 2^a
        low = f.bits - f.adaptive
        v = top.astype(np.uint64) << np.uint64(low)
        if low:
            v |= d.raw(f.name, np.full(count, low))
        values[f.name] = v
    held = len(words)
    if d.reads > held + 1:
        raise StreamError("truncated", f"the symbols need {d.reads} words, the stream holds {held}")
    rest = np.flatnonzero(np.asarray(words[d.reads :]) != 0)
    if len(rest):
        j = d.reads + int(rest[0])
        raise StreamError("padding", f"word {j} after the last symbol is {int(words[j])}, not 0", word=j)
    return delta, values
