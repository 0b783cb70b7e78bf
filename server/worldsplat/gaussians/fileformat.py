"""What every Gaussian file reader shares (PLY, glTF KHR_gaussian_splatting, SPZ, SOG, .splat;
web/docs/gaussians.md, "Files in and out"): the one error type, naming the format, the field and the byte offset,
and the checks that keep a reader from trusting a declared size before the bytes behind it are there.

Offsets are into the file as given, except inside a compressed container, where `where` says what they count
(`SPZ stream 'positions' byte 90` is the 90th byte of that stream once decompressed).
"""

from __future__ import annotations

import numpy as np

from worldsplat_models.geometry import normalize_quaternion

SH_C0 = 0.28209479177387814
# The most Gaussians any import accepts: 16.7M (a 1M-Gaussian scene is a large one), so a declared count can
# never make a reader allocate more than ~1 GiB even where the bytes behind it are compressed.
MAX_GAUSSIANS = 1 << 24


class FormatError(ValueError):
    """A malformed Gaussian file: `fmt` (ply, glb, spz, sog, splat), byte `offset`, the `field` at fault."""

    def __init__(self, fmt: str, offset: int, field: str, message: str, where: str = "file"):
        self.fmt, self.offset, self.field, self.where, self.detail = fmt, int(offset), field, where, message
        at = f"offset {offset}" if where == "file" else f"{where} byte {offset}"
        super().__init__(f"{fmt}: {at}: {field}: {message}")


def check_count(fmt: str, n: int, offset: int, field: str) -> int:
    if n < 0:
        raise FormatError(fmt, offset, field, f"{n} is negative")
    if n > MAX_GAUSSIANS:
        raise FormatError(fmt, offset, field, f"{n} Gaussians is more than this reader takes ({MAX_GAUSSIANS})")
    return n


def need(fmt: str, have: int, offset: int, size: int, field: str, where: str = "file") -> None:
    """Raise unless `size` bytes from `offset` lie inside the `have` bytes present (before anything is read)."""
    if offset < 0 or size < 0 or offset + size > have:
        raise FormatError(
            fmt, offset, field, f"needs {size} bytes from here, the data has {max(0, have - offset)}", where=where
        )


def check_finite(fmt: str, values: np.ndarray, field: str, base: int, stride: int, where: str = "file") -> None:
    """Raise at the first non-finite value of `values` (rows of a field stored `stride` bytes apart from `base`)."""
    v = values.reshape(len(values), -1)
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise FormatError(fmt, base + i * stride, f"{field}[{i}]", f"not finite ({v[i].tolist()})", where=where)


def writable_arrays(fmt: str, g, count_offset: int = 0, count_field: str = "count") -> dict[str, np.ndarray]:
    """What a writer takes from Gaussians `g`: its fields (extras aside) as float64 arrays, refused with a
    FormatError when there are more than MAX_GAUSSIANS (the count field at `count_offset`) or a value is not finite."""
    a = {k: v.astype(np.float64) for k, v in g.numpy().items() if k != "extras"}
    check_count(fmt, len(a["means"]), count_offset, count_field)
    for k, v in a.items():
        check_finite(fmt, v, f"Gaussians.{k}", 0, 0)
    return a


def canonical_quats(q: np.ndarray) -> np.ndarray:
    """Quaternions wxyz normalized; zero ones (|q| < 1e-12) become the identity."""
    return normalize_quaternion(q, 1e-12)
