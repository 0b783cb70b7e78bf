"""The models' condition arrays from the world: boxes packed in each frame's ego frame, sketches as RGB, and the
reprojected conditions (S', B', T', caption) of a shifted track (paper §3.5) that refinement reads."""

from __future__ import annotations

import numpy as np
import torch

from worldsplat.world.layout import shifted_ego


def pack_boxes(boxes_per_frame: list[list[dict]], ego_to_world: np.ndarray, max_boxes: int):
    """World-frame boxes per frame -> padded arrays in each frame's ego frame (nearest boxes kept)."""
    T = len(boxes_per_frame)
    corners = np.zeros((T, max_boxes, 8, 3), np.float32)
    cls = np.zeros((T, max_boxes), np.int64)
    moving = np.zeros((T, max_boxes), bool)
    mask = np.zeros((T, max_boxes), bool)
    for t, boxes in enumerate(boxes_per_frame):
        w2e = np.linalg.inv(np.asarray(ego_to_world[t], np.float64))
        items = []
        for b in boxes:
            c = np.asarray(b["corners"], np.float64).reshape(8, 3)
            ce = c @ w2e[:3, :3].T + w2e[:3, 3]
            items.append((float(np.linalg.norm(ce.mean(0)[:2])), ce, int(b["cls"]), bool(b.get("moving", False))))
        items.sort(key=lambda it: it[0])
        for i, (_, ce, c_id, mv) in enumerate(items[:max_boxes]):
            corners[t, i], cls[t, i], moving[t, i], mask[t, i] = ce, c_id, mv, True
    return corners, cls, moving, mask


def sketch_rgb(sketch: np.ndarray) -> np.ndarray:
    s = np.asarray(sketch, np.float32)
    if s.ndim == 4:
        s = s[..., None]
    if s.shape[-1] == 1:
        s = np.repeat(s, 3, axis=-1)
    return np.clip(s, 0.0, 1.0)


def conditions_for_track(world, shift_m: float, max_boxes: int = 32, cameras: list[str] | None = None) -> dict:
    """Reprojected conditions of the shifted track: sketch S', boxes B' (in the shifted ego frames), trajectory T',
    caption."""
    cond = world.conditions(shift_m=shift_m, cameras=cameras)
    ego = shifted_ego(world.ego_to_world, shift_m)
    corners, cls, moving, mask = pack_boxes(cond["boxes"], ego, max_boxes)
    sk = np.asarray(cond["sketch"], np.float32)
    if sk.ndim == 4:
        sk = np.repeat(sk[..., None], 3, axis=-1)
    return {
        "sketch": (sk > 0.5).astype(np.uint8),
        "box_corners": corners.astype(np.float32),
        "box_cls": cls,
        "box_moving": moving,
        "box_mask": mask,
        "traj": np.asarray(cond["ego_traj"], np.float32),
        "caption": str(cond["caption"]),
    }


def rig_tensors(rig, ego_to_world: np.ndarray, native_hw: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """intrinsics (T,V,4) rescaled to the native image size, cam_to_world (T,V,4,4)."""
    H, W = native_hw
    T = len(ego_to_world)
    intr = np.zeros((T, len(rig), 4), np.float32)
    c2w = np.zeros((T, len(rig), 4, 4), np.float32)
    for v, rc in enumerate(rig):
        sx, sy = W / rc.width, H / rc.height
        intr[:, v] = (rc.fx * sx, rc.fy * sy, rc.cx * sx, rc.cy * sy)
        for t in range(T):
            c2w[t, v] = np.asarray(ego_to_world[t]) @ rc.camera_to_ego
    return torch.from_numpy(intr), torch.from_numpy(c2w)
