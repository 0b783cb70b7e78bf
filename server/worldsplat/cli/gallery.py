"""`worldsplat gallery [--weights DIR] [--data DATA --split test --random 4] [--presets a,b,c,d] [--frame 1]
[--steps 8] [--out web/docs/img/gallery]`: GT | VAE decode | reconstruct | layout map | generate at the three front
cameras, one PNG per preset and random held-out scenario plus overview.png (worldsplat.evaluation.gallery)."""

from __future__ import annotations

import argparse
from pathlib import Path

from worldsplat.core import paths


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--weights", type=Path, default=None, help="weights folder (default: the shipped ones)")
    p.add_argument("--data", type=Path, default=None, help="dataset root with SPLIT/clip_*.npz (default: made here)")
    p.add_argument("--split", default="test", choices=("train", "val", "test"), help="split of the random cases")
    p.add_argument("--random", type=int, default=4, help="random scenarios of the split (default 4)")
    p.add_argument("--seed", type=int, default=0, help="which random scenarios (default 0)")
    p.add_argument(
        "--presets",
        default="urban_straight,highway,cut_in,crossing_pedestrian",
        help="comma-separated preset names or scenario files ('' for none)",
    )
    p.add_argument("--frame", type=int, default=1, help="frame shown (default 1)")
    p.add_argument("--steps", type=int, default=8, help="sampler steps of generate (default 8, as served)")
    p.add_argument("--scale", type=int, default=2, help="pixel scale of the per-case PNGs (default 2)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default web/docs/img/gallery)")


def run(args: argparse.Namespace) -> int:
    import torch  # noqa: PLC0415 - torch, only for the commands that run the models

    from worldsplat.evaluation.gallery import default_cases, write_gallery  # noqa: PLC0415 - imports torch
    from worldsplat.pipeline.inference import load_models  # noqa: PLC0415 - imports torch

    if args.random < 0:
        raise ValueError("--random must be >= 0")
    if not 1 <= args.steps <= 256:
        raise ValueError("--steps must be in 1..256")
    if not 1 <= args.scale <= 8:
        raise ValueError("--scale must be in 1..8")
    presets = [x.strip() for x in args.presets.split(",") if x.strip()]
    if not presets and not args.random:
        raise ValueError("nothing to show: give --presets or --random N")
    torch.set_num_threads(args.threads)
    models = load_models(args.weights)
    if not models.modes:
        raise FileNotFoundError(f"no VAE + decoder weights in {models.weights_dir}")
    out = args.out if args.out is not None else paths.docs_dir() / "img" / "gallery"
    cases = default_cases(models, presets, args.random, args.split, args.data, args.seed)
    write_gallery(models, cases, out, t=args.frame, steps=args.steps, scale=args.scale)
    return 0
