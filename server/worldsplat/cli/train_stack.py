"""`worldsplat train-stack --run-dir RUN [--size tiny|small|large] [--until STAGE]`: the served stack (VAE, decoder,
layout prior, DiT, enhancer, pixel mix) trained by one recipe on the CPU or a GPU (auto-detected), resumable from
RUN (keep it outside the work tree); weights in RUN/weights, cards in RUN/cards and RUN/MODEL_CARD.md
(`worldsplat.training.recipe`; web/docs/training.md). `--write-captions TABLE` writes the caption table that a
machine without the sentence encoder reads (`--captions TABLE`).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path


def configure(p: argparse.ArgumentParser) -> None:
    from worldsplat.training.recipe import SIZES, STAGES  # noqa: PLC0415 - torch only when the command runs

    p.add_argument("--run-dir", type=Path, help="checkpoints, state, weights and cards (outside the work tree)")
    p.add_argument("--size", choices=tuple(SIZES), default="small")
    p.add_argument("--device", default=None, help="default: cuda when there is one, else cpu")
    p.add_argument("--data", type=Path, default=None, help="world shards (default RUN/data)")
    p.add_argument("--until", choices=STAGES, default="mix", help="stop after this stage (in training order)")
    p.add_argument("--threads", type=int, default=min(2, os.cpu_count() or 1), help="torch threads")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="dataset processes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lr", action="append", default=[], metavar="STAGE=LR", help="force a stage's lr (no sweep)")
    p.add_argument("--minutes", type=float, default=None, help="wall budget of the run (the stages share it)")
    p.add_argument("--k", type=float, default=3.0, help="diverged: held-out figure above k x its best")
    p.add_argument("--captions", type=Path, default=None, help="caption table (where no sentence encoder is)")
    p.add_argument("--write-captions", type=Path, metavar="TABLE", help="write the caption table of the size's clips")


def run(a: argparse.Namespace) -> int:
    from worldsplat.training import recipe  # noqa: PLC0415
    from worldsplat.training.device_data import caption_table  # noqa: PLC0415
    from worldsplat.training.stage_runner import StageStopped  # noqa: PLC0415

    size = recipe.SIZES[a.size]
    if a.write_captions is not None:
        print(caption_table(a.write_captions, size.clips, size.test_clips, size.pair_clips, size.val_clips, a.workers))
        return 0
    if a.run_dir is None:
        raise ValueError("train-stack: --run-dir is required")
    lrs = {k: float(v) for k, v in (s.split("=", 1) for s in a.lr)}
    plan = recipe.Plan(
        a.run_dir,
        a.size,
        a.device,
        a.data,
        a.seed,
        a.threads,
        a.workers,
        a.captions,
        a.until,
        lrs,
        k=a.k,
        minutes=a.minutes,
    )
    try:
        card = recipe.train_stack(plan)
    except StageStopped as e:
        print(json.dumps({"stopped": str(e)}))
        return 3
    print(json.dumps({"wall_s": card["wall_s"], "weights": card["weights"], "card": str(a.run_dir / "MODEL_CARD.md")}))
    return 0
