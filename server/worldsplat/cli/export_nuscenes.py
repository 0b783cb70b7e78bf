"""`worldsplat export-nuscenes DIR --out NUSC_ROOT [--version v1.0-mini-like] [--images render|gt] [--shifts 2,-2]`:
scenes (.wsplat, e.g. a `worldsplat batch` folder) or dataset shards in the nuScenes layout (web/docs/scale-out.md)."""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("src", type=Path, help="a folder of .wsplat scenes or clip_*.npz dataset shards (or one file)")
    p.add_argument("--out", type=Path, required=True, help="the nuScenes dataroot to write")
    p.add_argument("--version", default="v1.0-mini-like", help="table folder name (NuScenes(version=...))")
    p.add_argument(
        "--images",
        choices=["auto", "render", "gt"],
        default="auto",
        help="scenes: their rendered track (render, the default) or the world's exact ground truth (gt); shards: gt",
    )
    p.add_argument("--shifts", default="", help="comma-separated lateral shifts (m): extra logs of shifted tracks")
    p.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    from worldsplat.scale.nuscenes import export_nuscenes

    shifts = tuple(float(s) for s in args.shifts.split(",") if s.strip())
    res = export_nuscenes(
        args.src, args.out, version=args.version, images=args.images, shifts=shifts, progress=not args.no_progress
    )
    print(
        f"wrote {res['scenes']} scene(s), {res['samples']} samples, {res['images']} images, "
        f"{res['annotations']} annotations; tables in {res['tables']}"
    )
    return 0
