"""`python -m worldsplat.scale.throughput --clips 8 --out DIR`: clips (and scenes) per minute, local vs Ray.

Writes the same dataset (default clips: 112x64, 4 frames, 6 cameras) and the same oracle batch (`urban_straight`,
4 frames, half as many scenes) locally and through `ray.init(num_cpus=WORKERS)`, checks the outputs are identical
byte for byte, and prints one JSON object (the figures of web/docs/scale-out.md). Ray's start-up is timed apart.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path

from worldsplat.core.scenario import load_preset
from worldsplat.scale.batch import run_batch
from worldsplat.scale.dataset import write_dataset_ray
from worldsplat.scale.ray_runner import TaskResources, start_local
from worldsplat.world.dataset import write_dataset


def _same(a: Path, b: Path) -> bool:
    fa = {p.relative_to(a): p.read_bytes() for p in a.rglob("*") if p.is_file()}
    fb = {p.relative_to(b): p.read_bytes() for p in b.rglob("*") if p.is_file()}
    return fa == fb


def measure(out: Path, clips: int, workers: int = 2, part: str = "both") -> dict:
    import ray  # noqa: PLC0415 - heavy optional dependency, this measurement is about it

    out = Path(out)
    if part != "ray":
        shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)
    scenes = max(1, clips // 2)
    base = load_preset("urban_straight")
    lines = "".join(base.with_updates(seed=100 + i, clip={"frames": 4}).normalized_json() + "\n" for i in range(scenes))
    (out / "scenarios.jsonl").write_text(lines)
    r: dict = {"clips": clips, "scenes": scenes, "workers": workers, "cores": os.cpu_count()}
    if part != "ray":
        t = time.perf_counter()
        write_dataset(out / "data_local", "train", clips, progress=False)
        r["dataset_local_s"] = time.perf_counter() - t
        t = time.perf_counter()
        run_batch(out / "scenarios.jsonl", out / "batch_local", "oracle", progress=False)
        r["batch_local_s"] = time.perf_counter() - t
        print(json.dumps(r), flush=True)  # the local half, in case Ray cannot start on a busy machine
    if part == "local":
        return r
    for d in ("data_ray", "batch_ray"):
        shutil.rmtree(out / d, ignore_errors=True)
    t = time.perf_counter()
    start_local(workers)
    r["ray_start_s"] = time.perf_counter() - t
    try:
        res = TaskResources(cpus=1, memory_gb=1.0)
        t = time.perf_counter()
        write_dataset_ray(out / "data_ray", "train", clips, progress=False, resources=res)
        r["dataset_ray_s"] = time.perf_counter() - t
        t = time.perf_counter()
        run_batch(out / "scenarios.jsonl", out / "batch_ray", "oracle", ray=True, progress=False, resources=res)
        r["batch_ray_s"] = time.perf_counter() - t
    finally:
        ray.shutdown()
    r["dataset_identical"] = _same(out / "data_local", out / "data_ray")
    r["batch_identical"] = _same(out / "batch_local", out / "batch_ray")
    r["shard_mb"] = sum(p.stat().st_size for p in (out / "data_local").rglob("*.npz")) / clips / 1e6
    for k in ("local", "ray") if part == "both" else ("ray",):
        r[f"dataset_{k}_clips_per_min"] = 60 * clips / r[f"dataset_{k}_s"]
        r[f"batch_{k}_scenes_per_min"] = 60 * scenes / r[f"batch_{k}_s"]
    r["load_average"] = os.getloadavg()
    return r


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", type=int, default=8)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, required=True, help="scratch folder (replaced)")
    p.add_argument("--part", choices=("both", "local", "ray"), default="both", help="ray: reuse OUT's local half")
    a = p.parse_args(argv)
    print(json.dumps(measure(a.out, a.clips, a.workers, a.part), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
