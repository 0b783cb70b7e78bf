"""`worldsplat eval nvs --split test --shifts 0,1,2,4 --out DIR [--count N] [--steps N]`: the novel-view ablation
(A-E, oracle, VAE ceiling) against exact ground truth on held-out seeds; writes nvs.json, nvs.md and nvs_psnr.png."""

from __future__ import annotations

import argparse
from pathlib import Path

from worldsplat.core.limits import MAX_SHIFT_M


def parse_shifts(text: str) -> tuple[float, ...]:
    try:
        shifts = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ValueError(f"--shifts: expected comma-separated metres such as 0,1,2,4, got {text!r}") from None
    if not shifts or any(not abs(s) <= MAX_SHIFT_M for s in shifts):
        raise ValueError(f"--shifts: need 1+ shifts within +-{MAX_SHIFT_M:g} m, got {text!r}")
    return shifts


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="what", metavar="WHAT", required=True)
    p = sub.add_parser("nvs", help="novel-view ablation A-E vs exact ground truth (web/docs/refinement.md)")
    p.add_argument("--split", default="test", choices=("val", "test"), help="held-out split (default test)")
    p.add_argument("--shifts", default="0,1,2,4", help="lateral shifts in metres, comma-separated")
    p.add_argument("--count", type=int, default=6, help="clips of the split (default 6)")
    p.add_argument("--steps", type=int, default=None, help="enhancer sampler steps (default: each model's own)")
    p.add_argument("--weights", type=Path, default=None, help="directory with enhancer_small[_nomix].safetensors")
    p.add_argument("--cache", type=Path, default=None, help="sample cache (default runs/enhancer_pairs)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    f = sub.add_parser("refine-figure", help="raw | refined | ground truth of a scenario at a shift (PNG)")
    f.add_argument("scenario", nargs="?", default="default", help="preset name or scenario JSON (default preset)")
    f.add_argument("--shift-m", type=float, default=4.0)
    f.add_argument("--cameras", default="CAM_FRONT,CAM_BACK,CAM_FRONT_RIGHT")
    f.add_argument("--steps", type=int, default=None, help="enhancer sampler steps (default: the model's own)")
    f.add_argument("--threads", type=int, default=1)
    f.add_argument("--weights", type=Path, default=None, help="enhancer weights file (default the shipped one)")
    f.add_argument("--out", type=Path, required=True, help="PNG path")


def run(args: argparse.Namespace) -> int:
    import torch

    if args.what == "refine-figure":
        return run_figure(args)

    from worldsplat.evaluation.nvs import evaluate, markdown_table

    if args.count < 1:
        raise ValueError("--count must be at least 1")
    if args.steps is not None and not 1 <= args.steps <= 64:
        raise ValueError("--steps must be in 1..64")
    torch.set_num_threads(args.threads)
    result = evaluate(args.split, parse_shifts(args.shifts), args.count, args.steps, args.weights, args.cache, args.out)
    print(markdown_table(result))
    print(f"wrote {args.out / 'nvs.md'}, {args.out / 'nvs.json'}, {args.out / 'nvs_psnr.png'}")
    return 0


def run_figure(args: argparse.Namespace) -> int:
    import json

    import torch
    from PIL import Image

    from worldsplat.core.scenario import resolve_scenario
    from worldsplat.evaluation.nvs import side_by_side

    torch.set_num_threads(args.threads)
    img, stats = side_by_side(
        resolve_scenario(args.scenario),
        args.shift_m,
        tuple(args.cameras.split(",")),
        steps=args.steps,
        weights=args.weights,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(args.out)
    print(json.dumps(stats, indent=1, default=float))
    print(f"wrote {args.out}")
    return 0
