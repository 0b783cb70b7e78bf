"""Oracle lifting: pixel-aligned Gaussians from ground-truth RGB + depth + camera (the training-free baseline).

Each non-sky pixel becomes one isotropic Gaussian at `origin + depth * dir` (dir has unit camera-z component, so
`depth` is camera z), coloured by the pixel, with a standard deviation of FOOTPRINT pixels at its depth
(`scale = FOOTPRINT * depth / f`), so neighbouring splats overlap into a closed surface.
"""
from __future__ import annotations

import numpy as np
import torch

from worldsplat.camera import Camera
from worldsplat.gaussians.types import Gaussians

FOOTPRINT = 0.7          # px: splat std relative to the pixel pitch (tuned on the presets, see gaussians.md)
OPACITY = 0.98
MAX_DEPTH = 200.0        # m: farther pixels are treated like sky (dropped)


def lift(rgb: np.ndarray, depth: np.ndarray, dynamic: np.ndarray | None, camera: Camera, *,
         footprint: float = FOOTPRINT, opacity: float = OPACITY, max_depth: float = MAX_DEPTH) -> Gaussians:
    """rgb (H,W,3) uint8 or float in [0,1], depth (H,W) camera z (sky = +inf), dynamic (H,W) bool or None.
    Returns Gaussians in world coordinates with extras[:, 0] = dynamic mask (1.0 for moving-agent pixels)."""
    H, W = camera.height, camera.width
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != (H, W) or np.asarray(rgb).shape[:2] != (H, W):
        raise ValueError(f"lift: rgb {np.asarray(rgb).shape} / depth {depth.shape} do not match camera {W}x{H}")
    col = np.asarray(rgb)
    col = col.astype(np.float64) / 255.0 if col.dtype == np.uint8 else col.astype(np.float64)
    keep = np.isfinite(depth) & (depth > 0) & (depth < max_depth)
    origin, dirs = camera.pixel_rays()
    d = depth[keep]
    means = origin + d[:, None] * dirs[keep]
    f = np.sqrt(camera.fx * camera.fy)
    scale = footprint * d / f
    n = len(d)
    dyn = np.zeros(n) if dynamic is None else np.asarray(dynamic, dtype=bool)[keep].astype(np.float64)
    return Gaussians.from_numpy(means, np.tile([1.0, 0, 0, 0], (n, 1)), np.repeat(scale[:, None], 3, 1),
                                np.full(n, opacity), col[keep], extras=dyn[:, None])
