"""v4's SCOL payload (web/docs/wsplat-v4.md): new colours of a run of statics sent before, in decoded order, as the
static layout stores colour (its r, g, b bits, v2's byte planes and filters, zstd)."""

from __future__ import annotations

import struct

import numpy as np

from worldsplat.gaussians.wsplat.layout import Layout
from worldsplat.gaussians.wsplat.quantise import dequantize_colours, quantize_colours
from worldsplat.gaussians.wsplat.spec import MAX_RATIO, SEARCH_LEVEL, ZSTD_LEVEL, WsplatError
from worldsplat.gaussians.wsplat.v2 import byte_plane, decode_sections, encode_sections, field_values, v2_planes

SCOL_HEADER = 8  # first u32, count u32


def colour_planes(layout: Layout) -> list[tuple[str, int]]:
    """A SCOL chunk's byte planes: v2's planes of the layout's r, g, b fields, in layout order."""
    return [(f, k) for f, k in v2_planes(layout) if f in ("r", "g", "b")]


def encode_scol(first: int, colours: np.ndarray, layout: Layout, level=ZSTD_LEVEL, search=SEARCH_LEVEL) -> bytes:
    """The SCOL payload of statics `first .. first + len(colours)` (decoded order): colours (n, 3) in [0, 1]."""
    v = quantize_colours(np.asarray(colours, dtype=np.float64), layout)
    planes = [(f, k, byte_plane(v[f], k)) for f, k in colour_planes(layout)]
    raw = len(colours) * len(planes)
    return struct.pack("<II", first, len(colours)) + encode_sections(planes, layout, raw, SCOL_HEADER, level, search)


def decode_scol(payload: memoryview, base: int, decoded: int, layout: Layout) -> tuple[int, np.ndarray]:
    """A SCOL payload at file offset `base`, `decoded` statics before it -> (first, colours (count, 3) float64).
    Checks: header length, count >= 1, first + count within the statics decoded so far, count against the bytes
    (MAX_RATIO), then the sections as v2's."""
    if len(payload) < SCOL_HEADER:
        raise WsplatError("bad_payload", base, "SCOL.first", f"payload shorter than its {SCOL_HEADER}-byte header")
    first, count = struct.unpack_from("<II", payload, 0)
    if count < 1:
        raise WsplatError("bad_payload", base + 4, "SCOL.count", "count must be >= 1")
    if first + count > decoded:
        raise WsplatError(
            "count_mismatch", base + 4, "SCOL.count", f"statics {first}..{first + count}, {decoded} decoded before"
        )
    planes = colour_planes(layout)
    if count * len(planes) > MAX_RATIO * len(payload):
        raise WsplatError(
            "bad_payload",
            base + 4,
            "SCOL.count",
            f"count {count} decodes to {count * len(planes)} bytes > {MAX_RATIO} x the chunk's {len(payload)}",
        )
    raw, where = decode_sections(payload, SCOL_HEADER, [(f, k, count) for f, k in planes], layout, base, "SCOL")
    v = field_values(raw, layout, [f for f, _ in layout.fields if f in ("r", "g", "b")], count, where, "SCOL")
    return first, dequantize_colours(v, layout)
