"""`worldsplat dataset --count N --split train|val|test --out DIR [--ray [auto|local|ADDRESS]]`: sharded,
resumable world dataset, on this machine or as Ray tasks (the same shards either way; web/docs/scale-out.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from worldsplat.scale.ray_runner import TaskFailures, add_ray_arguments, ray_session, resources_from_args


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--count", type=int, required=True, help="number of clips")
    p.add_argument("--split", choices=("train", "val", "test"), required=True)
    p.add_argument("--out", type=Path, required=True, help="dataset root (shards go to OUT/SPLIT/)")
    p.add_argument("--start", type=int, default=0, help="first clip index (seed = split base + index)")
    p.add_argument("--width", type=int, default=112)
    p.add_argument("--height", type=int, default=64)
    p.add_argument("--frames", type=int, default=4)
    p.add_argument("--fps", type=float, default=4.0)
    p.add_argument("--preset-mix", action="store_true", help="vary the shipped presets instead of fully random")
    p.add_argument(
        "--explicit-agents",
        type=float,
        metavar="P",
        help="fraction of clips that also get 1-3 explicit (scenario v2) agents (default 0.5: "
        "worldsplat.world.dataset.EXPLICIT_AGENTS; 0: none, as datasets written before)",
    )
    p.add_argument("--shifts", default="", help="comma-separated lateral shifts (m) to also render, e.g. 1,2,-2")
    p.add_argument("--no-progress", action="store_true")
    add_ray_arguments(p)


def run(args: argparse.Namespace) -> int:
    from worldsplat.world.dataset import write_dataset

    if args.count < 1:
        raise ValueError("--count must be at least 1")
    shifts = tuple(float(s) for s in args.shifts.split(",") if s.strip())
    kw = dict(
        width=args.width,
        height=args.height,
        frames=args.frames,
        fps=args.fps,
        preset_mix=args.preset_mix,
        shifts=shifts,
        start=args.start,
        progress=not args.no_progress,
    )
    if args.explicit_agents is not None:
        if not 0.0 <= args.explicit_agents <= 1.0:
            raise ValueError("--explicit-agents must be a probability in [0, 1]")
        kw["explicit_agents"] = args.explicit_agents
    if args.ray is None:
        res = write_dataset(args.out, args.split, args.count, **kw)
    else:
        from worldsplat.scale.dataset import write_dataset_ray

        resources = resources_from_args(args)
        try:
            with ray_session(args.ray):
                res = write_dataset_ray(args.out, args.split, args.count, resources=resources, **kw)
        except TaskFailures as e:
            print(f"worldsplat dataset: {e} (finished shards are kept; run the same command again to do the rest)")
            return 1
    print(f"{args.split}: wrote {res['written']} clip(s), skipped {res['skipped']} complete; {res['manifest']}")
    return 0
