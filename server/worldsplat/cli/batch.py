"""`worldsplat batch SCENARIOS.jsonl --mode generate|oracle --out DIR [--steps N] [--ray [auto|local|ADDRESS]]`:
one scene per line, resumable, on this machine or as Ray tasks (web/docs/scale-out.md)."""

from __future__ import annotations

import argparse
import time

from worldsplat.scale.ray_runner import TaskFailures, add_ray_arguments, ray_session, resources_from_args


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenarios", help="a .jsonl file: one scenario (object, preset document or preset name) per line")
    p.add_argument("--mode", required=True, choices=["oracle", "reconstruct", "generate"])
    p.add_argument("--steps", type=int, default=8, help="sampler steps (generate mode)")
    p.add_argument("--out", required=True, help="output folder (run.json, scenes/*.wsplat, manifest.json)")
    p.add_argument("--no-progress", action="store_true")
    add_ray_arguments(p)


def run(args: argparse.Namespace) -> int:
    from worldsplat.scale.batch import run_batch

    if args.steps < 1:
        raise ValueError("--steps must be at least 1")
    resources = resources_from_args(args)
    kw = dict(mode=args.mode, steps=args.steps, resources=resources, progress=not args.no_progress)
    t0 = time.perf_counter()
    try:
        if args.ray is None:
            res = run_batch(args.scenarios, args.out, **kw)
        else:
            with ray_session(args.ray):
                res = run_batch(args.scenarios, args.out, ray=True, **kw)
    except TaskFailures as e:
        print(f"worldsplat batch: {e} (finished scenes are kept; run the same command again to do the rest)")
        return 1
    dt = time.perf_counter() - t0
    rate = f", {60 * res['written'] / dt:.1f} scenes/min" if res["written"] else ""
    print(f"wrote {res['written']} scene(s), skipped {res['skipped']} complete in {dt:.1f} s{rate}; {res['manifest']}")
    return 0
