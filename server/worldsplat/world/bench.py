"""Renderer benchmark: `python -m worldsplat.world.bench [--preset NAME] [--repeat N]`.

Times `simulate` for 6 cameras x 8 frames at 200x112 (the target: <= 3 s on 2 cores) and prints seconds,
rays per second and the ratio to the 3 s budget. Also times `build_world` and `world.conditions`.
"""

from __future__ import annotations

import argparse
import os
import time

from worldsplat.core.scenario import list_presets, load_preset
from worldsplat.world import build_world, simulate

BUDGET_S = 3.0


def bench(preset: str, repeat: int, width: int, height: int, frames: int) -> dict:
    sc = load_preset(preset).with_updates(image={"width": width, "height": height}, clip={"frames": frames})
    t0 = time.perf_counter()
    world = build_world(sc)
    t_build = time.perf_counter() - t0
    sims = []
    cpus = []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        clip = simulate(world)
        sims.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    t0 = time.perf_counter()
    world.conditions()
    t_cond = time.perf_counter() - t0
    rays = clip.depth.size
    best = min(sims)
    return {
        "preset": preset,
        "build_s": t_build,
        "simulate_s": best,
        "rays": rays,
        "rays_per_s": rays / best,
        "conditions_s": t_cond,
        "budget_ratio": best / BUDGET_S,
        "cpu_s": min(cpus),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="all", help="preset name or 'all'")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--width", type=int, default=200)
    ap.add_argument("--height", type=int, default=112)
    ap.add_argument("--frames", type=int, default=8)
    a = ap.parse_args()
    names = [p["name"] for p in list_presets()] if a.preset == "all" else [a.preset]
    print(f"load average {os.getloadavg()[0]:.1f} (other processes share the cores; 'cpu s' is this process)")
    print(
        f"simulate: 6 cameras x {a.frames} frames at {a.width}x{a.height}, best of {a.repeat}; "
        f"cpu count {os.cpu_count()}, budget {BUDGET_S} s"
    )
    print(
        f"{'preset':<22} {'build s':>8} {'simulate s':>11} {'cpu s':>6} {'Mrays/s':>8} {'x budget':>9} "
        f"{'conditions s':>13}"
    )
    for n in names:
        r = bench(n, a.repeat, a.width, a.height, a.frames)
        print(
            f"{n:<22} {r['build_s']:>8.3f} {r['simulate_s']:>11.3f} {r['cpu_s']:>6.2f} {r['rays_per_s'] / 1e6:>8.3f} "
            f"{r['budget_ratio']:>9.2f} {r['conditions_s']:>13.3f}"
        )


if __name__ == "__main__":
    main()
