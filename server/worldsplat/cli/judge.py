"""`worldsplat judge train|heldout|eval`: the downstream judge, a small segmentation model of the world's classes
trained on world ground truth (web/docs/downstream.md).

    worldsplat judge train --data DATA --out DIR [--steps N] [--minutes M]     weights + held-out figures + card
    worldsplat judge heldout --data DATA [--weights W] --out DIR               mIoU on DATA/test (world images)
    worldsplat judge eval --count N --shifts 0,2,-2,4,-4 --out DIR             domain gap per mode and shift,
                                                                               judge Fréchet distances, BEV IoU,
                                                                               vehicle box AP
    worldsplat judge train-bev --data DATA --out DIR                           the BEV head
    worldsplat judge ablation --count N --shifts 2,-2 --out DIR                novel-view versions A-E ranked
    worldsplat judge augment --world DATA --batch DIR --out DIR                world vs world+generated clips
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from worldsplat.cli.eval import parse_shifts


def _weights_default() -> Path:
    from worldsplat_models.weights import weights_dir

    return weights_dir() / "judge_small.safetensors"


def _bev_head(path: Path | None):
    from worldsplat_models.judge_bev import load_bev
    from worldsplat_models.weights import weights_dir

    path = path or weights_dir() / "judge_bev_small.safetensors"
    return load_bev(path) if path.exists() else None


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="what", metavar="WHAT", required=True)
    t = sub.add_parser("train", help="train the judge on DATA/train (shards of `worldsplat dataset`)")
    t.add_argument("--data", type=Path, required=True, help="dataset folder with train/ (and test/ for the figures)")
    t.add_argument("--out", type=Path, required=True, help="checkpoints, log, judge_small.safetensors, heldout.json")
    t.add_argument("--steps", type=int, default=1200, help="optimizer steps (default 1200)")
    t.add_argument("--batch", type=int, default=12, help="images per step (default 12)")
    t.add_argument("--width", type=int, default=24, help="channels of the first level (default 24)")
    t.add_argument("--lr", type=float, default=3e-3, help="peak learning rate (default 3e-3)")
    t.add_argument("--minutes", type=float, default=None, help="stop (with a checkpoint) after this wall time")
    t.add_argument("--clips", type=int, default=None, help="use the first N training clips (default all)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    t.add_argument(
        "--degrade", action="store_true", help="also blur, colour-cast and add noise to training images (a 2nd judge)"
    )
    b = sub.add_parser("train-bev", help="train the BEV head (drivable area, vehicles) through the frozen judge")
    b.add_argument("--data", type=Path, required=True, help="dataset folder with train/ (and test/ for the figures)")
    b.add_argument("--out", type=Path, required=True, help="checkpoints, log, judge_bev_small.safetensors, figures")
    b.add_argument("--steps", type=int, default=400, help="optimizer steps (default 400)")
    b.add_argument("--batch", type=int, default=4, help="frames (six cameras each) per step (default 4)")
    b.add_argument("--minutes", type=float, default=None, help="stop (with a checkpoint) after this wall time")
    b.add_argument("--weights", type=Path, default=None, help="judge weights (default the shipped ones)")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    g = sub.add_parser("scenarios", help="the scenario list of the generated clips (for `worldsplat batch`)")
    g.add_argument("--split", default="train", choices=("train", "val", "test"))
    g.add_argument("--start", type=int, default=300, help="first clip index (default 300: after the world clips)")
    g.add_argument("--count", type=int, default=260, help="clips (default 260)")
    g.add_argument("--frames", type=int, default=2, help="frames per clip (default 2)")
    g.add_argument("--out", type=Path, required=True, help="the .jsonl to write")
    u = sub.add_parser("augment", help="the judge trained on world, world + generated and generated clips, over seeds")
    u.add_argument("--world", type=Path, required=True, help="dataset folder with train/ and test/ (world clips)")
    u.add_argument(
        "--batch", type=Path, nargs="+", required=True, help="`worldsplat batch` folder(s) of generated scenes"
    )
    u.add_argument("--out", type=Path, required=True, help="runs, augment.json, augment.md")
    u.add_argument("--n", type=int, default=20, help="world clips (default 20)")
    u.add_argument("--m", type=int, default=200, help="generated clips (default 200)")
    u.add_argument("--seeds", default="0,1,2", help="training seeds, comma-separated (default 0,1,2)")
    u.add_argument("--arms", default="world,world+generated,generated", help="training sets, comma-separated")
    u.add_argument("--steps", type=int, default=300, help="optimizer steps of every run (default 300)")
    u.add_argument("--width", type=int, default=16, help="judge width of every run (default 16)")
    u.add_argument("--threads", type=int, default=1)
    h = sub.add_parser("heldout", help="the judge's mIoU on held-out world clips (DATA/test)")
    h.add_argument("--data", type=Path, required=True, help="dataset folder with test/")
    h.add_argument("--split", default="test", choices=("val", "test"))
    h.add_argument("--weights", type=Path, default=None, help="judge weights (default the shipped ones)")
    h.add_argument("--threads", type=int, default=2)
    h.add_argument("--out", type=Path, required=True, help="output directory (heldout.json, heldout.md)")
    e = sub.add_parser("eval", help="domain gap: the judge on renders of served scenes vs the world's exact labels")
    e.add_argument("--split", default="test", choices=("val", "test"), help="held-out split of the clips")
    e.add_argument("--count", type=int, default=2, help="clips of the split (default 2)")
    e.add_argument("--start", type=int, default=0, help="first clip index (default 0)")
    e.add_argument("--shifts", default="0,2,-2,4,-4", help="lateral shifts in metres, comma-separated")
    e.add_argument("--modes", default="oracle,reconstruct,generate", help="served modes, comma-separated")
    e.add_argument("--frames", default="", help="frames judged, comma-separated (default all)")
    e.add_argument("--steps", type=int, default=8, help="generate mode's sampler steps (default 8)")
    e.add_argument("--cameras", default="", help="cameras judged, comma-separated names (default all six)")
    e.add_argument("--clip-frames", type=int, default=4, help="frames of each clip's scenario (default 4)")
    e.add_argument("--cache", type=Path, default=None, help="keep each clip's images here (default runs/judge_renders)")
    e.add_argument("--weights", type=Path, default=None, help="judge weights (default the shipped ones)")
    e.add_argument(
        "--refine", default="", help="also each mode refined on the track with these blends, e.g. none,holes,mix"
    )
    e.add_argument("--bev", type=Path, default=None, help="BEV head weights (default the shipped ones, when present)")
    e.add_argument(
        "--no-bev", action="store_true", help="no BEV or box scores (a judge the BEV head was not trained through)"
    )
    e.add_argument(
        "--reuse-renders",
        action="store_true",
        help="judge each clip's one image file in --cache even if made by other served models (an earlier run)",
    )
    e.add_argument(
        "--blur",
        default="",
        help="also the world's images blurred by a Gaussian of these sigmas (px of the judged image), e.g. 0.55,0.89: "
        "the judge's reading of exact content seen through a splat render's blur",
    )
    e.add_argument("--threads", type=int, default=2)
    e.add_argument("--out", type=Path, required=True, help="output directory (downstream.json/.md/.png)")
    a = sub.add_parser("ablation", help="the novel-view ablation versions A-E: judge Fréchet distances and mIoU")
    a.add_argument("--split", default="test", choices=("val", "test"), help="held-out split of the clips")
    a.add_argument("--count", type=int, default=8, help="clips of the split (default 8)")
    a.add_argument("--shifts", default="2,-2", help="lateral shifts in metres, comma-separated (default the paper's)")
    a.add_argument("--steps", type=int, default=None, help="enhancer sampler steps (default each model's own)")
    a.add_argument("--cache", type=Path, default=None, help="samples (default runs/judge/ablation_samples)")
    a.add_argument("--weights", type=Path, default=None, help="judge weights (default the shipped ones)")
    a.add_argument("--threads", type=int, default=2)
    a.add_argument("--out", type=Path, required=True, help="output directory (ablation.json, ablation.md)")


def run(args: argparse.Namespace) -> int:
    import torch

    torch.set_num_threads(getattr(args, "threads", 1))
    if args.what == "train":
        return run_train(args)
    if args.what == "train-bev":
        return run_train_bev(args)
    if args.what in ("scenarios", "augment"):
        return run_augment(args)
    from worldsplat.core.paths import runs_dir
    from worldsplat.evaluation import downstream
    from worldsplat_models.judge import load_judge

    judge = load_judge(args.weights or _weights_default())
    if args.what == "ablation":
        from worldsplat.evaluation import downstream_ablation

        if args.count < 1:
            raise ValueError("--count must be at least 1")
        res = downstream_ablation.judge_ablation(
            judge, args.split, args.count, parse_shifts(args.shifts), steps=args.steps, cache=args.cache
        )
        downstream_ablation.write_ablation(res, args.out)
        print(downstream_ablation.ablation_markdown(res))
        return 0
    if args.what == "heldout":
        result = downstream.heldout(judge, args.data, args.split)
        downstream.write_heldout(result, args.out)
        print(downstream.heldout_markdown(result))
        return 0
    modes = tuple(m for m in args.modes.split(",") if m)
    frames = [int(f) for f in args.frames.split(",") if f.strip()] or None
    cameras = [c for c in args.cameras.split(",") if c.strip()] or None
    if args.count < 1:
        raise ValueError("--count must be at least 1")
    result = downstream.domain_gap(
        judge,
        args.split,
        args.count,
        parse_shifts(args.shifts),
        modes,
        frames=frames,
        cameras=cameras,
        steps=args.steps,
        start=args.start,
        clip_frames=args.clip_frames,
        cache=args.cache or runs_dir() / "judge_renders",
        blends=tuple(b for b in args.refine.split(",") if b.strip()),
        bev_head=None if args.no_bev else _bev_head(args.bev),
        reuse_renders=args.reuse_renders,
        blurs=_blurs(args.blur),
    )
    downstream.write_domain_gap(result, args.out)
    print(downstream.domain_gap_markdown(result))
    return 0


def _blurs(text: str) -> tuple[float, ...]:
    """`--blur`: sigmas in px, each a finite number > 0."""
    out = []
    for x in (t.strip() for t in text.split(",")):
        if not x:
            continue
        try:
            v = float(x)
        except ValueError:
            raise ValueError(f"--blur: {x!r} is not a number (sigmas in px, comma-separated)") from None
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"--blur: a sigma must be a finite number > 0 px, got {x}")
        out.append(v)
    return tuple(out)


def run_train(args: argparse.Namespace) -> int:
    from worldsplat.training.judge import train_judge
    from worldsplat_models.judge import load_judge

    if args.steps < 1 or args.batch < 1:
        raise ValueError("--steps and --batch must be at least 1")
    path = train_judge(
        args.data,
        args.out,
        steps=args.steps,
        batch=args.batch,
        width=args.width,
        lr=args.lr,
        minutes=args.minutes,
        seed=args.seed,
        threads=args.threads,
        clips=args.clips,
        degraded=args.degrade,
    )
    print(f"wrote {path}")
    if (Path(args.data) / "test").is_dir():
        from worldsplat.evaluation import downstream

        result = downstream.heldout(load_judge(path), args.data, "test")
        downstream.write_heldout(result, args.out)
        print(downstream.heldout_markdown(result))
        print(json.dumps({"miou": result["miou"], "groups": result["groups"]}))
    return 0


def run_train_bev(args: argparse.Namespace) -> int:
    from worldsplat.evaluation import downstream
    from worldsplat.training.judge_bev import train_bev
    from worldsplat_models.judge import load_judge
    from worldsplat_models.judge_bev import load_bev

    judge = load_judge(args.weights or _weights_default())
    path = train_bev(
        judge, args.data, args.out, args.steps, args.batch, seed=args.seed, threads=args.threads, minutes=args.minutes
    )
    print(f"wrote {path}")
    if (Path(args.data) / "test").is_dir():
        result = downstream.heldout_bev(judge, load_bev(path), args.data, "test")
        (Path(args.out) / "heldout_bev.json").write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps({k: result.get(k) for k in ("samples", "bev_miou", "bev_iou", "box_map", "box_ap")}))
    return 0


def run_augment(args: argparse.Namespace) -> int:
    from worldsplat.evaluation import downstream_augment as aug

    if args.what == "scenarios":
        print(f"wrote {aug.write_scenarios(args.out, args.split, args.start, args.count, args.frames)}")
        return 0
    seeds = tuple(int(x) for x in args.seeds.split(",") if x.strip())
    arms = tuple(a for a in args.arms.split(",") if a.strip())
    unknown = set(arms) - set(aug.ARMS)
    if unknown or not seeds:
        raise ValueError(f"--arms must be among {', '.join(aug.ARMS)} and --seeds not empty")
    generated = args.out / "generated"
    if arms != ("world",):  # the world arm alone needs no generated clips
        shards = aug.generated_shards(args.batch, generated)
        if len(shards) < args.m:
            raise ValueError(f"{args.batch} has {len(shards)} scenes, fewer than --m {args.m}")
    r = aug.augmentation(
        args.world, generated, args.out, args.n, args.m, seeds, arms, args.steps, width=args.width, threads=args.threads
    )
    (args.out / "augment.json").write_text(json.dumps(r, indent=1) + "\n")
    (args.out / "augment.md").write_text(aug.augmentation_markdown(r) + "\n")
    aug.plot_augmentation(r, args.out / "augment.png")
    print(aug.augmentation_markdown(r))
    return 0
