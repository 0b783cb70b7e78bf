"""Visibility fusion of per-view Gaussian layers: keep one observation per surface, drop floaters.

The per-frame, per-view layers of a window (paper eq. 3's static union) each hold a copy of every surface they see.
Where the copies agree the economy's cells merge them; where a layer's depth is off by more than a cell (decoded
depth is), its copy lands in other cells and shows as a ghost layer in front of or behind the others. Fusion
decides per Gaussian, from the other layers' depth maps (a z-buffer of each layer's own static means on its own
pixel grid):

- redundant: another layer sees the same place (its depth there within `tol`, as a log ratio) at a finer pixel
  footprint (depth / focal): drop it, the finer observation stands for the surface;
- floater: another layer looks through it (it lies in front of that layer's nearest depth in a 3x3 neighbourhood by
  more than `carve_tol`, on a pixel no dynamic Gaussian of that layer covers): drop it.

What no other layer contradicts or sees better is kept, so every surface keeps its finest observation (as a depth
fusion keeps the nearest views of a surface). Sky-shell Gaussians (extras[:, SKY_CHANNEL]) are never dropped and
never occlude. Measured in web/docs/models.md ("v11").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worldsplat.core.camera import Camera
from worldsplat.gaussians.lift import SKY_CHANNEL
from worldsplat.gaussians.types import Gaussians

FUSE_TOL = 0.1  # |log(z / z_other)| below this: the same surface
FUSE_CARVE_TOL = 0.2  # in front of the other layer's nearest depth by more than this fraction: a floater
FUSE_TIE = 0.05  # footprints within this fraction are equal; the earlier layer (frame, view order) wins


@dataclass
class Layer:
    """One frame-view layer: its static Gaussians (world metres), the means of its dynamic ones, its camera and
    how many Gaussians the decoder or lifting put in its view (the density of its pixel grid)."""

    static: Gaussians
    dynamic_means: np.ndarray
    camera: Camera
    count: int


def _grid(cam: Camera, count: int) -> tuple[int, int, float, float, float, float]:
    """The layer's pixel grid: the camera's image scaled so that it holds about `count` pixels (at most 1:1)."""
    f = float(np.clip(np.sqrt(max(count, 1) / (cam.width * cam.height)), 1 / 16, 1.0))
    gw, gh = max(1, round(cam.width * f)), max(1, round(cam.height * f))
    sx, sy = gw / cam.width, gh / cam.height
    return gh, gw, cam.fx * sx, cam.fy * sy, (cam.cx + 0.5) * sx - 0.5, (cam.cy + 0.5) * sy - 0.5


def _project(p: np.ndarray, cam: Camera, grid) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Camera depth z, grid pixel (row, col) and whether it lands inside, of world points p (N,3)."""
    gh, gw, fx, fy, cx, cy = grid
    w2c = cam.world_to_camera
    pc = p @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    zs = np.where(z > 1e-3, z, 1.0)
    col = np.floor(fx * pc[:, 0] / zs + cx + 0.5).astype(np.int64)
    row = np.floor(fy * pc[:, 1] / zs + cy + 0.5).astype(np.int64)
    inside = (z > 0.1) & (col >= 0) & (col < gw) & (row >= 0) & (row < gh)
    return z, np.clip(row, 0, gh - 1), np.clip(col, 0, gw - 1), inside


def _min3(a: np.ndarray) -> np.ndarray:
    p = np.pad(a, 1, constant_values=np.inf)
    h, w = a.shape
    return np.min([p[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)


def _any3(a: np.ndarray) -> np.ndarray:
    p = np.pad(a, 1, constant_values=False)
    h, w = a.shape
    return np.any([p[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)


def fuse_layers(
    layers: list[Layer], tol: float = FUSE_TOL, carve_tol: float = FUSE_CARVE_TOL, tie: float = FUSE_TIE
) -> tuple[list[np.ndarray], dict]:
    """Keep masks (one bool array per layer's static Gaussians) and counts {"redundant", "floaters"}."""
    maps = []
    for L in layers:
        grid = _grid(L.camera, L.count)
        gh, gw = grid[:2]
        p = L.static.means.detach().double().cpu().numpy()
        sky = _sky(L.static)
        z, r, c, ok = _project(p, L.camera, grid)
        ok &= ~sky
        zbuf = np.full((gh, gw), np.inf)
        np.minimum.at(zbuf, (r[ok], c[ok]), z[ok])
        dyn = np.zeros((gh, gw), dtype=bool)
        if len(L.dynamic_means):
            _, dr, dc, dok = _project(np.asarray(L.dynamic_means, np.float64), L.camera, grid)
            dyn[dr[dok], dc[dok]] = True
        maps.append((grid, zbuf, _min3(zbuf), _any3(dyn), p, sky, np.where(ok, z / grid[2], np.nan)))
    keeps, n_red, n_float = [], 0, 0
    for a, (_, _, _, _, p, sky, fp_a) in enumerate(maps):
        redundant = np.zeros(len(p), dtype=bool)
        floater = np.zeros(len(p), dtype=bool)
        for c, (grid, zbuf, zmin, dyn, _, _, _) in enumerate(maps):
            if c == a or not len(p):
                continue
            z, r, col, ok = _project(p, layers[c].camera, grid)
            zb, zm = zbuf[r, col], zmin[r, col]
            fp_c = zb / grid[2]
            same = ok & np.isfinite(zb) & (np.abs(np.log(np.maximum(z, 1e-6) / np.where(np.isfinite(zb), zb, 1.0))) < tol)
            ratio = fp_c / np.where(np.isfinite(fp_a) & (fp_a > 0), fp_a, np.inf)
            finer = (ratio < 1 - tie) | ((np.abs(ratio - 1) <= tie) & (c < a))
            redundant |= same & finer
            floater |= ok & np.isfinite(zm) & (z < zm * (1 - carve_tol)) & ~dyn[r, col]
        drop = (redundant | floater) & ~sky
        n_red += int((redundant & ~sky).sum())
        n_float += int((floater & ~redundant & ~sky).sum())
        keeps.append(~drop)
    return keeps, {"fusion_redundant": n_red, "fusion_floaters": n_float}


def _sky(g: Gaussians) -> np.ndarray:
    if g.extras is None or g.extras.shape[1] <= SKY_CHANNEL:
        return np.zeros(len(g), dtype=bool)
    return (g.extras[:, SKY_CHANNEL] > 0.5).detach().cpu().numpy()
