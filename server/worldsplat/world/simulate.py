"""`simulate(world, shift_m, cameras, frames)`: render a world's exact ground truth into a `Clip`."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from worldsplat.core.camera import Camera, RigCamera
from worldsplat.world.layout import World, shifted_ego
from worldsplat.world.render import render_frame, single_threaded_blas


@dataclass
class Clip:
    rig: list[RigCamera]
    ego_to_world: np.ndarray  # (T,4,4) float64, the (unshifted) ego track
    frame_times: np.ndarray  # (T,) float64 seconds
    fps: float
    rgb: np.ndarray  # (T,V,H,W,3) uint8
    depth: np.ndarray  # (T,V,H,W) float32 camera z in metres, sky = +inf
    dynamic: np.ndarray  # (T,V,H,W) bool: pixels of moving agents
    semantic: np.ndarray  # (T,V,H,W) uint8 class ids (worldsplat.world.classes)
    caption: str
    shift_m: float = 0.0
    frame_indices: tuple[int, ...] = ()  # which world frames these are

    @property
    def camera_names(self) -> list[str]:
        return [c.name for c in self.rig]

    def camera(self, t: int, v: int) -> Camera:
        """World camera of frame t (index into this clip), view v, including the shift."""
        return self.rig[v].at(self.ego_to_world[t], self.shift_m)


def render_views(world: World, t: int, cameras: list[Camera], shift_m: float = 0.0) -> dict:
    """Render any cameras (e.g. from a camera JSON) against the world at frame t: rgb (V,H,W,3), depth, dynamic,
    semantic. The ego (headlights, shadow-map centre) is the track shifted by `shift_m`."""
    names = [c.name for c in world.rig]
    view_ids = [names.index(c.name) if c.name in names else len(names) + i for i, c in enumerate(cameras)]
    with single_threaded_blas():
        return render_frame(world, t, cameras, view_ids, shifted_ego(world.ego_to_world, shift_m)[t])


def render_threads() -> int:
    env = os.environ.get("WORLDSPLAT_RENDER_THREADS")
    if env:
        return max(1, int(env))
    return min(2, os.cpu_count() or 1)


def simulate(
    world: World, shift_m: float = 0.0, cameras: list[str] | None = None, frames: list[int] | None = None
) -> Clip:
    """Render RGB, depth, dynamic mask and semantics for every camera and frame (the track shifted left by
    `shift_m` metres along the ego y axis)."""
    if not np.isfinite(shift_m) or abs(shift_m) > 50:
        raise ValueError(f"shift_m must be finite and within +-50 m, got {shift_m}")
    rig = world.rig if cameras is None else [world.rig_camera(n) for n in cameras]
    if frames is None:
        frames = list(range(world.num_frames))
    for f in frames:
        if not 0 <= f < world.num_frames:
            raise ValueError(f"frame {f} out of range 0..{world.num_frames - 1}")
    names = [c.name for c in world.rig]
    view_ids = [names.index(c.name) for c in rig]
    poses = shifted_ego(world.ego_to_world, shift_m)

    def one(t: int) -> dict:
        cams = [rc.at(world.ego_to_world[t], shift_m) for rc in rig]
        return render_frame(world, t, cams, view_ids, poses[t])

    # Frames are independent and numpy releases the GIL: render them on a couple of threads (results are
    # identical to a serial run; `WORLDSPLAT_RENDER_THREADS=1` forces serial).
    threads = min(render_threads(), len(frames))
    with single_threaded_blas():
        if threads > 1:
            with ThreadPoolExecutor(threads) as pool:
                outs = list(pool.map(one, frames))
        else:
            outs = [one(t) for t in frames]
    return Clip(
        rig=list(rig),
        ego_to_world=world.ego_to_world[frames].copy(),
        frame_times=world.frame_times[frames].copy(),
        fps=world.fps,
        rgb=np.stack([o["rgb"] for o in outs]),
        depth=np.stack([o["depth"] for o in outs]),
        dynamic=np.stack([o["dynamic"] for o in outs]),
        semantic=np.stack([o["semantic"] for o in outs]),
        caption=world.caption,
        shift_m=float(shift_m),
        frame_indices=tuple(frames),
    )
