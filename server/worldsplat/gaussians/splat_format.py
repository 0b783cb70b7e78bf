"""The antimatter15 `.splat` layout (web/docs/gaussians.md, "Files in and out"): no header, 32 bytes per
Gaussian, little-endian: position 3 x f32, scale 3 x f32 (linear), colour + opacity 4 x u8, rotation 4 x u8 (w x y z,
`(q + 1) / 2 x 255`, normalized on reading). Coordinates as they are, like the PLY export.
"""

from __future__ import annotations

import numpy as np

from worldsplat.gaussians.fileformat import FormatError, canonical_quats, check_count, check_finite
from worldsplat.gaussians.types import Gaussians

FMT = "splat"
RECORD = np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])


def encode(g: Gaussians) -> bytes:
    a = {k: v.astype(np.float64) for k, v in g.numpy().items() if k != "extras"}
    n = len(a["means"])
    rec = np.zeros(n, dtype=RECORD)
    rec["pos"] = a["means"]
    rec["scale"] = a["scales"]
    rgba = np.concatenate([a["colors"], a["opacities"][:, None]], 1)
    rec["rgba"] = np.clip(np.round(rgba * 255), 0, 255)
    rec["rot"] = np.clip(np.round((canonical_quats(a["quats"]) + 1) / 2 * 255), 0, 255)
    return rec.tobytes()


def decode(data: bytes) -> Gaussians:
    data = bytes(data)
    if len(data) == 0:
        raise FormatError(FMT, 0, "file", "empty: no Gaussian")
    if len(data) % RECORD.itemsize:
        n = len(data) // RECORD.itemsize
        raise FormatError(
            FMT, n * RECORD.itemsize, f"record[{n}]", f"truncated: {len(data) % RECORD.itemsize} of 32 bytes"
        )
    n = check_count(FMT, len(data) // RECORD.itemsize, 0, "file length")
    rec = np.frombuffer(data, dtype=RECORD, count=n)
    check_finite(FMT, rec["pos"], "position", 0, RECORD.itemsize)
    check_finite(FMT, rec["scale"], "scale", 12, RECORD.itemsize)
    scales = rec["scale"].astype(np.float64)
    if (scales < 0).any():
        i = int(np.argmax((scales < 0).any(1)))
        raise FormatError(FMT, i * RECORD.itemsize + 12, f"scale[{i}]", "negative (.splat scales are linear)")
    quats = canonical_quats(rec["rot"].astype(np.float64) / 255 * 2 - 1)
    rgba = rec["rgba"].astype(np.float64) / 255
    return Gaussians.from_numpy(rec["pos"].astype(np.float64), quats, scales, rgba[:, 3], rgba[:, :3])
