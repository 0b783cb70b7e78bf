"""POST /api/scene-files?format=ply|glb|spz|sog|splat: a Gaussian file dropped on the page, read by the same code as
`worldsplat import` (`gaussians.formats.decode_gaussians`, `scene_from_gaussians`, then `importance_order`) and
answered as a .wsplat (`runners.WSPLAT_VERSION`) that the viewer loads like any scene. The body is the file's bytes
(`application/octet-stream`, at most MAX_SCENE_FILE); a .sog is the bundled zip.

Bounded memory: the body limit holds before anything is read (BodyLimit: a declared or streamed body over
MAX_SCENE_FILE is a 413), one conversion runs at a time (another request meanwhile gets 503 + Retry-After before its
body is buffered), and the readers never allocate more than the bytes received allow (their count checks). Every
refusal of a bad file is a 422 whose entry names the format, the field and the byte offset, as the CLI's errors do.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from typing import Literal

import numpy as np

FORMATS = ("ply", "glb", "spz", "sog", "splat")
MAX_SCENE_FILE = 64 << 20  # a 1M-Gaussian 3DGS PLY without SH is 62 MB
PATH = "/api/scene-files"
GATE = threading.BoundedSemaphore(1)  # one conversion at a time (BodyLimit takes it before buffering the body)
RETRY_AFTER_S = 2
log = logging.getLogger("worldsplat.api")

Format = Literal["ply", "glb", "spz", "sog", "splat"]


class SceneFileProblem(Exception):
    """A 422 about the file: `field` (e.g. `ply vertex count`), `offset` (bytes into the file, or into `where`)."""

    def __init__(self, fmt: str, field: str, offset: int, message: str, where: str = "file"):
        at = f"offset {offset}" if where == "file" else f"{where} byte {offset}"
        super().__init__(f"{fmt}: {at}: {field}: {message}")
        self.fmt, self.field, self.offset, self.where, self.message = fmt, field, offset, where, message

    def body(self) -> dict:
        entry = {"field": self.field, "message": self.message, "offset": self.offset, "format": self.fmt}
        if self.where != "file":
            entry["where"] = self.where
        return {"detail": [entry], "error": str(self), "field": self.field}


def orbit(means) -> dict:
    """The free camera the viewer opens a bare point cloud with (splat-core view_state::orbit_around): the centre
    of the Gaussians, from 2.5 x their RMS spread, pitched down 0.3 rad."""
    pts = np.asarray(means, dtype=np.float64)[:: max(1, len(means) // 20_000)]
    if not len(pts):
        return {"target": [0.0, 0.0, 0.0], "yaw": 0.0, "pitch": -0.3, "distance": 10.0, "hfov_deg": 60.0}
    c = pts.mean(0)
    spread = float(np.sqrt(((pts - c) ** 2).sum(1).mean()))
    return {"target": c.tolist(), "yaw": 0.0, "pitch": -0.3, "distance": min(max(2.5 * spread, 1.0), 2000.0),
            "hfov_deg": 60.0}  # fmt: skip


def convert(data: bytes, fmt: str, version: int, name: str | None = None) -> tuple[bytes, int, dict | None]:
    """The file's bytes -> (.wsplat bytes, Gaussians, the free camera to open it with, or None when the file
    carried its rig and pose: .glb / .sog written by `worldsplat export`); raises SceneFileProblem."""
    # heavy (torch), imported on first use: `worldsplat serve` starts without them
    from worldsplat.gaussians import wsplat  # noqa: PLC0415 - heavy (torch)
    from worldsplat.gaussians.aggregate import importance_order  # noqa: PLC0415 - heavy (torch)
    from worldsplat.gaussians.fileformat import FormatError  # noqa: PLC0415 - heavy (torch, via gaussians)
    from worldsplat.gaussians.formats import decode_gaussians, scene_from_gaussians  # noqa: PLC0415 - heavy (torch)

    if not data:
        raise SceneFileProblem(fmt, "body", 0, "empty: send the file's bytes as the request body")
    name = name or f"file.{fmt}"
    try:
        g, extras = decode_gaussians(data, f".{fmt}", name)
        scene = scene_from_gaussians(g, extras, name)
    except FormatError as e:
        raise SceneFileProblem(e.fmt, e.field, e.offset, e.detail, e.where) from None
    except Exception as e:  # noqa: BLE001 - a reader's own failure on an odd file: the client's 422, logged
        log.warning("scene file import (%s) failed", fmt, exc_info=True)
        raise SceneFileProblem(fmt, "file", 0, f"cannot import: {type(e).__name__}: {e}") from None
    scene = dataclasses.replace(scene, static=importance_order(scene.static))  # chunks in importance order
    view = None if "rig" in extras else orbit(scene.static.means.detach().numpy())
    return wsplat.encode(scene, version=version), len(scene.static), view
