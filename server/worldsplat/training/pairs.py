"""Novel-view samples: (render of a shifted track, exact ground truth of that track, its reprojected conditions).

The refinement model trains on them (worldsplat.training.enhancer) and `worldsplat eval nvs` scores on them.
A sample is a dict of numpy arrays (T frames, V views, H x W images):

    shift_m float                   seed int                  caption str
    target (T,V,H,W,3) uint8        ground truth of the shifted track      target_depth (T,V,H,W) float32 (sky inf)
    sketch (T,V,H,W,3) uint8 {0,1}  reprojected S' for the shifted rig
    box_corners (T,N,8,3) float32   reprojected B' in each frame's shifted ego frame, nearest first; box_cls (T,N),
    box_moving (T,N), box_mask (T,N)                                        traj (T,4,4) shifted ego vs its frame 0
    render_4d / alpha_4d / depth_4d   the 4D-aggregated oracle lifting of the ORIGINAL track (shift 0) rendered
    render_3d / alpha_3d / depth_3d   single-frame 3D Gaussians (ablation B), same cameras
Only the render kinds asked for are present. Files: one .npz per (seed, shift) under a cache directory.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from worldsplat.core.io import write_npz_atomic
from worldsplat.core.scenario import random_scenario
from worldsplat.pipeline.conditions import conditions_for_track
from worldsplat.pipeline.render import render_scene_track, render_single_frame_track
from worldsplat.pipeline.scene import oracle_scene
from worldsplat.world import simulate
from worldsplat.world.dataset import split_seed


def split_seeds(split: str, count: int, start: int = 0) -> list[int]:
    """Seeds of clips [start, start+count) of a split: the world dataset's disjoint ranges (one definition)."""
    if count < 0 or start < 0:
        raise ValueError("count and start must be non-negative")
    return [split_seed(split, i) for i in range(start, start + count)]


def sample_scenario(seed: int, width: int = 112, height: int = 64, frames: int = 4):
    return random_scenario(seed, width=width, height=height, frames=frames)


def make_sample(
    world, shift_m: float, renders: tuple[str, ...] = ("4d",), source=None, scene=None, max_boxes: int = 32
) -> dict:
    """One novel-view sample of `world` at `shift_m` (see the module doc). `source` (the unshifted clip) and
    `scene` (its oracle Scene4D) can be passed in to share them between shifts."""
    unknown = set(renders) - {"4d", "3d"}
    if unknown:
        raise ValueError(f"unknown render kind(s) {sorted(unknown)}; expected 4d and/or 3d")
    truth = simulate(world, shift_m=shift_m)
    out = {
        "shift_m": np.float32(shift_m),
        "seed": np.int64(world.scenario.seed),
        "target": truth.rgb,
        "target_depth": truth.depth.astype(np.float32),
        **conditions_for_track(world, shift_m, max_boxes),
    }
    if renders:
        source = source if source is not None else (truth if shift_m == 0 else simulate(world, shift_m=0.0))
    if "4d" in renders:
        scene = scene if scene is not None else oracle_scene(source)
        r = render_scene_track(scene, shift_m)
        out.update(render_4d=r.rgb, alpha_4d=r.alpha.astype(np.float16), depth_4d=r.depth.astype(np.float16))
    if "3d" in renders:
        r = render_single_frame_track(source, shift_m)
        out.update(render_3d=r.rgb, alpha_3d=r.alpha.astype(np.float16), depth_3d=r.depth.astype(np.float16))
    return out


def save_sample(path: Path, sample: dict) -> None:
    """Atomic .npz write so an interrupted generator never leaves a torn sample."""
    write_npz_atomic(path, sample)


def load_sample(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        out = {k: z[k] for k in z.files}
    out["caption"] = str(out["caption"])
    out["shift_m"] = float(out["shift_m"])
    out["seed"] = int(out["seed"])
    return out


def sample_path(cache: Path, split: str, seed: int, shift_m: float, tag: str = "") -> Path:
    return Path(cache) / split / f"seed{seed:08d}_shift{shift_m:+.1f}{tag}.npz"
