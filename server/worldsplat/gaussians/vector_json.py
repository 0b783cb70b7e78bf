"""Gaussians in the JSON form of the shared test vectors (tests/vectors, web/docs/splatting-math.md): arrays of
numbers where non-finite values are the strings "NaN", "Infinity" and "-Infinity"."""

from __future__ import annotations

import math

import numpy as np

FIELDS = {"means": (3,), "quats": (4,), "scales": (3,), "opacities": (), "colors": (3,)}


def _encode_float(x: float):
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "Infinity" if x > 0 else "-Infinity"
    return float(x)


def to_json_array(a: np.ndarray) -> list:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        return [_encode_float(v) for v in a]
    return [to_json_array(r) for r in a]


def from_json_array(v, shape_tail: tuple[int, ...]) -> np.ndarray:
    def dec(x):
        if isinstance(x, list):
            return [dec(y) for y in x]
        if isinstance(x, str):
            return {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}[x]
        return float(x)

    a = np.asarray(dec(v), dtype=np.float64)
    return a.reshape((-1,) + shape_tail)


def gaussians_to_json(g: dict[str, np.ndarray]) -> dict:
    return {k: to_json_array(g[k]) for k in FIELDS}


def gaussians_from_json(obj: dict) -> dict[str, np.ndarray]:
    return {k: from_json_array(obj[k], t) for k, t in FIELDS.items()}
