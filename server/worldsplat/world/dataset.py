"""Sharded training data from the world: one compressed .npz per clip, resumable, non-overlapping split seeds.

Split seed ranges never overlap: train [0, 1e6), val [1e6, 2e6), test [2e6, 3e6); clip i of a split uses seed
`SPLIT_BASE[split] + i` and a random scenario drawn from that seed (`worldsplat.core.scenario.random_scenario`), which
carries explicit agents with probability `EXPLICIT_AGENTS` (0.5).
A shard is written to a temporary file and renamed, so an existing `clip_XXXXXX.npz` is always complete and a
re-run skips it. Shard keys are listed in `SHARD_KEYS` and documented in web/docs/world.md.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from worldsplat.core.io import write_json_atomic, write_npz_atomic
from worldsplat.core.scenario import Scenario, random_scenario, scenario_id
from worldsplat.world import build_world, simulate

SPLIT_BASE = {"train": 0, "val": 1_000_000, "test": 2_000_000}
SPLIT_SIZE = 1_000_000
# The fraction of clips whose scenario also gets 1-3 explicit (scenario v2) agents, so the models learn placed and
# scripted agents beside the procedural traffic (`worldsplat.core.scenario.add_random_agents`: lanes of the ego's
# direction, faster than the ego, or standing in an oncoming lane; drawn from a random stream of their own seeded by
# the clip's seed, so a clip is the same on every run and the split seed ranges keep them disjoint).
# `worldsplat dataset --explicit-agents P` changes it; 0 gives the datasets written before it (no explicit agents).
EXPLICIT_AGENTS = 0.5
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


def clip_scenario(
    split: str,
    index: int,
    width: int = 112,
    height: int = 64,
    frames: int = 4,
    fps: float = 4.0,
    preset_mix=False,
    explicit_agents: float = EXPLICIT_AGENTS,
) -> Scenario:
    """The scenario of clip `index` of a split (its seed is `split_seed(split, index)`); with probability
    `explicit_agents` it carries explicit agents."""
    seed = split_seed(split, index)
    return random_scenario(
        seed, width=width, height=height, frames=frames, fps=fps, preset_mix=preset_mix, explicit_agents=explicit_agents
    )


def write_clip(out: Path, split: str, index: int, shifts: tuple[float, ...] = (), **scenario_kw) -> tuple[dict, bool]:
    """Clip `index`: its manifest entry, and its shard written unless a complete one exists (-> entry, written).
    The one per-clip step of `write_dataset`, also what a worker of a distributed run calls
    (worldsplat.scale.dataset), so both write the same bytes."""
    sc = clip_scenario(split, index, **scenario_kw)
    path = shard_path(out, split, index)
    entry = {"file": path.name, "seed": sc.seed, "scenario_id": scenario_id(sc)}
    if path.exists():
        return entry, False
    write_shard(path, clip_arrays(sc, shifts))
    return entry, True


def run_params(
    width: int, height: int, frames: int, fps: float, preset_mix: bool, shifts, explicit_agents: float = EXPLICIT_AGENTS
) -> dict:
    """What the manifest records about how its clips were made; a later run into the same folder must match."""
    return {
        "image": [width, height],
        "frames": frames,
        "fps": fps,
        "preset_mix": preset_mix,
        "explicit_agents": float(explicit_agents),
        "shifts": list(shifts),
    }


# a manifest written before a parameter existed was written with this value of it
RUN_PARAM_BEFORE = {"explicit_agents": 0.0}


def check_same_run(out: Path, split: str, indices: range, shifts: tuple[float, ...] = (), **scenario_kw) -> None:
    """Refuse to resume into a split folder written by another run (other image size, frames, fps, preset mix or
    shifts): its manifest, and the first complete shard in `indices`, must be what this run would write. Both
    writers (local and Ray) call it before anything is written, so it also checks their shared arguments."""
    p = scenario_kw.get("explicit_agents", EXPLICIT_AGENTS)
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"explicit_agents must be a probability in [0, 1], got {p}")
    folder = Path(out) / split
    mpath = folder / "manifest.json"
    kw = {
        "width": 112,
        "height": 64,
        "frames": 4,
        "fps": 4.0,
        "preset_mix": False,
        "explicit_agents": EXPLICIT_AGENTS,
        **scenario_kw,
    }
    mine = run_params(
        kw["width"], kw["height"], kw["frames"], kw["fps"], kw["preset_mix"], shifts, kw["explicit_agents"]
    )
    if mpath.exists():
        theirs = json.loads(mpath.read_text())
        theirs = {**RUN_PARAM_BEFORE, **theirs}
        diff = [f"{k} {theirs.get(k)} (this run: {v})" for k, v in mine.items() if theirs.get(k) != v]
        if diff:
            raise ValueError(f"{folder} holds a dataset of another run: {'; '.join(diff)}; write to another --out")
    for i in indices:
        path = shard_path(out, split, i)
        if path.exists():
            with np.load(path, allow_pickle=False) as z:
                theirs = str(z["scenario"]) if "scenario" in z.files else ""
            if theirs != clip_scenario(split, i, **scenario_kw).normalized_json():
                raise ValueError(
                    f"{path} was written by another run (its scenario differs from clip {i} of this one: other "
                    f"image size, frames, fps, preset mix or explicit agents); write to another --out"
                )
            break


def write_manifest(out: Path, split: str, entries: list[dict], params: dict) -> Path:
    """Merge `entries` into OUT/SPLIT/manifest.json (atomic); `params` from `run_params`."""
    mpath = Path(out) / split / "manifest.json"
    clips = {c["file"]: c for c in (json.loads(mpath.read_text())["clips"] if mpath.exists() else [])}
    clips.update({c["file"]: c for c in entries})
    manifest = {
        "format": "worldsplat-dataset-v1",
        "split": split,
        "seed_range": [SPLIT_BASE[split], SPLIT_BASE[split] + SPLIT_SIZE],
        **params,
        "keys": list(SHARD_KEYS),
        "clips": [clips[k] for k in sorted(clips)],
    }
    write_json_atomic(mpath, manifest, sort_keys=False)
    return mpath


def prepare_split(out: Path, split: str) -> None:
    """Create OUT/SPLIT and remove the temporary files an interrupted writer left (never taken for shards)."""
    (Path(out) / split).mkdir(parents=True, exist_ok=True)
    for stale in (Path(out) / split).glob(".clip_*.tmp"):
        stale.unlink(missing_ok=True)


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
    explicit_agents: float = EXPLICIT_AGENTS,
    write_clips: Callable | None = None,
) -> dict:
    """Write clips start..start+count-1 of a split; existing complete shards are skipped (resumable).
    `write_clips(out, split, indices, shifts, kw, progress)` writes the clips (`write_clip` each) and returns their
    (manifest entry, written) in index order: by default one after the other here; `worldsplat.scale.dataset`
    runs one Ray task per clip."""

    out = Path(out)
    kw = dict(
        width=width, height=height, frames=frames, fps=fps, preset_mix=preset_mix, explicit_agents=explicit_agents
    )
    indices = range(start, start + count)
    check_same_run(out, split, indices, shifts, **kw)
    prepare_split(out, split)
    clips = (write_clips or _write_clips_here)(out, split, indices, shifts, kw, progress)
    written = sum(wrote for _, wrote in clips)
    params = run_params(width, height, frames, fps, preset_mix, shifts, explicit_agents)
    mpath = write_manifest(out, split, [entry for entry, _ in clips], params)
    return {"written": written, "skipped": len(indices) - written, "manifest": str(mpath)}


def _write_clips_here(out: Path, split: str, indices: range, shifts: tuple, kw: dict, progress: bool) -> list:
    clips = tqdm(indices, desc=f"dataset {split}", unit="clip", disable=not progress)
    return [write_clip(out, split, i, shifts, **kw) for i in clips]
