"""Morton (Z-order) curves: the order of records into blocks (`_block_order`) and v2's Morton code of a record's
px py pz (`morton3`, `unmorton3`)."""

from __future__ import annotations

import numpy as np

from worldsplat.gaussians.wsplat.spec import FAR_FACTOR, MAX_POS_BITS_V2


def _morton_order(p: np.ndarray) -> np.ndarray:
    """Order points along a 3D Morton curve so consecutive blocks are spatially compact (small boxes)."""
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = p.min(0), p.max(0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-9) * 1023).astype(np.uint64)
    code = np.zeros(len(p), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def _block_order(p: np.ndarray) -> np.ndarray:
    """Morton order, with the far outliers (farther than FAR_FACTOR x the median distance from the median point,
    e.g. a sky shell 300 m out around a street) ordered after the rest on their own curve: a block that mixed
    the two would get a position box hundreds of metres wide and lose the street's precision."""
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    d = np.linalg.norm(p - np.median(p, axis=0), axis=1)
    far = d > FAR_FACTOR * max(float(np.median(d)), 1e-9)
    near_idx, far_idx = np.flatnonzero(~far), np.flatnonzero(far)
    return np.concatenate([near_idx[_morton_order(p[near_idx])], far_idx[_morton_order(p[far_idx])]])


_SPREAD = (  # part-1-by-2 bit spreading of a 21-bit integer (shift, mask): bit i -> bit 3i
    (32, 0x1F00000000FFFF),
    (16, 0x1F0000FF0000FF),
    (8, 0x100F00F00F00F00F),
    (4, 0x10C30C30C30C30C3),
    (2, 0x1249249249249249),
)


def _spread3(v: np.ndarray) -> np.ndarray:
    x = v.astype(np.uint64) & np.uint64((1 << 21) - 1)
    for shift, mask in _SPREAD:
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def _compact3(code: np.ndarray) -> np.ndarray:
    """The inverse of _spread3: bits 0, 3, 6, ... of `code` -> bits 0, 1, 2, ..."""
    shifts = [shift for shift, _ in reversed(_SPREAD)]  # 2, 4, 8, 16, 32
    masks = [mask for _, mask in reversed(_SPREAD)][1:] + [(1 << 21) - 1]  # the mask after each step
    x = code & np.uint64(_SPREAD[-1][1])
    for shift, mask in zip(shifts, masks):
        x = (x | (x >> np.uint64(shift))) & np.uint64(mask)
    return x


def morton3(x: np.ndarray, y: np.ndarray, z: np.ndarray, bits: int) -> np.ndarray:
    """Interleave three `bits`-bit integers (bits <= 21): bit i of x -> bit 3i, of y -> 3i + 1, of z -> 3i + 2."""
    assert bits <= MAX_POS_BITS_V2
    keep = np.uint64((1 << bits) - 1)
    return _spread3(x & keep) | (_spread3(y & keep) << np.uint64(1)) | (_spread3(z & keep) << np.uint64(2))


def unmorton3(code: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    keep = np.uint64((1 << bits) - 1)
    return tuple(_compact3(code >> np.uint64(k)) & keep for k in range(3))
