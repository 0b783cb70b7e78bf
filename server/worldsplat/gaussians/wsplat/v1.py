"""v1 chunk bodies: blocks of a 32-byte box and bit-packed records (web/docs/wsplat-v1.md)."""

from __future__ import annotations

import math

import numpy as np

from worldsplat.gaussians.wsplat.layout import Layout, pack_records, unpack_records
from worldsplat.gaussians.wsplat.quantise import dequantize, quantize_block
from worldsplat.gaussians.wsplat.spec import BLOCK_HEADER, WsplatError


def encode_blocks(
    a: dict[str, np.ndarray], layout: Layout, block_size: int, pos_precision: float | None = None
) -> bytes:
    out = bytearray()
    for s in range(0, len(a["means"]), block_size):
        box, vals = quantize_block({k: v[s : s + block_size] for k, v in a.items()}, layout, pos_precision)
        out += box.astype("<f4").tobytes()
        out += pack_records(vals, layout)
    return bytes(out)


def _empty_arrays() -> dict[str, np.ndarray]:
    return {
        "means": np.zeros((0, 3)),
        "quats": np.zeros((0, 4)),
        "scales": np.zeros((0, 3)),
        "opacities": np.zeros(0),
        "colors": np.zeros((0, 3)),
    }


def decode_blocks(
    payload: memoryview, pos: int, count: int, layout: Layout, block_size: int, base: int, name: str
) -> dict[str, np.ndarray]:
    """Decode `count` v1 records from payload[pos:] (length already checked exactly). `base` = absolute offset of
    payload[0] for error messages."""
    rs = layout.record_size
    parts = []
    left = count
    while left > 0:
        n = min(block_size, left)
        box = np.frombuffer(payload[pos : pos + BLOCK_HEADER], dtype="<f4").astype(np.float64)
        if not np.all(np.isfinite(box)) or np.any(box[0:3] > box[3:6]) or box[6] > box[7]:
            raise WsplatError("bad_payload", base + pos, f"{name}.block", "box not finite or lo > hi")
        pos += BLOCK_HEADER
        parts.append(dequantize(unpack_records(payload[pos : pos + n * rs], n, layout), box, layout))
        pos += n * rs
        left -= n
    if not parts:
        return _empty_arrays()
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _payload_size(count: int, layout: Layout, block_size: int) -> int:
    return math.ceil(count / block_size) * BLOCK_HEADER + count * layout.record_size
