"""Oracle lifting: pixel-aligned Gaussians from ground-truth RGB + depth + camera (the training-free baseline).

Each pixel becomes one isotropic Gaussian on its ray, coloured by the pixel, with a standard deviation of FOOTPRINT
pixels at its depth (`scale = FOOTPRINT * z / f`), so neighbouring splats overlap into a closed surface:
- a surface pixel (finite depth < `max_depth`) sits at `origin + depth * dir` (dir has unit camera-z component, so
  `depth` is camera z);
- a sky pixel (depth +inf, or beyond `max_depth`) sits on a far shell, SKY_DISTANCE metres along its ray, and is
  flagged in extras[:, SKY_CHANNEL]: the sky is a static backdrop rendered by the same rasterizer (at 300 m a
  +-4 m track shift moves it by ~1 % of the focal length in pixels, which is what "at infinity" looks like).
"""

from __future__ import annotations

import numpy as np

from worldsplat.core.camera import Camera
from worldsplat.gaussians.types import Gaussians

FOOTPRINT = 0.7  # px: splat std relative to the pixel pitch (tuned on the presets, see gaussians.md)
OPACITY = 0.98
MAX_DEPTH = 200.0  # m: farther pixels join the sky shell
SKY_DISTANCE = 300.0  # m along the ray: the sky shell
DYNAMIC_CHANNEL = 0  # extras[:, 0]: 1.0 for moving-agent pixels
SKY_CHANNEL = 1  # extras[:, 1]: 1.0 for sky-shell pixels (the economy keeps them beyond its range cut)


def lift(
    rgb: np.ndarray,
    depth: np.ndarray,
    dynamic: np.ndarray | None,
    camera: Camera,
    *,
    footprint: float = FOOTPRINT,
    opacity: float = OPACITY,
    max_depth: float = MAX_DEPTH,
    sky: bool = True,
    sky_distance: float = SKY_DISTANCE,
) -> Gaussians:
    """rgb (H,W,3) uint8 or float in [0,1], depth (H,W) camera z (sky = +inf), dynamic (H,W) bool or None.
    Returns Gaussians in world coordinates with extras[:, 0] = dynamic mask, extras[:, 1] = sky flag.
    `sky=False` drops sky pixels instead of lifting them onto the shell."""
    H, W = camera.height, camera.width
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != (H, W) or np.asarray(rgb).shape[:2] != (H, W):
        raise ValueError(f"lift: rgb {np.asarray(rgb).shape} / depth {depth.shape} do not match camera {W}x{H}")
    if not (np.isfinite(sky_distance) and sky_distance > 0):
        raise ValueError(f"lift: sky_distance must be a finite number > 0, got {sky_distance}")
    col = np.asarray(rgb)
    col = col.astype(np.float64) / 255.0 if col.dtype == np.uint8 else col.astype(np.float64)
    surface = np.isfinite(depth) & (depth > 0) & (depth < max_depth)
    # +inf or beyond max_depth is sky; NaN, zero and negative depths are invalid and dropped.
    is_sky = (np.isposinf(depth) | (np.isfinite(depth) & (depth >= max_depth))) if sky else np.zeros_like(surface)
    keep = surface | is_sky
    origin, dirs = camera.pixel_rays()
    d = np.where(surface, depth, sky_distance / np.linalg.norm(dirs, axis=-1).reshape(H, W))[keep]
    means = origin + d[:, None] * dirs[keep]
    f = np.sqrt(camera.fx * camera.fy)
    scale = footprint * d / f
    n = len(d)
    dyn = np.zeros(n) if dynamic is None else np.asarray(dynamic, dtype=bool)[keep].astype(np.float64)
    dyn = np.where(is_sky[keep], 0.0, dyn)  # the sky never moves
    extras = np.stack([dyn, is_sky[keep].astype(np.float64)], 1)
    return Gaussians.from_numpy(
        means,
        np.tile([1.0, 0, 0, 0], (n, 1)),
        np.repeat(scale[:, None], 3, 1),
        np.full(n, opacity),
        col[keep],
        extras=extras,
    )
