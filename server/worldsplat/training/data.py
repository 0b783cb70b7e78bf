"""Training samples: one clip (T frames x V views) as a dict of numpy arrays, from the world or from dataset shards.

Sample fields (T frames, V views, H x W images, N = DataConfig.max_boxes):
    rgb (T,V,H,W,3) uint8          depth (T,V,H,W) float32 camera-z metres, sky = inf
    dynamic (T,V,H,W) bool         sketch (T,V,H,W,3) float32 in [0, 1]
    intrinsics (T,V,4) fx,fy,cx,cy  cam_to_world (T,V,4,4)     ego_to_world (T,4,4)
    box_corners (T,N,8,3) metres in the ego frame of that frame   box_cls (T,N) int   box_moving (T,N) bool
    box_mask (T,N) bool            traj (T,4,4) ego pose relative to frame 0            caption str
Boxes beyond N are dropped nearest-first-kept.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.camera import default_rig
from worldsplat.pipeline.conditions import pack_boxes, sketch_rgb
from worldsplat.world import build_world, simulate
from worldsplat_models.configs import DataConfig
from worldsplat_models.vae import normalize_depth


def rig_arrays(clip, frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """intrinsics (T,V,4) and cam_to_world (T,V,4,4) of a simulated clip (its shift included)."""
    T = clip.rgb.shape[0] if frames is None else frames
    V = len(clip.rig)
    intr = np.zeros((T, V, 4), np.float32)
    c2w = np.zeros((T, V, 4, 4), np.float32)
    for t in range(T):
        for v in range(V):
            cam = clip.camera(t, v)
            intr[t, v] = (cam.fx, cam.fy, cam.cx, cam.cy)
            c2w[t, v] = cam.camera_to_world
    return intr, c2w


def sample_from_simulation(clip, conditions: dict, max_boxes: int) -> dict:
    """A `worldsplat.world.simulate` clip + `world.conditions()` -> one training sample."""
    intr, c2w = rig_arrays(clip)
    ego = np.asarray(clip.ego_to_world, np.float64)
    return {
        "rgb": np.asarray(clip.rgb, np.uint8),
        "depth": np.asarray(clip.depth, np.float32),
        "dynamic": np.asarray(clip.dynamic, bool),
        "sketch": sketch_rgb(conditions["sketch"]),
        **_poses_and_boxes(
            intr, c2w, ego, conditions["boxes"], max_boxes, conditions["ego_traj"], conditions["caption"]
        ),
    }


def _poses_and_boxes(intr, c2w, ego: np.ndarray, boxes: list, max_boxes: int, traj, caption) -> dict:
    """The sample fields from `intrinsics` to `caption` (module docstring); `ego` (T,4,4) float64, `boxes` one
    list per frame in the world frame (`pack_boxes` puts them in each frame's ego frame)."""
    corners, cls, moving, mask = pack_boxes(boxes, ego, max_boxes)
    return {
        "intrinsics": intr,
        "cam_to_world": c2w,
        "ego_to_world": ego.astype(np.float32),
        "box_corners": corners,
        "box_cls": cls,
        "box_moving": moving,
        "box_mask": mask,
        "traj": np.asarray(traj, np.float32),
        "caption": str(caption),
    }


def sample_from_scenario(scenario, shift_m: float = 0.0, max_boxes: int = 32) -> dict:
    world = build_world(scenario)
    return sample_from_simulation(simulate(world, shift_m=shift_m), world.conditions(shift_m=shift_m), max_boxes)


def synthetic_sample(cfg: DataConfig, seed: int) -> dict:
    """Random but well-formed sample (for tests and the DDP smoke test; not a world)."""
    rng = np.random.default_rng(seed)
    T, V, H, W, N = cfg.frames, cfg.views, cfg.height, cfg.width, cfg.max_boxes
    rig = default_rig(W, H)[:V]
    ego = np.stack([np.eye(4)] * T).astype(np.float64)
    ego[:, 0, 3] = np.arange(T) * 1.0
    c2w = np.array([[ego[t] @ rc.camera_to_ego for rc in rig] for t in range(T)], np.float32)
    intr = np.array([[[rc.fx, rc.fy, rc.cx, rc.cy] for rc in rig]] * T, np.float32)
    depth = rng.uniform(2, 60, (T, V, H, W)).astype(np.float32)
    depth[:, :, : H // 3] = np.inf
    corners = rng.normal(0, 10, (T, N, 8, 3)).astype(np.float32)
    return {
        "rgb": rng.integers(0, 256, (T, V, H, W, 3), dtype=np.uint8),
        "depth": depth,
        "dynamic": rng.random((T, V, H, W)) > 0.8,
        "sketch": (rng.random((T, V, H, W, 3)) > 0.9).astype(np.float32),
        "intrinsics": intr,
        "cam_to_world": c2w,
        "ego_to_world": ego.astype(np.float32),
        "box_corners": corners,
        "box_cls": rng.integers(12, 17, (T, N)),
        "box_moving": rng.random((T, N)) > 0.5,
        "box_mask": rng.random((T, N)) > 0.5,
        "traj": ego.astype(np.float32),
        "caption": f"synthetic {seed}",
    }


# --- dataset shards (`worldsplat dataset --out DIR`: one clip_XXXXXX.npz per clip, keys in web/docs/world.md) -----


def sample_from_shard(z: dict, max_boxes: int, shift_index: int | None = None) -> dict:
    """A loaded shard (dict of arrays) -> one sample. shift_index selects a shifted-track truth (`shifts` key)."""
    ego = np.asarray(z["ego_to_world"], np.float64)
    T = ego.shape[0]
    K = np.asarray(z["K"], np.float64)
    c2e = np.asarray(z["camera_to_ego"], np.float64)
    V = K.shape[0]
    shift = 0.0 if shift_index is None else float(z["shifts"][shift_index])
    sh = np.eye(4)
    sh[1, 3] = shift
    c2w = np.einsum("tij,jk,vkl->tvil", ego, sh, c2e).astype(np.float32)
    intr = np.broadcast_to(np.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1), (T, V, 4))
    corners_w = np.asarray(z["box_corners"], np.float64)
    n = corners_w.shape[1]
    boxes = [
        [
            {"corners": corners_w[t, k], "cls": int(z["box_cls"][k]), "moving": bool(z["box_moving"][k])}
            for k in range(n)
        ]
        for t in range(T)
    ]
    sfx = "" if shift_index is None else "_shifted"
    pick_ = (lambda a: a) if shift_index is None else (lambda a: a[shift_index])
    return {
        "rgb": pick_(z["rgb" + sfx]),
        "depth": pick_(z["depth" + sfx]).astype(np.float32),
        "dynamic": pick_(z["dynamic" + sfx]).astype(bool),
        "sketch": sketch_rgb(pick_(z["sketch" + sfx])),
        **_poses_and_boxes(
            np.ascontiguousarray(intr, dtype=np.float32), c2w, ego, boxes, max_boxes, z["ego_traj"], z["caption"]
        ),
        "seed": int(z["seed"]),
        "scenario": str(z["scenario"]),
        "shift_m": shift,
    }


def shard_files(root: str | os.PathLike, split: str, limit: int | None = None) -> list[Path]:
    """The clip shards `ROOT/<split>/clip_*.npz` in index order (at most `limit`); a clear error when there are none."""
    folder = Path(root) / split
    files = sorted(folder.glob("clip_*.npz"))
    if not files:
        raise FileNotFoundError(
            f"no clip_*.npz shards in {folder} (write them with `worldsplat dataset --split {split} --out {root}`)"
        )
    return files[:limit] if limit else files


class ShardDataset:
    """Clips of `DIR/<split>/clip_*.npz` in index order, read lazily."""

    def __init__(self, root: str | os.PathLike, split: str, max_boxes: int = 32, limit: int | None = None):
        self.dir = Path(root) / split
        self.files = shard_files(root, split, limit)
        self.max_boxes = max_boxes

    def __len__(self) -> int:
        return len(self.files)

    def load(self, i: int) -> dict:
        with np.load(self.files[i], allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def __getitem__(self, i: int) -> dict:
        return sample_from_shard(self.load(i), self.max_boxes)

    def shifted(self, i: int) -> list[dict]:
        """Samples of the shifted tracks stored in shard i (empty if it was written without --shifts)."""
        z = self.load(i)
        return [sample_from_shard(z, self.max_boxes, j) for j in range(len(z.get("shifts", [])))]


def collate(samples: list[dict]) -> dict:
    out = {}
    for k in samples[0]:
        if isinstance(samples[0][k], str):
            out[k] = [s[k] for s in samples]
        elif isinstance(samples[0][k], torch.Tensor):
            out[k] = torch.stack([s[k] for s in samples])
        else:
            out[k] = torch.from_numpy(np.stack([np.asarray(s[k]) for s in samples]))
    return out


def vae_inputs(batch: dict, cfg: DataConfig) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Collated batch -> per-image VAE inputs (B*T*V, C, H, W): rgb [-1,1], normalised depth, mask {0,1},
    sketch [-1,1]."""
    rgb = batch["rgb"].float().div(127.5).sub(1.0).flatten(0, 2).permute(0, 3, 1, 2)
    depth = normalize_depth(batch["depth"], cfg.depth_near, cfg.depth_far).flatten(0, 2)[:, None]
    mask = batch["dynamic"].float().flatten(0, 2)[:, None]
    sketch = batch["sketch"].float().mul(2).sub(1).flatten(0, 2).permute(0, 3, 1, 2) if "sketch" in batch else None
    return rgb, depth, mask, sketch
