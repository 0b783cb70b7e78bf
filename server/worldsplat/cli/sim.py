"""`worldsplat sim SCENARIO.json|PRESET --out DIR [--shift-m M]`: write a scenario's exact ground truth."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="a scenario JSON file or a preset name (see `worldsplat presets`)")
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--shift-m", type=float, default=0.0, help="lateral shift of the ego track, metres, left positive")
    p.add_argument("--cameras", default=None, help="comma-separated camera names (default: the scenario's rig)")
    p.add_argument("--no-conditions", action="store_true", help="skip BEV, sketches and boxes")
    p.add_argument("--width", type=int, help="override the scenario's image width")
    p.add_argument("--height", type=int, help="override the scenario's image height")
    p.add_argument("--frames", type=int, help="override the scenario's number of frames")


def run(args: argparse.Namespace) -> int:
    from worldsplat.core.scenario import resolve_scenario
    from worldsplat.world import build_world, simulate
    from worldsplat.world.io import write_sim

    scenario = resolve_scenario(args.scenario)
    image = {k: v for k, v in (("width", args.width), ("height", args.height)) if v is not None}
    if image or args.frames is not None:
        scenario = scenario.with_updates(image=image, clip={"frames": args.frames} if args.frames else {})
    cameras = args.cameras.split(",") if args.cameras else None
    t0 = time.perf_counter()
    world = build_world(scenario)
    clip = simulate(world, shift_m=args.shift_m, cameras=cameras)
    cond = None if args.no_conditions else world.conditions(args.shift_m, cameras)
    write_sim(args.out, world, clip, cond)
    T, V, H, W = clip.depth.shape
    print(f"wrote {T} frames x {V} cameras at {W}x{H} to {args.out} in {time.perf_counter() - t0:.2f} s")
    print(clip.caption)
    return 0
