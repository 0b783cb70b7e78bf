"""The judge's BEV head: a bird's-eye-view map of the drivable area and of vehicle occupancy around the ego, read
from the six cameras of a rig through the frozen judge (the paper's downstream BEV map segmentation, §4 Table a1,
in the small).

    each camera (3, H, W) -> frozen judge -> class probabilities (17, H, W) + its 1/4-scale features (3w, H/4, W/4)
    each BEV cell centre, at the ground and at 1 m, projected into every camera (the rig's fixed geometry) ->
        bilinear samples, averaged over the cameras that see it, + the fraction of cameras that see it
    -> three 3x3 convolutions (the second dilated) -> logits of the BEV layers (drivable, vehicle)

The lifting has no parameters (inverse perspective mapping at two heights, as in the simplest BEV detectors); the
head learns what is on the ground and what stands on it from where features of several heights and cameras agree.
The grid is ego-centred, x forward (up) and y left (left), as the world's BEV raster; the sampling coordinates are computed
once from the rig the head was trained for and kept in the weight file, so it reads only that rig at that image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from .judge import Judge
from .weights import read_tagged, save_tagged

KIND = "judge_bev"
LAYERS = ("drivable", "vehicle")


@dataclass
class BevConfig:
    x_range: tuple[float, float] = (-24.0, 24.0)  # metres, forward
    y_range: tuple[float, float] = (-16.0, 16.0)  # metres, left
    cell: float = 0.5
    heights: tuple[float, ...] = (0.0, 1.0)  # sampling heights above the ground (m)
    in_channels: int = 17 + 72  # judge class probabilities + its 1/4-scale features (3w with w = 24)
    width: int = 32
    layers: tuple[str, ...] = LAYERS
    # the rig: per camera (fx, fy, cx, cy) at the image and camera_to_ego (4x4, OpenCV camera in FLU ego)
    image: tuple[int, int] = (112, 64)
    intrinsics: list = field(default_factory=list)
    camera_to_ego: list = field(default_factory=list)

    @property
    def shape(self) -> tuple[int, int]:
        return (
            round((self.x_range[1] - self.x_range[0]) / self.cell),
            round((self.y_range[1] - self.y_range[0]) / self.cell),
        )


def cell_centres(cfg: BevConfig) -> tuple[np.ndarray, np.ndarray]:
    """Ego x, y of every cell centre, each (X, Y), in the world's BEV raster layout (`worldsplat.world.conditions`):
    row 0 is the farthest forward, column 0 the farthest left."""
    nx, ny = cfg.shape
    x = cfg.x_range[1] - (np.arange(nx) + 0.5) * cfg.cell
    y = cfg.y_range[1] - (np.arange(ny) + 0.5) * cfg.cell
    return np.meshgrid(x, y, indexing="ij")


def sampling_grid(cfg: BevConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """grid (V, K, X, Y, 2) for grid_sample in [-1, 1] and valid (V, K, X, Y): every cell at every height
    projected into every camera; valid where it is in front of the camera and inside its image."""
    X, Y = cell_centres(cfg)
    W, H = cfg.image
    grids, valid = [], []
    for intr, c2e in zip(cfg.intrinsics, cfg.camera_to_ego):
        fx, fy, cx, cy = intr
        e2c = np.linalg.inv(np.asarray(c2e, np.float64))
        g_v, m_v = [], []
        for h in cfg.heights:
            p = np.stack([X, Y, np.full_like(X, h), np.ones_like(X)], -1) @ e2c.T
            z = p[..., 2]
            zs = np.where(z > 0.1, z, 1.0)
            u, v = fx * p[..., 0] / zs + cx, fy * p[..., 1] / zs + cy
            g_v.append(np.stack([2 * u / W - 1, 2 * v / H - 1], -1))
            m_v.append((z > 0.1) & (u >= 0) & (u < W) & (v >= 0) & (v < H))
        grids.append(g_v)
        valid.append(m_v)
    return torch.tensor(np.array(grids), dtype=torch.float32), torch.tensor(np.array(valid))


class JudgeBev(nn.Module):
    def __init__(self, cfg: BevConfig):
        super().__init__()
        self.cfg = cfg
        grid, valid = sampling_grid(cfg)
        self.register_buffer("grid", grid, persistent=False)
        self.register_buffer("valid", valid.float(), persistent=False)
        k = len(cfg.heights)
        cin = k * cfg.in_channels + k
        w = cfg.width
        self.net = nn.Sequential(
            nn.Conv2d(cin, w, 3, padding=1),
            nn.BatchNorm2d(w),
            nn.ReLU(inplace=True),
            nn.Conv2d(w, w, 3, padding=2, dilation=2),
            nn.BatchNorm2d(w),
            nn.ReLU(inplace=True),
            nn.Conv2d(w, len(cfg.layers), 3, padding=1),
        )

    def lift(self, maps: torch.Tensor) -> torch.Tensor:
        """maps (N, V, C, h, w) per-camera maps -> (N, K*C + K, X, Y): per height the mean over the cameras that
        see a cell, then per height the fraction of cameras that see it."""
        N, V, C = maps.shape[:3]
        K, nx, ny = self.grid.shape[1:4]
        flat = maps.reshape(N * V, C, *maps.shape[-2:])
        g = self.grid.reshape(1, V, K * nx, ny, 2).expand(N, -1, -1, -1, -1).reshape(N * V, K * nx, ny, 2)
        s = F.grid_sample(flat, g, mode="bilinear", padding_mode="zeros", align_corners=False)
        s = s.reshape(N, V, C, K, nx, ny) * self.valid.view(1, V, 1, K, nx, ny)
        seen = self.valid.sum(0)  # (K, X, Y)
        mean = s.sum(1) / seen.clamp(min=1).view(1, 1, K, nx, ny)
        frac = (seen / V).unsqueeze(0).expand(N, -1, -1, -1)
        return torch.cat([mean.permute(0, 2, 1, 3, 4).reshape(N, K * C, nx, ny), frac], 1)

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        """maps (N, V, C, h, w) -> BEV logits (N, layers, X, Y)."""
        return self.net(self.lift(maps))


def judge_maps(judge: Judge, x: torch.Tensor) -> torch.Tensor:
    """x (N, 3, H, W) camera images -> (N, 17 + 3w, H/4, W/4): the judge's class probabilities (area-pooled to
    1/4) beside its 1/4-scale features, the BEV head's input per camera."""
    levels = judge._encode(x)
    probs = judge.head_probs(levels)
    quarter = levels[2]
    return torch.cat([F.adaptive_avg_pool2d(probs, quarter.shape[-2:]), quarter], 1)


def rig_config(rig, image: tuple[int, int], **kw) -> BevConfig:
    """A BevConfig for a rig (RigCamera list) at `image` (W, H)."""
    W, H = image
    intr = [[c.fx * W / c.width, c.fy * H / c.height, c.cx * W / c.width, c.cy * H / c.height] for c in rig]
    c2e = [np.asarray(c.camera_to_ego, np.float64).tolist() for c in rig]
    return BevConfig(image=(W, H), intrinsics=intr, camera_to_ego=c2e, **kw)


def save_bev(model: JudgeBev, path: str | Path, meta: dict | None = None) -> Path:
    return save_tagged(model, path, KIND, meta)


def load_bev(path: str | Path) -> JudgeBev:
    tensors, meta = read_tagged(path, KIND, "train them with `worldsplat judge train-bev`")
    c = meta["config"]
    for k in ("x_range", "y_range", "heights", "layers", "image"):
        c[k] = tuple(c[k])
    model = JudgeBev(BevConfig(**c))
    model.load_state_dict({k: v.float() for k, v in tensors.items()})
    model.meta = meta
    return model.eval()
