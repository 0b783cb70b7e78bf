"""What the scenario-file readers share: the refusal, the import's result, the file's frame -> ours, the clip.

`scenario_io` (the entry points) and each format's reader and writer (`openscenario_read`, `opendrive_read`,
`commonroad_read`, `openscenario_write`, `commonroad_write`) import these from here, so none imports its package back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


class ImportRefused(ValueError):
    """A file that cannot be represented; `errors` holds one "Element/Path: why" string per problem, `warnings` what
    the import had noted before it was refused."""

    def __init__(self, errors: list[str], warnings: list[str] | None = None):
        self.errors = errors
        self.warnings = list(warnings or [])
        super().__init__("cannot import: " + "; ".join(errors))


@dataclass
class Imported:
    scenario: dict  # a v2 scenario document (validate with Scenario.parse)
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Frame:
    """The file's world frame -> ours: translate the ego's start to the origin and turn its heading to +x."""

    x: float
    y: float
    h: float

    def point(self, x: float, y: float) -> tuple[float, float]:
        c, s = math.cos(self.h), math.sin(self.h)
        dx, dy = x - self.x, y - self.y
        return c * dx + s * dy, -s * dx + c * dy

    def yaw(self, h: float) -> float:
        return wrap(h - self.h)


def xml_text(s: str) -> str:
    """`s` as an XML 1.0 attribute can hold it: characters outside XML's Char production (control characters other
    than tab, newline and carriage return; U+FFFE, U+FFFF) are dropped, as no escape can write them."""
    return "".join(
        c
        for c in s
        if c in "\t\n\r" or "\x20" <= c <= "\ud7ff" or "\ue000" <= c <= "\ufffd" or "\U00010000" <= c <= "\U0010ffff"
    )


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def fit_clip(duration: float, fps: float = 4.0, frames: int | None = None) -> dict:
    """The clip for a scenario that lasts `duration` seconds: at most 32 frames unless `frames` says (a short clip by
    default; a scenario takes up to core.limits.MAX_CLIP_FRAMES)."""
    if frames is None:
        frames = int(max(1, min(32, math.floor(duration * fps + 1e-6) + 1)))
    return {"frames": int(frames), "fps": float(fps)}


def subsample(times: np.ndarray, max_n: int = 64) -> np.ndarray:
    """Indices of at most max_n of `times`, first and last kept."""
    n = len(times)
    if n <= max_n:
        return np.arange(n)
    step = int(math.ceil((n - 1) / (max_n - 1)))
    idx = list(range(0, n, step))
    if idx[-1] != n - 1:
        idx[-1] = n - 1 if len(idx) == max_n else idx[-1]
        if idx[-1] != n - 1:
            idx.append(n - 1)
    return np.array(idx)
