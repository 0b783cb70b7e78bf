"""Quantisation shared by v1 and v2: sanitising Gaussians, canonical and smallest-three rotations, a block's box
(`position_box`), the stored integer of every layout field (`quantize_block`) and back (`dequantize`)."""

from __future__ import annotations

import math

import numpy as np

from worldsplat.gaussians import constants as C
from worldsplat.gaussians.types import Gaussians
from worldsplat.gaussians.wsplat.layout import Layout
from worldsplat.gaussians.wsplat.spec import ISOTROPY_TOL, POS_SIZE_PERCENTILE, Q_CANON
from worldsplat_models.geometry import normalize_quaternion, quaternion_multiply, quaternion_to_matrix


def _canon_steps(bits: int) -> int:
    """Steps of a canonical-rotation component's grid (spec.Q_CANON): 2^bits - 2, so the grid has an exact zero."""
    return (1 << bits) - 2


def _quantize(v: np.ndarray, lo: float, hi: float, bits: int) -> np.ndarray:
    n = (1 << bits) - 1
    span = hi - lo
    if not span > 0:
        return np.zeros(len(v), dtype=np.uint64)
    return np.clip(np.round((v - lo) / span * n), 0, n).astype(np.uint64)


def _smallest_three(q: np.ndarray, bits: dict) -> dict[str, np.ndarray]:
    """Unit quaternions (wxyz) -> qi (index of the largest |component|, made positive) + the other three."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    qi = np.argmax(np.abs(q), axis=1)
    q = q * np.where(q[np.arange(len(q)), qi] < 0, -1.0, 1.0)[:, None]
    rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[qi]
    others = np.take_along_axis(q, rest, axis=1)
    out = {"qi": qi.astype(np.uint64)}
    for k, f in enumerate(("qa", "qb", "qc")):
        n = (1 << bits[f]) - 1
        out[f] = np.clip(np.round((others[:, k] * math.sqrt(2) + 1) / 2 * n), 0, n).astype(np.uint64)
    return out


def _octahedral_rotations() -> np.ndarray:
    """The 24 rotations of the cube as unit quaternions (wxyz, one of each +-q pair)."""
    h, r = 0.5, math.sqrt(0.5)
    out = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    for i in range(4):
        for j in range(i + 1, 4):
            for sign in (1, -1):
                q = [0.0] * 4
                q[i], q[j] = r, sign * r
                out.append(q)
    out += [[h, a * h, b * h, c * h] for a in (1, -1) for b in (1, -1) for c in (1, -1)]
    return np.asarray(out, dtype=np.float64)


CUBE_ROTATIONS = _octahedral_rotations()


def canonical_rotation(q: np.ndarray, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions (N,4) wxyz + scales (N,3) -> the same covariances as q * g (g the cube rotation that brings
    q closest to the identity, made w >= 0) with the scales permuted to match: |x|, |y|, |z| <= sin(pi/8)."""
    # w of q * g is q . (gw, -gx, -gy, -gz): one (N,4) @ (4,24) product picks g, then one product per Gaussian
    k = np.argmax(np.abs(q @ (CUBE_ROTATIONS * [1.0, -1.0, -1.0, -1.0]).T), axis=1)
    out = quaternion_multiply(q, CUBE_ROTATIONS[k])
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    # R(q g) = R(q) R(g); S'^2 = R(g)^T S^2 R(g): axis j of the new frame is old axis argmax_i |R(g)[i, j]|.
    rg = quaternion_to_matrix(CUBE_ROTATIONS)  # (24,3,3)
    perm = np.argmax(np.abs(rg), axis=1)  # (24,3): new axis j <- old axis
    return out, np.take_along_axis(scales, perm[k], axis=1)


def _sanitized_numpy(g: Gaussians, layout: Layout | None = None) -> dict[str, np.ndarray]:
    """Drop rows with non-finite fields or opacity < ALPHA_MIN (the renderer drops them too); clamp the rest;
    canonical rotations for a layout with qx qy qz."""
    return _sanitize(g, layout)[0]


def _sanitize(g: Gaussians, layout: Layout | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """`_sanitized_numpy` and the index in `g` of each row it keeps (a v4 writer recolours the rows it wrote)."""
    a = {k: v.astype(np.float64) for k, v in g.numpy().items() if k != "extras"}
    keep = np.ones(len(g), dtype=bool)
    for v in a.values():
        keep &= np.isfinite(v if v.ndim == 2 else v[:, None]).all(1)
    keep &= np.clip(np.nan_to_num(a["opacities"]), 0, 1) >= C.ALPHA_MIN
    a = {k: v[keep] for k, v in a.items()}
    a["scales"] = np.clip(a["scales"], C.SCALE_MIN, C.SCALE_MAX)
    a["opacities"] = np.clip(a["opacities"], 0, 1)
    a["colors"] = np.clip(a["colors"], 0, 1)
    a["quats"] = normalize_quaternion(a["quats"], C.QUAT_EPS)
    if layout is not None and layout.canonical and len(a["quats"]):
        a["quats"], a["scales"] = canonical_rotation(a["quats"], a["scales"])
    return a, np.flatnonzero(keep)


def is_isotropic(g: Gaussians) -> bool:
    if len(g) == 0:
        return True
    s = g.scales.detach().double().clamp(C.SCALE_MIN, C.SCALE_MAX)
    return bool((s.max(1).values / s.min(1).values <= 1 + ISOTROPY_TOL).all())


def position_box(p: np.ndarray, scales: np.ndarray, bits: tuple[int, int, int], precision: float):
    """The position box of a block whose step is at most `precision` x its Gaussians' size (the
    POS_SIZE_PERCENTILE-th percentile of their middle scale) and the same on the three axes: from the points'
    minimum, (2^bits - 1) steps on each axis, the step never finer than the points' extent needs (their largest
    extent / (2^bits - 1)). A decoder reads it as any box (lo + (hi - lo) * q / (2^bits - 1)); the Morton deltas then
    cost what the Gaussians' size asks, not what the layout's bits allow. p: float32 (n, 3), scales (n, 3)."""
    lo = p.min(0)
    m = np.array([(1 << b) - 1 for b in bits], dtype=np.float64)
    size = float(np.percentile(np.sort(scales, 1)[:, 1], POS_SIZE_PERCENTILE))
    step = max(precision * size, float(((p.max(0) - lo).astype(np.float64) / m).max()))
    hi = np.maximum((lo.astype(np.float64) + step * m).astype(np.float32), p.max(0))  # float32 rounding: hold all
    return lo, hi


def quantize_block(
    blk: dict[str, np.ndarray], layout: Layout, pos_precision: float | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One block of sanitized Gaussians -> its box (pos_lo[3], pos_hi[3], lsc_lo, lsc_hi as float32) and the stored
    integer of every layout field (the same in v1 and v2). `pos_precision`: the position box of `position_box`
    (None: the points' own box, every bit spent on their extent)."""
    bits = dict(layout.fields)
    p = blk["means"].astype(np.float32)
    if pos_precision is None:
        plo, phi = p.min(0), p.max(0)
    else:
        plo, phi = position_box(p, blk["scales"], (bits["px"], bits["py"], bits["pz"]), pos_precision)
    ls = np.log(blk["scales"][:, :1] if layout.isotropic else blk["scales"]).astype(np.float32)
    llo, lhi = np.float32(ls.min()), np.float32(ls.max())
    box = np.array([*plo, *phi, llo, lhi], dtype=np.float32)
    vals = {}
    for i, f in enumerate(("px", "py", "pz")):
        vals[f] = _quantize(p[:, i].astype(np.float64), float(plo[i]), float(phi[i]), bits[f])
    if layout.isotropic:
        vals["s"] = _quantize(ls[:, 0].astype(np.float64), float(llo), float(lhi), bits["s"])
    else:
        for i, f in enumerate(("sx", "sy", "sz")):
            vals[f] = _quantize(ls[:, i].astype(np.float64), float(llo), float(lhi), bits[f])
        if layout.canonical:
            for i, f in enumerate(("qx", "qy", "qz")):
                m = _canon_steps(bits[f])
                vals[f] = np.clip(np.round((blk["quats"][:, 1 + i] / Q_CANON + 1) / 2 * m), 0, m).astype(np.uint64)
        else:
            vals.update(_smallest_three(blk["quats"], bits))
    vals["o"] = _quantize(blk["opacities"], 0.0, 1.0, bits["o"])
    vals.update(quantize_colours(blk["colors"], layout))
    return box, vals


def quantize_colours(colors: np.ndarray, layout: Layout) -> dict[str, np.ndarray]:
    """Colours (n, 3) in [0, 1] -> the stored r, g, b integers of `layout` (no box: a record's colour is its own, so
    v4's SCOL chunk stores exactly what a STAT chunk would)."""
    bits = dict(layout.fields)
    return {f: _quantize(colors[:, i], 0.0, 1.0, bits[f]) for i, f in enumerate("rgb")}


def dequantize_colours(v: dict[str, np.ndarray], layout: Layout) -> np.ndarray:
    """The stored r, g, b integers -> colours (n, 3), float64 (`x / n`)."""
    bits = dict(layout.fields)
    return np.stack([v[f].astype(np.float64) / ((1 << bits[f]) - 1) for f in "rgb"], 1)


def dequantize(v: dict[str, np.ndarray], box: np.ndarray, layout: Layout) -> dict[str, np.ndarray]:
    """Stored integers per field (n,) + the box of each record ((8,) for all, or (n, 8)) -> float64 Gaussians."""
    bits = dict(layout.fields)
    n = len(v["o"])
    box = np.broadcast_to(np.asarray(box, dtype=np.float64), (n, 8))
    deq = lambda f, lo, hi: lo + (hi - lo) * v[f].astype(np.float64) / ((1 << bits[f]) - 1)  # noqa: E731
    means = np.stack([deq(f, box[:, i], box[:, 3 + i]) for i, f in enumerate(("px", "py", "pz"))], 1)
    if layout.isotropic:
        s = np.exp(deq("s", box[:, 6], box[:, 7]))
        scales = np.stack([s, s, s], 1)
        quats = np.tile([1.0, 0, 0, 0], (n, 1))
    elif layout.canonical:
        scales = np.exp(np.stack([deq(f, box[:, 6], box[:, 7]) for f in ("sx", "sy", "sz")], 1))
        xyz = np.stack(
            [
                Q_CANON * (2 * np.minimum(v[f], _canon_steps(bits[f])).astype(np.float64) / _canon_steps(bits[f]) - 1)
                for f in ("qx", "qy", "qz")
            ],
            1,
        )
        quats = np.concatenate([np.sqrt(np.maximum(0.0, 1 - (xyz**2).sum(1)))[:, None], xyz], 1)
    else:
        scales = np.exp(np.stack([deq(f, box[:, 6], box[:, 7]) for f in ("sx", "sy", "sz")], 1))
        three = np.stack(
            [(v[f].astype(np.float64) / ((1 << bits[f]) - 1) * 2 - 1) / math.sqrt(2) for f in ("qa", "qb", "qc")], 1
        )
        largest = np.sqrt(np.maximum(0.0, 1 - (three**2).sum(1)))
        qi = v["qi"].astype(np.int64)
        quats = np.zeros((n, 4))
        quats[np.arange(n), qi] = largest
        rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[qi]
        np.put_along_axis(quats, rest, three, axis=1)
    return {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": deq("o", 0.0, 1.0),
        "colors": dequantize_colours(v, layout),
    }
