"""Analytic primitives the world is made of: yaw-oriented boxes and spheres (struct of arrays).

Every static object and every agent part is a primitive with a class id, a base colour and a material that
the renderer's shader turns into texture (facade windows, car lights, foliage noise...).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BOX, SPHERE = 0, 1
# Materials (how the shader textures a primitive).
M_PLAIN, M_BUILDING, M_CAR_BODY, M_CABIN, M_FOLIAGE, M_PERSON, M_BUS, M_LAMP, M_SIGN, M_TRAFFIC_LIGHT, M_HOUSE = range(
    11
)


@dataclass
class Prims:
    center: np.ndarray  # (P,3) float64, world (or agent-local for agent templates)
    yaw: np.ndarray  # (P,) radians about +z
    half: np.ndarray  # (P,3) half extents (spheres: radius in all three)
    shape: np.ndarray  # (P,) int8 BOX | SPHERE
    cls: np.ndarray  # (P,) uint8 semantic class
    color: np.ndarray  # (P,3) float32 albedo in [0,1]
    material: np.ndarray  # (P,) int8
    key: np.ndarray  # (P,) float32 in [0,1): per-object variation (window lights, patterns)
    agent: np.ndarray  # (P,) int32 agent index or -1 for static

    def __len__(self) -> int:
        return int(self.center.shape[0])

    @staticmethod
    def empty() -> Prims:
        return Prims(
            np.zeros((0, 3)),
            np.zeros(0),
            np.zeros((0, 3)),
            np.zeros(0, np.int8),
            np.zeros(0, np.uint8),
            np.zeros((0, 3), np.float32),
            np.zeros(0, np.int8),
            np.zeros(0, np.float32),
            np.zeros(0, np.int32),
        )

    @staticmethod
    def concat(items: list[Prims]) -> Prims:
        items = [p for p in items if len(p)]
        if not items:
            return Prims.empty()
        return Prims(*(np.concatenate([getattr(p, f) for p in items]) for f in Prims.__dataclass_fields__))

    def take(self, idx: np.ndarray) -> Prims:
        return Prims(*(getattr(self, f)[idx] for f in Prims.__dataclass_fields__))

    @property
    def radius(self) -> np.ndarray:
        """Bounding-sphere radius."""
        return np.linalg.norm(self.half, axis=1)


class PrimBuilder:
    """Collects primitives one by one (layout code reads better this way), then packs them."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []

    def box(self, center, yaw, half, cls, color, material=M_PLAIN, key=0.0, agent=-1) -> None:
        self.rows.append((tuple(center), float(yaw), tuple(half), BOX, cls, tuple(color), material, key, agent))

    def sphere(self, center, radius, cls, color, material=M_PLAIN, key=0.0, agent=-1) -> None:
        r = float(radius)
        self.rows.append((tuple(center), 0.0, (r, r, r), SPHERE, cls, tuple(color), material, key, agent))

    def build(self) -> Prims:
        if not self.rows:
            return Prims.empty()
        c, y, h, s, cl, co, m, k, a = zip(*self.rows)
        return Prims(
            np.array(c, np.float64),
            np.array(y, np.float64),
            np.array(h, np.float64),
            np.array(s, np.int8),
            np.array(cl, np.uint8),
            np.array(co, np.float32),
            np.array(m, np.int8),
            np.array(k, np.float32),
            np.array(a, np.int32),
        )
