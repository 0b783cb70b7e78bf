"""`worldsplat dataset ... --ray`: the same shards as `worldsplat.world.dataset.write_dataset`, one Ray task per clip.

The driver checks the folder belongs to this run, skips complete shards (a finished shard is never redone), submits
the rest, and writes the manifest once every task is done. Each task calls the one per-clip step
(`world.dataset.write_clip`, atomic write), so a shard is byte-identical to the local run's and a worker killed
mid-way leaves at most a hidden temporary file, which the retry and the next run ignore and clean up.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from worldsplat.scale.ray_runner import TaskResources, run_tasks
from worldsplat.world.dataset import (
    EXPLICIT_AGENTS,
    check_same_run,
    prepare_split,
    run_params,
    shard_path,
    write_clip,
    write_manifest,
)


def clip_task(out: str, split: str, index: int, shifts: tuple, kw: dict, threads: int, fault: Callable | None):
    """One clip on a worker. `fault(index)` is a test hook (it may kill the worker mid-way)."""
    os.environ["WORLDSPLAT_RENDER_THREADS"] = str(threads)
    if fault is not None:
        fault(index)
    return write_clip(Path(out), split, index, tuple(shifts), **kw)


def write_dataset_ray(
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
    resources: TaskResources | None = None,
    fault: Callable | None = None,
    explicit_agents: float = EXPLICIT_AGENTS,
) -> dict:
    """Like `write_dataset`, inside a `ray_session`; returns written / skipped / manifest."""
    res = resources or TaskResources()
    out = Path(out).resolve()  # the workers' view of the folder: absolute (shared storage on a cluster)
    kw = dict(
        width=width, height=height, frames=frames, fps=fps, preset_mix=preset_mix, explicit_agents=explicit_agents
    )
    indices = range(start, start + count)
    check_same_run(out, split, indices, shifts, **kw)
    prepare_split(out, split)
    done = [i for i in indices if shard_path(out, split, i).exists()]
    todo = [i for i in indices if i not in set(done)]
    entries = {i: write_clip(out, split, i, shifts, **kw)[0] for i in done}  # complete: entry only, no write
    results = run_tasks(
        clip_task,
        [(str(out), split, i, tuple(shifts), kw, res.threads, fault) for i in todo],
        res,
        desc=f"dataset {split} (ray)",
        unit="clip",
        progress=progress,
    )
    written = 0
    for i, (entry, wrote) in zip(todo, results):
        entries[i] = entry
        written += wrote
    prepare_split(out, split)  # temporaries of workers killed mid-way
    mpath = write_manifest(
        out,
        split,
        [entries[i] for i in indices],
        run_params(width, height, frames, fps, preset_mix, shifts, explicit_agents),
    )
    return {"written": written, "skipped": len(indices) - written, "manifest": str(mpath)}
