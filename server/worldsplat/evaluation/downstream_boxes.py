"""Vehicle boxes from the judge's BEV head, scored as nuScenes scores detections (the paper's mAP, Table a1, in the
small): a centre-based average precision of vehicle centres on the ego's BEV grid.

detections    the peaks of the head's vehicle probability (`vehicle_centres`): a cell whose probability is at least
              `MIN_SCORE` and the largest within `PEAK_WINDOW_M`, its centre the probability-weighted mean of the
              cells around it; its score that probability (of peaks closer than half the window, the first in
              score order stays). The head maps occupancy, not boxes, so a detection is a centre with a score (no
              size or heading: nuScenes' AP matches on the centre distance alone; box size and heading are its
              separate TP errors, not scored here).
ground truth  the world's vehicles (car, bus, truck) whose centre lies on the head's grid at that frame, in the ego
              frame of the track scored (`true_centres`).
AP            nuScenes' detection AP (`average_precision`): over all frames, detections in score order are matched
              greedily to the nearest unmatched true centre of their frame within a distance threshold (0.5, 1, 2
              and 4 m on the ground); precision is interpolated at 101 recall points, and the AP is the mean of
              (precision - 0.1) over recall >= 0.1, clipped at 0 and divided by 0.9. mAP is its mean over the four
              thresholds (one class here: vehicle).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.core.camera import rigid_inverse, shifted_ego
from worldsplat.world.classes import VEHICLE_CLASSES
from worldsplat_models.judge_bev import BevConfig, cell_centres

DIST_THRESHOLDS_M = (0.5, 1.0, 2.0, 4.0)  # nuScenes' centre-distance thresholds
MIN_RECALL, MIN_PRECISION = 0.1, 0.1  # nuScenes' AP: the low-recall part and precision under 0.1 do not count
PEAK_WINDOW_M = 3.5  # a peak is the largest probability within this square (one car's length, less a margin)
MIN_SCORE = 0.1  # detections below this probability are dropped


def vehicle_centres(logits, cfg: BevConfig, layer: str = "vehicle") -> list[np.ndarray]:
    """BEV logits (N, layers, X, Y) -> per sample the detections (k, 3): score, ego x, ego y (metres)."""
    z = torch.as_tensor(np.asarray(logits, np.float32)[:, list(cfg.layers).index(layer)])[:, None]
    p = torch.sigmoid(z)
    k = max(1, round(PEAK_WINDOW_M / cfg.cell)) | 1  # odd
    # peaks on the logits: probabilities saturate at 1 and would tie
    peaks = (z == F.max_pool2d(z, k, 1, k // 2)) & (p >= MIN_SCORE)
    # the centre of a peak: its 3x3 neighbourhood's probability-weighted mean (a sub-cell position)
    X, Y = (torch.as_tensor(c, dtype=torch.float32) for c in cell_centres(cfg))
    mass = F.avg_pool2d(p, 3, 1, 1, count_include_pad=False)
    mx = F.avg_pool2d(p * X, 3, 1, 1, count_include_pad=False) / mass.clamp_min(1e-6)
    my = F.avg_pool2d(p * Y, 3, 1, 1, count_include_pad=False) / mass.clamp_min(1e-6)
    out = []
    for i in range(len(p)):
        m = peaks[i, 0]
        d = torch.stack([p[i, 0][m], mx[i, 0][m], my[i, 0][m]], -1).numpy().astype(np.float64)
        out.append(_suppress(d[np.argsort(-d[:, 0], kind="stable")], (k // 2 + 0.5) * cfg.cell))
    return out


def _suppress(dets: np.ndarray, radius_m: float) -> np.ndarray:
    """Detections in score order without those within `radius_m` (each axis) of a kept one: a plateau of equal
    logits gives one peak, not one per cell."""
    keep: list[int] = []
    for j, d in enumerate(dets):
        if all(np.abs(d[1:] - dets[i, 1:]).max() >= radius_m for i in keep):
            keep.append(j)
    return dets[keep]


def centres_on_grid(ego_to_world: np.ndarray, centres: np.ndarray, cfg: BevConfig) -> list[np.ndarray]:
    """Per frame the world centres (T, A, 2+) (x, y on the ground) in the ego frame of that frame's pose
    (T, 4, 4), those on the head's grid: (m, 2) each."""
    out = []
    for ego, c in zip(ego_to_world, np.asarray(centres, np.float64)):
        inv = rigid_inverse(ego)
        pts = np.concatenate([c[:, :2], np.zeros((len(c), 1))], 1)
        pe = pts @ inv[:3, :3].T + inv[:3, 3]
        on = (
            (pe[:, 0] >= cfg.x_range[0])
            & (pe[:, 0] < cfg.x_range[1])
            & (pe[:, 1] >= cfg.y_range[0])
            & (pe[:, 1] < cfg.y_range[1])
        )
        out.append(pe[on, :2])
    return out


def true_centres(world, shift_m: float, cfg: BevConfig, frames: list[int] | None = None) -> list[np.ndarray]:
    """Per frame the world's vehicle centres (m, 2) in the ego frame of the track shifted `shift_m`, those on the
    head's grid."""
    ts = list(range(world.num_frames) if frames is None else frames)
    ego = shifted_ego(world.ego_to_world, shift_m)[ts]
    vehicles = [ag for ag in world.agents if ag.cls in VEHICLE_CLASSES]
    centres = np.array([[ag.poses[t][:2] for ag in vehicles] for t in ts], np.float64).reshape(len(ts), -1, 2)
    return centres_on_grid(ego, centres, cfg)


def shard_centres(z, cfg: BevConfig) -> list[np.ndarray]:
    """Per frame of a dataset shard (its `box_corners`, `box_cls`, `ego_to_world`) the vehicle centres on the grid."""
    vehicle = np.isin(z["box_cls"], VEHICLE_CLASSES)
    return centres_on_grid(z["ego_to_world"], z["box_corners"][:, vehicle].mean(2), cfg)


def average_precision(frames: list[tuple[np.ndarray, np.ndarray]], threshold_m: float) -> float | None:
    """nuScenes' AP of centre detections at one distance threshold; `frames` is per frame (detections (k, 3):
    score, x, y; true centres (m, 2)). None when there is no true centre at all."""
    total = sum(len(g) for _, g in frames)
    if total == 0:
        return None
    dets = [(d[0], f, d[1:]) for f, (ds, _) in enumerate(frames) for d in ds]
    dets.sort(key=lambda d: -d[0])
    taken = [np.zeros(len(g), bool) for _, g in frames]
    tp = np.zeros(len(dets))
    for j, (_, f, xy) in enumerate(dets):
        g = frames[f][1]
        if not len(g):
            continue
        dist = np.where(taken[f], np.inf, np.linalg.norm(g - xy, axis=1))
        best = int(np.argmin(dist))
        if dist[best] < threshold_m:
            taken[f][best], tp[j] = True, 1.0
    if not len(dets):
        return 0.0
    ctp = np.cumsum(tp)
    prec, rec = ctp / np.arange(1, len(dets) + 1), ctp / total
    grid = np.linspace(0, 1, 101)
    p = np.interp(grid, rec, prec, right=0)
    p = p[round(100 * MIN_RECALL) + 1 :] - MIN_PRECISION
    return float(np.mean(np.clip(p, 0, None)) / (1 - MIN_PRECISION))


def box_summary(frames: list[tuple[np.ndarray, np.ndarray]]) -> dict:
    """The vehicle box scores of a set of frames: AP per distance threshold, their mean (mAP), and the counts."""
    ap = {f"{t:g}": average_precision(frames, t) for t in DIST_THRESHOLDS_M}
    vals = [v for v in ap.values() if v is not None]
    return {
        "box_map": float(np.mean(vals)) if vals else None,
        "box_ap": ap,
        "box_true": int(sum(len(g) for _, g in frames)),
        "box_detections": int(sum(len(d) for d, _ in frames)),
    }
