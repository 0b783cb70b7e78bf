"""`worldsplat dataset ... --ray`: the same shards as `worldsplat.world.dataset.write_dataset`, one Ray task per clip.

The driver checks the folder belongs to this run, skips complete shards (a finished shard is never redone), submits
the rest, and writes the manifest once every task is done. Each task calls the one per-clip step
(`world.dataset.write_clip`, atomic write), so a shard is byte-identical to the local run's and a worker killed
mid-way leaves at most a hidden temporary file, which the retry and the next run ignore and clean up.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from pathlib import Path

from worldsplat.scale.ray_runner import TaskResources, run_tasks
from worldsplat.world.dataset import prepare_split, shard_path, write_clip, write_dataset


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
    resources: TaskResources | None = None,
    fault: Callable | None = None,
    **options,
) -> dict:
    """`write_dataset` with the same options, one Ray task per clip, inside a `ray_session`; returns written /
    skipped / manifest."""
    write_clips = functools.partial(_write_clips_ray, resources or TaskResources(), fault)
    # the workers' view of the folder: absolute (shared storage on a cluster)
    return write_dataset(Path(out).resolve(), split, count, write_clips=write_clips, **options)


def _write_clips_ray(
    res: TaskResources,
    fault: Callable | None,
    out: Path,
    split: str,
    indices: range,
    shifts: tuple,
    kw: dict,
    progress: bool,
) -> list:
    done = [i for i in indices if shard_path(out, split, i).exists()]
    todo = [i for i in indices if i not in set(done)]
    clips = {i: (write_clip(out, split, i, shifts, **kw)[0], False) for i in done}  # complete: entry only, no write
    results = run_tasks(
        clip_task,
        [(str(out), split, i, tuple(shifts), kw, res.threads, fault) for i in todo],
        res,
        desc=f"dataset {split} (ray)",
        unit="clip",
        progress=progress,
    )
    for i, (entry, wrote) in zip(todo, results):
        clips[i] = entry, wrote
    prepare_split(out, split)  # temporaries of workers killed mid-way
    return [clips[i] for i in indices]
