"""Training the judge's BEV head (worldsplat_models.judge_bev) on the world's exact BEV raster, through the frozen
judge.

Data: the shards of `worldsplat dataset`: every frame of a clip is one sample (its six camera images, `rgb`) with
the world's BEV raster of that frame (`bev`, `worldsplat.world.conditions.bev_raster`) cropped to the head's grid:
the drivable area and the vehicles' footprints. A step draws `batch` samples with the step's generator, jitters
brightness and contrast per sample (no flips: the rig's geometry is fixed), runs the frozen judge on the cameras and
the head on the lifted maps; the loss is binary cross-entropy per layer with positives weighted by
sqrt(negatives / positives) over the training targets (vehicles cover a few per cent of the grid).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.core.camera import shifted_ego
from worldsplat.training.data import shard_files
from worldsplat.training.loop import train_loop
from worldsplat.world.conditions import BEV_CHANNELS, BEV_RES, BEV_SIZE, bev_raster
from worldsplat_models.configs import TrainConfig
from worldsplat_models.judge import Judge, num_params, to_input
from worldsplat_models.judge_bev import BevConfig, JudgeBev, judge_maps, save_bev


def bev_crop(cfg: BevConfig, bev: np.ndarray) -> np.ndarray:
    """The world's BEV raster (..., channels, 200, 200) -> the head's layers on its grid (..., layers, X, Y) uint8."""
    if cfg.cell != BEV_RES:
        raise ValueError(f"the head's cell ({cfg.cell} m) must be the world raster's ({BEV_RES} m)")
    r0, c0 = round(BEV_SIZE / 2 - cfg.x_range[1] / BEV_RES), round(BEV_SIZE / 2 - cfg.y_range[1] / BEV_RES)
    nx, ny = cfg.shape
    ch = [BEV_CHANNELS.index(layer) for layer in cfg.layers]
    return (bev[..., ch, r0 : r0 + nx, c0 : c0 + ny] > 0.5).astype(np.uint8)


def bev_targets(world, shift_m: float, cfg: BevConfig, frames: list[int] | None = None) -> np.ndarray:
    """The head's exact targets (T', layers, X, Y) of a world on the track shifted `shift_m`, for `frames`."""
    ego = shifted_ego(world.ego_to_world, shift_m)
    ts = range(world.num_frames) if frames is None else frames
    return np.stack([bev_crop(cfg, bev_raster(world, t, ego[t])) for t in ts])


def shard_config(data: Path, split: str = "train", **kw) -> BevConfig:
    """A BevConfig for the rig and image of the split's first shard."""
    with np.load(shard_files(data, split, 1)[0], allow_pickle=False) as z:
        K, c2e, H, W = z["K"], z["camera_to_ego"], *z["rgb"].shape[-3:-1]
    intr = [[float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])] for k in K]
    return BevConfig(image=(int(W), int(H)), intrinsics=intr, camera_to_ego=np.asarray(c2e).tolist(), **kw)


def load_bev_data(data: Path, split: str, cfg: BevConfig, limit: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every frame of the split's clips: camera images (N, V, H, W, 3) uint8 and targets (N, layers, X, Y) uint8."""
    images, targets = [], []
    for f in shard_files(data, split, limit):
        with np.load(f, allow_pickle=False) as z:
            images.append(z["rgb"])
            targets.append(bev_crop(cfg, z["bev"]))
    return np.concatenate(images), np.concatenate(targets)


def pos_weights(targets: np.ndarray) -> np.ndarray:
    pos = targets.mean(axis=(0, 2, 3)).astype(np.float64)
    return np.sqrt((1 - pos) / np.maximum(pos, 1e-4)).astype(np.float32)


def bev_logits(judge: Judge, head: JudgeBev, images: np.ndarray) -> torch.Tensor:
    """(N, V, H, W, 3) uint8 -> BEV logits (N, layers, X, Y) (the judge frozen)."""
    N, V = images.shape[:2]
    with torch.no_grad():
        maps = judge_maps(judge, to_input(images))
    return head(maps.reshape(N, V, *maps.shape[1:]))


def bev_step_fn(judge: Judge, images: np.ndarray, targets: np.ndarray, batch: int):
    w = torch.from_numpy(pos_weights(targets)).view(1, -1, 1, 1)

    def step(model, step_i: int, gen: torch.Generator):
        idx = torch.randint(0, len(images), (batch,), generator=gen).numpy()
        B, V, H, W = images[idx].shape[:4]
        x = to_input(images[idx])
        gain = (0.8 + 0.4 * torch.rand(B, 1, 1, 1, 1, generator=gen)).expand(B, V, 1, 1, 1).reshape(B * V, 1, 1, 1)
        x = (x * gain).clamp(0, 1)
        with torch.no_grad():
            maps = judge_maps(judge, x)
        logits = model(maps.reshape(B, V, *maps.shape[1:]))
        y = torch.from_numpy(targets[idx].astype(np.float32))
        loss = F.binary_cross_entropy_with_logits(logits, y, pos_weight=w)
        return loss, {}

    return step


def train_bev(
    judge: Judge,
    data: Path,
    out: Path,
    steps: int = 400,
    batch: int = 4,
    width: int = 32,
    lr: float = 3e-3,
    seed: int = 0,
    threads: int = 2,
    clips: int | None = None,
    minutes: float | None = None,
    progress: bool = True,
) -> Path:
    """Train a BEV head on DATA/train through the frozen `judge`; checkpoints and log in OUT, weights in
    OUT/judge_bev_small.safetensors (exported at every checkpoint; a re-run resumes)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(threads)
    t0 = time.time()
    judge.eval().requires_grad_(False)
    cfg = shard_config(data, "train", width=width, in_channels=judge.cfg.num_classes + 3 * judge.cfg.width)
    images, targets = load_bev_data(data, "train", cfg, clips)
    head = JudgeBev(cfg)
    tcfg = TrainConfig(
        steps=steps, lr=lr, warmup=min(30, steps // 10), seed=seed, ckpt_every=50, log_every=10, threads=threads
    )
    path = out / "judge_bev_small.safetensors"

    def export(m, done: int) -> None:
        prov = {
            "data": str(data),
            "train_clips": len(shard_files(data, "train", clips)),
            "train_samples": int(len(images)),
            "steps": int(done),
            "batch": batch,
            "lr": lr,
            "seed": seed,
            "params": num_params(m),
            "judge": getattr(judge, "meta", {}).get("provenance", {}).get("steps"),
            "wall_s": round(time.time() - t0, 1),
        }
        save_bev(m, path, {"provenance": prov})

    history = train_loop(
        "judge_bev", head, bev_step_fn(judge, images, targets, batch), tcfg, out, progress, export, minutes
    )
    if history:
        (out / "judge_bev_last.json").write_text(json.dumps(history[-1]) + "\n")
    return path
