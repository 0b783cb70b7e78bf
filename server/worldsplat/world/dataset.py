"""Sharded training data from the world: one compressed .npz per clip, resumable, non-overlapping split seeds.

Split seed ranges never overlap: train [0, 1e6), val [1e6, 2e6), test [2e6, 3e6); clip i of a split uses seed
`SPLIT_BASE[split] + i` and a random scenario drawn from that seed (`worldsplat.core.scenario.random_scenario`).
A shard is written to a temporary file and renamed, so an existing `clip_XXXXXX.npz` is always complete and a
re-run skips it. Shard keys are listed in `SHARD_KEYS` and documented in web/docs/world.md.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from worldsplat.core.io import write_json_atomic, write_npz_atomic
from worldsplat.core.scenario import Scenario, random_scenario, scenario_id
from worldsplat.world import build_world, simulate

SPLIT_BASE = {"train": 0, "val": 1_000_000, "test": 2_000_000}
SPLIT_SIZE = 1_000_000
SHARD_KEYS = (
    "rgb",
    "depth",
    "dynamic",
    "semantic",
    "bev",
    "bev_channels",
    "sketch",
    "layout",
    "box_corners",
    "box_cls",
    "box_track_id",
    "box_moving",
    "ego_to_world",
    "ego_traj",
    "frame_times",
    "K",
    "camera_to_ego",
    "camera_names",
    "caption",
    "scenario",
    "seed",
)


def split_seed(split: str, index: int) -> int:
    if split not in SPLIT_BASE:
        raise ValueError(f"split must be one of {sorted(SPLIT_BASE)}, got {split!r}")
    if not 0 <= index < SPLIT_SIZE:
        raise ValueError(f"clip index {index} outside 0..{SPLIT_SIZE - 1}")
    return SPLIT_BASE[split] + index


def shard_path(out: Path, split: str, index: int) -> Path:
    return Path(out) / split / f"clip_{index:06d}.npz"


def clip_arrays(scenario: Scenario, shifts: tuple[float, ...] = ()) -> dict[str, np.ndarray]:
    """Everything one training clip needs, as arrays (see SHARD_KEYS); `shifts` adds shifted-track truth."""

    world = build_world(scenario)
    clip = simulate(world)
    cond = world.conditions(layout_size=(clip.rgb.shape[3], clip.rgb.shape[2]))
    T = clip.rgb.shape[0]
    n = len(world.agents)
    corners = np.zeros((T, n, 8, 3), np.float32)
    for t, frame in enumerate(cond["boxes"]):
        for k, b in enumerate(frame):
            corners[t, k] = b["corners"]
    out = {
        "rgb": clip.rgb,
        "depth": clip.depth,
        "dynamic": clip.dynamic,
        "semantic": clip.semantic,
        "bev": (cond["bev"] > 0.5).astype(np.uint8),
        "bev_channels": np.array(cond["bev_channels"]),
        "sketch": (cond["sketch"] > 0.5).astype(np.uint8),
        "layout": cond["layout"].astype(np.float16),
        "box_corners": corners,
        "box_cls": np.array([a.cls for a in world.agents], np.uint8),
        "box_track_id": np.array([a.track_id for a in world.agents], np.int32),
        "box_moving": np.array([a.moving for a in world.agents], bool),
        "ego_to_world": clip.ego_to_world,
        "ego_traj": cond["ego_traj"],
        "frame_times": clip.frame_times,
        "K": np.stack([np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1.0]]) for c in clip.rig]),
        "camera_to_ego": np.stack([c.camera_to_ego for c in clip.rig]),
        "camera_names": np.array(clip.camera_names),
        "caption": np.array(clip.caption),
        "scenario": np.array(scenario.normalized_json()),
        "seed": np.array(scenario.seed, np.int64),
    }
    if shifts:
        shifted = [simulate(world, shift_m=s) for s in shifts]
        out["shifts"] = np.array(shifts, np.float64)
        out["rgb_shifted"] = np.stack([c.rgb for c in shifted])
        out["depth_shifted"] = np.stack([c.depth for c in shifted])
        out["dynamic_shifted"] = np.stack([c.dynamic for c in shifted])
        out["sketch_shifted"] = np.stack([(world.conditions(s)["sketch"] > 0.5).astype(np.uint8) for s in shifts])
    return out


def write_shard(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Atomic (worldsplat.core.io): a reader never sees a torn shard."""
    write_npz_atomic(path, arrays, compressed=True)


def load_shard(path: str | Path) -> dict:
    """A shard as a dict of arrays; `caption` and `scenario` come back as str, `bev`/`sketch` as float32."""
    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    d["caption"] = str(d["caption"])
    d["scenario"] = str(d["scenario"])
    d["bev"] = d["bev"].astype(np.float32)
    d["sketch"] = d["sketch"].astype(np.float32)
    return d


def write_dataset(
    out: Path,
    split: str,
    count: int,
    width: int = 112,
    height: int = 64,
    frames: int = 4,
    fps: float = 4.0,
    preset_mix: bool = False,
    shifts: tuple[float, ...] = (),
    start: int = 0,
    progress: bool = True,
) -> dict:
    """Write clips start..start+count-1 of a split; existing complete shards are skipped (resumable)."""

    out = Path(out)
    (out / split).mkdir(parents=True, exist_ok=True)
    for stale in (out / split).glob(".clip_*.tmp"):
        stale.unlink()
    written = skipped = 0
    index = []
    for i in tqdm(range(start, start + count), desc=f"dataset {split}", unit="clip", disable=not progress):
        seed = split_seed(split, i)
        sc = random_scenario(seed, width=width, height=height, frames=frames, fps=fps, preset_mix=preset_mix)
        path = shard_path(out, split, i)
        index.append({"file": path.name, "seed": seed, "scenario_id": scenario_id(sc)})
        if path.exists():
            skipped += 1
            continue
        write_shard(path, clip_arrays(sc, shifts))
        written += 1
    mpath = out / split / "manifest.json"
    clips = {c["file"]: c for c in (json.loads(mpath.read_text())["clips"] if mpath.exists() else [])}
    clips.update({c["file"]: c for c in index})
    manifest = {
        "format": "worldsplat-dataset-v1",
        "split": split,
        "seed_range": [SPLIT_BASE[split], SPLIT_BASE[split] + SPLIT_SIZE],
        "image": [width, height],
        "frames": frames,
        "fps": fps,
        "preset_mix": preset_mix,
        "shifts": list(shifts),
        "keys": list(SHARD_KEYS),
        "clips": [clips[k] for k in sorted(clips)],
    }
    write_json_atomic(mpath, manifest, sort_keys=False)
    return {"written": written, "skipped": skipped, "manifest": str(mpath)}
