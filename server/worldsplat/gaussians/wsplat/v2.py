"""v2 chunk bodies (web/docs/wsplat-v2.md): the boxes, then one zstd byte plane per section, records Morton-ordered
inside each block; or, for DYNA chunks, one stream of the range coder (`context_coder`)."""

from __future__ import annotations

import math
import struct

import numpy as np
import zstandard

from worldsplat.gaussians import context_coder
from worldsplat.gaussians.wsplat.layout import Layout
from worldsplat.gaussians.wsplat.morton import morton3, unmorton3
from worldsplat.gaussians.wsplat.quantise import dequantize, quantize_block
from worldsplat.gaussians.wsplat.spec import BLOCK_HEADER, MAX_RATIO, SEARCH_LEVEL, ZSTD_LEVEL, WsplatError


def v2_planes(layout: Layout) -> list[tuple[str, int]]:
    """The byte planes of a v2 chunk after its boxes, in order: (name, byte index). `pos` is the Morton-code delta of
    px py pz (ceil(3 bits / 8) bytes), then every other layout field in layout order (ceil(bits / 8) bytes each)."""
    bits = dict(layout.fields)
    planes = [("pos", k) for k in range((3 * bits["px"] + 7) // 8)]
    for f, b in layout.fields:
        if f not in ("px", "py", "pz"):
            planes += [(f, k) for k in range((b + 7) // 8)]
    return planes


def max_window(size: int) -> int:
    """The largest zstd window a section of `size` bytes may declare: its size rounded up to a power of two, at
    least 1 KiB (what zstd writes for a frame whose size it knows; a decoder never allocates more)."""
    return max(1 << 10, 1 << max(0, size - 1).bit_length())


def v2_raw_size(count: int, layout: Layout, block_size: int) -> int:
    """Decoded bytes of a v2 chunk's sections (boxes + one byte per record per plane)."""
    return math.ceil(count / block_size) * BLOCK_HEADER + count * len(v2_planes(layout))


def _section_label(name: str, k: int, layout: Layout) -> str:
    bits = dict(layout.fields)
    width = (3 * bits["px"] + 7) // 8 if name == "pos" else (bits[name] + 7) // 8
    return name if width == 1 else f"{name}[{k}]"


def v2_records(
    a: dict[str, np.ndarray], layout: Layout, block_size: int, pos_precision: float | None = None
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Sanitized Gaussians (block order) -> what a v2 chunk stores: the blocks' boxes ((B, 8) float32), and the
    records sorted by the Morton code of (px, py, pz) inside each block: their Morton deltas (the first of each block
    from 0), the stored integer of every layout field (uint64), and the row of `a` of each stored record (what a
    decoder's record i is; v4's SCOL chunk names statics in that order). `pos_precision`: as `quantize_block`."""
    pb = dict(layout.fields)["px"]
    boxes, codes, rows, vals = [], [], [], {f: [] for f, _ in layout.fields}
    for s in range(0, len(a["means"]), block_size):
        box, v = quantize_block({k: x[s : s + block_size] for k, x in a.items()}, layout, pos_precision)
        code = morton3(v["px"], v["py"], v["pz"], pb)
        order = np.argsort(code, kind="stable")
        code = code[order]
        codes.append(np.diff(code, prepend=np.uint64(0)))
        rows.append(s + order)
        for f in vals:
            vals[f].append(v[f][order])
        boxes.append(box)
    delta = np.concatenate(codes) if codes else np.zeros(0, dtype=np.uint64)
    cat = {f: (np.concatenate(x) if x else np.zeros(0, dtype=np.uint64)) for f, x in vals.items()}
    row = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    return np.asarray(boxes, dtype=np.float32).reshape(-1, 8), delta, cat, row


def encode_dyna_range(
    a: dict[str, np.ndarray],
    layout: Layout,
    block_size: int,
    models: context_coder.Models,
    pos_precision: float | None = None,
) -> bytes:
    """Sanitized Gaussians (block order) -> a range-coded DYNA chunk's payload after its frame and count: the boxes
    (B x 32 bytes, as v1's block headers), the stream's length in words (u32), its words (u32). `models` carry over
    from the file's previous DYNA chunks (and are updated). Records as `v2_records`. A chunk whose records would
    decode to more than MAX_RATIO x its payload (degenerate data: every Gaussian the same) gets zero words after its
    stream (a decoder checks that the words after the last symbol are 0)."""
    boxes, delta, cat, _ = v2_records(a, layout, block_size, pos_precision)
    words = context_coder.encode_chunk(models, delta, cat)
    raw = v2_raw_size(len(delta), layout, block_size)
    size = 8 + boxes.nbytes + 4 + 4 * len(words)  # + the DYNA frame and count
    pad = max(0, -(-(raw - MAX_RATIO * size) // (4 * MAX_RATIO)))
    words = np.concatenate([words, np.zeros(pad, dtype=np.uint32)])
    return boxes.astype("<f4").tobytes() + struct.pack("<I", len(words)) + words.astype("<u4").tobytes()


def encode_blocks_v2(
    a: dict[str, np.ndarray],
    layout: Layout,
    block_size: int,
    level: int = ZSTD_LEVEL,
    search: int | None = SEARCH_LEVEL,
    pos_precision: float | None = None,
) -> tuple[bytes, np.ndarray]:
    """Sanitized Gaussians (block order) -> the sections of a v2 chunk: boxes, then one byte plane per section, each
    `filter u8, length u32, zstd frame` (`encode_sections`), and the row of `a` of each stored record (`v2_records`).
    Records are sorted by the Morton code of (px, py, pz) inside each block. `pos_precision`: as
    `quantize_block`."""
    boxes, delta, cat, row = v2_records(a, layout, block_size, pos_precision)
    planes = [("boxes", 0, np.frombuffer(boxes.astype("<f4").tobytes(), dtype=np.uint8))]
    planes += [(f, k, byte_plane(delta if f == "pos" else cat[f], k)) for f, k in v2_planes(layout)]
    raw = v2_raw_size(len(delta), layout, block_size)
    return encode_sections(planes, layout, raw, 4, level, search), row  # + the STAT count (DYNA: + 8)


def byte_plane(x: np.ndarray, k: int) -> np.ndarray:
    """Byte k of every integer of x."""
    return ((x >> np.uint64(8 * k)) & np.uint64(255)).astype(np.uint8)


def encode_sections(
    planes: list[tuple[str, int, np.ndarray]],
    layout: Layout,
    raw: int,
    head: int,
    level: int = ZSTD_LEVEL,
    search: int | None = SEARCH_LEVEL,
) -> bytes:
    """v2 sections of byte planes (name, byte index, plane), each `filter u8, length u32, zstd frame`: the encoder
    keeps the smallest of the filtered planes (boxes: never filtered; r / b also minus the g plane's same byte),
    chosen at zstd level `search` (None: each candidate at `level`), then compressed at `level`. Every choice decodes
    to the same integers. `raw`: the bytes the sections decode to; `head`: the payload's bytes before them. Sections
    that would compress past MAX_RATIO x the payload (degenerate data, e.g. every Gaussian the same) are stored in
    raw zstd blocks (still one valid frame per section, decoded by any zstd decoder)."""

    def coder(lv: int):
        return zstandard.ZstdCompressor(level=lv, write_checksum=False, write_content_size=True, write_dict_id=False)

    zc = coder(level)
    zs = coder(search) if search is not None and search != level else None
    g_bytes = (dict(layout.fields)["g"] + 7) // 8
    g_plane = {k: x for f, k, x in planes if f == "g"}
    out = bytearray()
    for f, k, plane in planes:
        if f == "boxes":
            box = zc.compress(plane.tobytes())
            out += struct.pack("<BI", 0, len(box)) + box
            continue
        cands = [(0, plane)]
        if f in ("r", "b") and k < g_bytes:  # minus the green plane's same byte
            cands.append((2, plane - g_plane[k]))
        cands += [(c + 1, np.diff(x, prepend=np.uint8(0)).astype(np.uint8)) for c, x in cands]  # then delta
        if zs is None:
            filt, best = min(((c, zc.compress(x.tobytes())) for c, x in cands), key=lambda t: len(t[1]))
        else:
            filt, x = min(cands, key=lambda t: len(zs.compress(t[1].tobytes())))
            best = zc.compress(x.tobytes())
        out += struct.pack("<BI", filt, len(best)) + best
    if raw > MAX_RATIO * (len(out) + head):
        out = bytearray()
        for _, _, plane in planes:
            frame = raw_zstd_frame(plane.tobytes())
            out += struct.pack("<BI", 0, len(frame)) + frame
    return bytes(out)


def raw_zstd_frame(data: bytes) -> bytes:
    """`data` as one zstd frame of raw (uncompressed) blocks, RFC 8878: single segment, 4-byte content size, no
    checksum; blocks of at most 128 KiB."""
    out = bytearray(struct.pack("<IBI", 0xFD2FB528, 0xA0, len(data)))  # FCS flag 2 (4 bytes) | single segment
    step = 1 << 17
    starts = range(0, len(data), step) if data else [0]
    for i in starts:
        block = data[i : i + step]
        last = i + step >= len(data)
        out += (len(block) << 3 | int(last)).to_bytes(3, "little") + block  # block type 0: raw
    return bytes(out)


def decode_blocks_v2(
    payload: memoryview, pos: int, count: int, layout: Layout, block_size: int, base: int, name: str
) -> dict[str, np.ndarray]:
    """The sections of a v2 chunk from payload[pos:] -> float64 Gaussians. Every size is checked against the bytes
    present before anything is decompressed; a section decompresses to exactly its size or is refused."""
    nblocks = math.ceil(count / block_size)
    planes = [("boxes", 0, nblocks * BLOCK_HEADER)] + [(f, k, count) for f, k in v2_planes(layout)]
    raw, where = decode_sections(payload, pos, planes, layout, base, name)
    boxes = raw[("boxes", 0)].view("<f4").reshape(nblocks, 8).astype(np.float64)
    _check_boxes(boxes, where["boxes"], name)
    v = field_values(raw, layout, [f for f, _ in layout.fields if f not in ("px", "py", "pz")], count, where, name)
    pb = dict(layout.fields)["px"]
    d = np.zeros(count, dtype=np.uint64)
    for k in range((3 * pb + 7) // 8):
        d |= raw[("pos", k)].astype(np.uint64) << np.uint64(8 * k)
    v["px"], v["py"], v["pz"] = _morton_positions(d, block_size, pb, where["pos"], name)
    box = np.repeat(boxes, block_size, axis=0)[:count]
    return dequantize(v, box, layout)


def decode_sections(
    payload: memoryview, pos: int, planes: list[tuple[str, int, int]], layout: Layout, base: int, name: str
) -> tuple[dict[tuple[str, int], np.ndarray], dict[str, int]]:
    """v2 sections from payload[pos:] to the chunk's end: one per plane (name, byte index, size), each
    decompressed to exactly its size, its filters undone (r / b minus g: once every section is in). Returns the
    planes and the absolute offset of each field's first section (errors about its values)."""
    raw: dict[tuple[str, int], np.ndarray] = {}
    where: dict[str, int] = {}
    minus_g: list[tuple[str, int]] = []  # r / b planes stored minus the g plane's same byte
    for f, k, size in planes:
        where.setdefault(f, base + pos)
        label = f"{name}.{'boxes' if f == 'boxes' else _section_label(f, k, layout)}"
        if pos + 5 > len(payload):
            raise WsplatError("bad_payload", base + pos, label, "section header past the end of the chunk")
        filt, clen = struct.unpack_from("<BI", payload, pos)
        allowed = 0 if f == "boxes" else 3 if f in ("r", "b") and k < (dict(layout.fields)["g"] + 7) // 8 else 1
        if filt > allowed:
            raise WsplatError(
                "bad_payload",
                base + pos,
                f"{label}.filter",
                f"filter {filt} (0: none, 1: delta, 2/3: minus g (+ delta))",
            )
        if pos + 5 + clen > len(payload):
            raise WsplatError(
                "bad_payload",
                base + pos + 1,
                f"{label}.length",
                f"{clen} bytes, the chunk has {len(payload) - pos - 5}",
            )
        frame = bytes(payload[pos + 5 : pos + 5 + clen])
        try:
            fp = zstandard.get_frame_parameters(frame)
        except zstandard.ZstdError as e:
            raise WsplatError("bad_payload", base + pos + 5, label, f"not a zstd frame: {e}") from None
        if fp.content_size != size:
            raise WsplatError(
                "bad_payload",
                base + pos + 5,
                label,
                f"zstd frame declares {fp.content_size} bytes, the section is {size}",
            )
        window = max_window(size)
        if fp.window_size > window:
            raise WsplatError("bad_payload", base + pos + 5, label, f"zstd window {fp.window_size} > {window} bytes")
        dobj = zstandard.ZstdDecompressor(max_window_size=window).decompressobj()
        try:
            data = dobj.decompress(frame)
        except zstandard.ZstdError as e:
            raise WsplatError("bad_payload", base + pos + 5, label, f"zstd: {e}") from None
        if len(data) != size or not dobj.eof or dobj.unused_data:
            raise WsplatError("bad_payload", base + pos + 5, label, "zstd frame is not exactly one whole section")
        x = np.frombuffer(data, dtype=np.uint8)
        raw[(f, k)] = np.cumsum(x, dtype=np.uint8) if filt in (1, 3) else x
        if filt >= 2:
            minus_g.append((f, k))
        pos += 5 + clen
    if pos != len(payload):
        raise WsplatError(
            "bad_payload", base + pos, f"{name}.length", f"{len(payload) - pos} bytes after the last section"
        )
    for key in minus_g:
        raw[key] = raw[key] + raw[("g", key[1])]  # mod 256
    return raw, where


def field_values(
    raw: dict[tuple[str, int], np.ndarray], layout: Layout, fields: list[str], count: int, where: dict, name: str
) -> dict[str, np.ndarray]:
    """The stored integer of each of `fields` from its byte planes, each checked to be < 2^bits."""
    bits = dict(layout.fields)
    v: dict[str, np.ndarray] = {}
    for f in fields:
        b = bits[f]
        x = np.zeros(count, dtype=np.uint64)
        for k in range((b + 7) // 8):
            x |= raw[(f, k)].astype(np.uint64) << np.uint64(8 * k)
        if (x >> np.uint64(b)).any():
            i = int(np.argmax(x >> np.uint64(b)))
            raise WsplatError("bad_payload", where[f], f"{name}.{f}", f"record {i}: value {int(x[i])} >= 2^{b}")
        v[f] = x
    return v


def _morton_positions(d: np.ndarray, block_size: int, pb: int, at: int, name: str):
    """Morton deltas (block by block, each block's first from 0) -> px, py, pz; `at`: the offset errors name."""
    count = len(d)
    limit = np.uint64((1 << (3 * pb)) - 1)
    code = np.empty(count, dtype=np.uint64)
    for blk in range(math.ceil(count / block_size)):
        s, e = blk * block_size, min(count, (blk + 1) * block_size)
        part = d[s:e]
        cs = np.cumsum(part, dtype=np.uint64)  # exact while every delta and partial sum is <= limit < 2^63
        if (part > limit).any() or (cs > limit).any():
            raise WsplatError(
                "bad_payload", at, f"{name}.pos", f"block {blk}: Morton deltas add up past 2^{3 * pb} - 1"
            )
        code[s:e] = cs
    return unmorton3(code, pb)


def _check_boxes(boxes: np.ndarray, at: int, name: str) -> None:
    bad = ~np.isfinite(boxes).all(1) | (boxes[:, 0:3] > boxes[:, 3:6]).any(1) | (boxes[:, 6] > boxes[:, 7])
    if bad.any():
        b = int(np.argmax(bad))
        raise WsplatError("bad_payload", at, f"{name}.boxes", f"block {b}: box not finite or lo > hi")


def decode_dyna_range(
    payload: memoryview, pos: int, count: int, layout: Layout, block_size: int, base: int, models: context_coder.Models
) -> dict[str, np.ndarray]:
    """A range-coded DYNA chunk from payload[pos:] (its boxes, the stream's length in words, the words) -> float64
    Gaussians, decoded with the file's `models` (carried from its earlier DYNA chunks, updated here). Sizes are
    checked against the bytes present before anything is decoded (the count was bounded by the caller)."""
    nblocks = math.ceil(count / block_size)
    boxes_at = pos
    if pos + nblocks * BLOCK_HEADER > len(payload):
        raise WsplatError(
            "bad_payload",
            base + pos,
            "DYNA.boxes",
            f"{nblocks} boxes ({nblocks * BLOCK_HEADER} bytes) past the end of the chunk",
        )
    pos += nblocks * BLOCK_HEADER
    if pos + 4 > len(payload):
        raise WsplatError("bad_payload", base + pos, "DYNA.words", "the stream's length past the end of the chunk")
    (nwords,) = struct.unpack_from("<I", payload, pos)
    left = len(payload) - pos - 4
    if 4 * nwords > left:
        raise WsplatError(
            "bad_payload", base + pos, "DYNA.words", f"{nwords} words, the chunk has {left} bytes after it"
        )
    stream_at = pos + 4
    if 4 * nwords < left:
        end = stream_at + 4 * nwords
        raise WsplatError("bad_payload", base + end, "DYNA.length", f"{left - 4 * nwords} bytes after the stream")
    boxes = np.frombuffer(payload[boxes_at:pos], dtype="<f4").reshape(nblocks, 8).astype(np.float64)
    _check_boxes(boxes, base + boxes_at, "DYNA")
    words = np.frombuffer(payload[stream_at:], dtype="<u4")
    try:
        delta, v = context_coder.decode_chunk(models, words, count)
    except context_coder.StreamError as e:
        at = {"symbol": stream_at, "truncated": len(payload), "padding": stream_at + 4 * e.word}[e.what]
        raise WsplatError("bad_payload", base + at, "DYNA.stream", str(e)) from None
    v["px"], v["py"], v["pz"] = _morton_positions(
        delta, block_size, dict(layout.fields)["px"], base + stream_at, "DYNA"
    )
    return dequantize(v, np.repeat(boxes, block_size, axis=0)[:count], layout)
