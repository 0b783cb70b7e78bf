"""`worldsplat train-accelerator --out OUT [--minutes 9] [--size large|smoke]`: world data on every CPU core, then
the whole model stack (VAE, cache, Gaussian decoder, DiT) on the GPU within the budget, the held-out evaluation of
the result, and its fp16 weights (OUT/weights.tar.NN), model card (OUT/MODEL_CARD.md, OUT/card.json), curves and
logs in at most 8 files (`worldsplat.training.accelerator`; web/docs/models.md "On an accelerator").
`--write-captions` (here, before the run): the caption table the lent machine reads instead of the sentence encoder.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, help="what comes back: weights, card, curves, logs ($OUT on the lent machine)")
    p.add_argument("--work", type=Path, default=Path("/tmp/worldsplat-accelerator"), help="data, checkpoints")
    p.add_argument("--captions", type=Path, default=Path(".whl/captions.pt"), help="the caption table")
    p.add_argument(
        "--write-captions", action="store_true", help="write the caption table (--train-clips, --test-clips)"
    )
    p.add_argument("--minutes", type=float, default=9.0, help="wall budget of the whole run")
    p.add_argument("--size", choices=("large", "smoke"), default="large")
    p.add_argument("--device", default=None, help="default: cuda when there is one, else cpu")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="dataset processes (one per core)")
    p.add_argument("--train-clips", type=int, default=None, help="at most this many (default: the caption table's)")
    p.add_argument("--test-clips", type=int, default=8)
    p.add_argument("--test-shifts", default="2,-2", help="shifted tracks of the test clips (reconstruct figures)")
    p.add_argument("--eval-clips", type=int, default=3)
    p.add_argument("--eval-frames", default="1")
    p.add_argument("--eval-parts", default="vae,reconstruct,generate", help="python -m worldsplat.evaluation.models")
    p.add_argument("--eval-only", type=Path, metavar="EVAL_JSON", help=argparse.SUPPRESS)  # the run's own subprocess


def evaluate(a: argparse.Namespace) -> int:
    """The held-out evaluation of OUT/weights on the run's test clips, the caption table serving the captions (the
    run starts it as a subprocess, so that its time is bounded)."""
    from worldsplat.evaluation import models as evaluation
    from worldsplat.training import accelerator as acc

    with acc.caption_table_installed(a.captions):
        return evaluation.main(
            ["--data", str(a.work / "data"), "--split", "test", "--weights", str(a.out / "weights"),
             "--out", str(a.eval_only), "--clips", str(a.eval_clips), "--parts", a.eval_parts,
             "--threads", str(a.workers), "--frames", a.eval_frames]
        )  # fmt: skip


def run(a: argparse.Namespace) -> int:
    import torch

    from worldsplat.training import accelerator as acc

    if a.eval_only is not None:
        return evaluate(a)
    if a.write_captions:
        print(acc.caption_table(a.captions, a.train_clips or 1200, a.test_clips, workers=a.workers))
        return 0
    if a.out is None:
        raise ValueError("train-accelerator: --out is required")
    if not a.captions.exists():
        raise FileNotFoundError(f"{a.captions}: no caption table (package-config/accelerator-wheels.sh writes it)")
    t0 = time.time()
    device = a.device or ("cuda" if torch.cuda.is_available() else "cpu")
    shifts = tuple(float(s) for s in a.test_shifts.split(",") if s.strip())
    plan = acc.Plan(
        out=a.out,
        work=a.work,
        captions=a.captions,
        minutes=a.minutes,
        size=a.size,
        device=device,
        workers=a.workers,
        train_clips=a.train_clips,
        test_clips=a.test_clips,
        test_shifts=shifts,
    )
    a.work.mkdir(parents=True, exist_ok=True)
    data_log = a.work / "workers.log"  # the dataset workers and the evaluation
    with acc.caption_table_installed(a.captions), open(data_log, "ab") as log:
        card = acc.train_all(plan, log)
        ev = a.work / "eval.json"
        cmd = [sys.executable, "-m", "worldsplat.cli", "train-accelerator", "--eval-only", str(ev), "--out", str(a.out)]
        cmd += ["--work", str(a.work), "--captions", str(a.captions), "--eval-clips", str(a.eval_clips)]
        cmd += ["--eval-frames", a.eval_frames, "--workers", str(a.workers)]
        t = time.time()
        card["eval_wall_s"] = {}
        # one part a process, each bounded by the time left (evaluation.models merges into EVAL_JSON), so the parts
        # that finished come back whatever the others do; the weights and training figures come back regardless
        for part in a.eval_parts.split(","):
            left = 60 * a.minutes - (time.time() - t0) - 15  # the card and the bundle after it
            tp = time.time()
            try:
                if left < 20:
                    raise TimeoutError(f"{left:.0f} s left")
                subprocess.run([*cmd, "--eval-parts", part], timeout=left, check=True, stdout=log, stderr=log)
            except (subprocess.SubprocessError, OSError) as e:
                card.setdefault("eval_errors", {})[part] = repr(e)
            card["eval_wall_s"][part] = round(time.time() - tp, 1)
        if ev.exists():
            card["eval"] = json.loads(ev.read_text())
        card["eval_wall_s"]["all"] = round(time.time() - t, 1)
    card["wall_s"] = round(time.time() - t0, 1)
    acc.write_card(a.out, card)
    parts = acc.bundle(a.out, a.work, [data_log])
    print(json.dumps({"wall_s": card["wall_s"], "weights": [p.name for p in parts]}), flush=True)
    return 0
