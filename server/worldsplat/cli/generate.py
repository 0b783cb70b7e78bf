"""`worldsplat generate SCENARIO.json|PRESET --mode oracle|reconstruct|generate [--steps N] --out SCENE.wsplat`."""

from __future__ import annotations

import argparse
import sys
import time


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="a scenario JSON file or a preset name (see `worldsplat presets`)")
    p.add_argument(
        "--mode",
        default=None,
        choices=["oracle", "reconstruct", "generate"],
        help="default: the playground's default (generate when its weights ship, else oracle)",
    )
    p.add_argument(
        "--steps", type=int, default=8, help="sampler steps (generate mode; the one-frame first window takes min(N, 4))"
    )
    p.add_argument("--seed", type=int, default=None, help="sampling seed (generate mode; default: scenario seed)")
    p.add_argument("--out", required=True, help="output .wsplat")
    p.add_argument("--quiet", action="store_true")


def run(args) -> int:
    from worldsplat.core.scenario import resolve_scenario
    from worldsplat.gaussians import wsplat
    from worldsplat.pipeline.scene import default_mode, generate_scene

    if not args.out.endswith(".wsplat"):
        raise ValueError(f"--out must end with .wsplat, got {args.out}")
    scenario = resolve_scenario(args.scenario)
    args.mode = args.mode or default_mode()
    t0 = time.time()
    last = [None]

    def progress(stage: str, frac: float) -> None:
        if not args.quiet and stage != last[0]:
            print(f"[{time.time() - t0:6.1f}s] {stage}", file=sys.stderr, flush=True)
            last[0] = stage

    scene = generate_scene(scenario, mode=args.mode, steps=args.steps, seed=args.seed, progress=progress)
    n = wsplat.write(scene, args.out)
    st = scene.meta.get("aggregate", {})
    dyn = sum(len(d) for d in scene.dynamic)
    print(
        f"wrote {args.out}: {len(scene.static)} static + {dyn} dynamic Gaussians over {scene.num_frames} frames, "
        f"{n} bytes ({n / max(1, len(scene.static) + dyn):.2f} B/Gaussian), mode {args.mode}"
        + (f", {100 * st['kept_fraction_of_naive']:.1f}% of naive V*T*H*W" if st.get("naive") else "")
    )
    return 0
