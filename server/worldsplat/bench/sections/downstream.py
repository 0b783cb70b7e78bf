"""Downstream value of the served scenes: the judge (a segmentation model of the world's classes trained on world
images only) on renders of each mode's scene against the world's exact labels, the world's own images as the
reference row (paper Table a1, web/docs/downstream.md).

Knob: the served mode. The cost is the seconds to make and render a clip's scene; the error axis is the judge's mIoU
on its renders (all tracks), beside the judge Fréchet distance to the world's images.
"""

from __future__ import annotations

from worldsplat.bench.report import Pareto, Section
from worldsplat.core.paths import runs_dir
from worldsplat.evaluation.downstream import GROUND_TRUTH, domain_gap
from worldsplat.pipeline.scene import available_modes
from worldsplat_models.judge import load_judge
from worldsplat_models.weights import weights_dir


def run(quick: bool) -> Section:
    judge = load_judge(weights_dir() / "judge_small.safetensors")
    have = available_modes()
    if quick:  # one frame of one clip, the three front cameras, the rig's track: seconds
        modes = tuple(m for m in ("oracle", "generate") if m in have)
        kw = dict(count=1, shifts=(0.0,), cameras=["CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"], clip_frames=1)
    else:
        modes = tuple(m for m in ("oracle", "reconstruct", "generate") if m in have)
        kw = dict(count=2, shifts=(0.0, 2.0, -2.0, 4.0, -4.0), frames=[1, 3], cache=runs_dir() / "judge_renders")
    r = domain_gap(judge, "test", modes=modes, progress=False, **kw)
    shifts = [str(s) for s in r["shifts"]]
    gt = r["table"][GROUND_TRUTH]["all"]["miou"]
    rows, points = [], []
    for row in (GROUND_TRUTH, *modes):
        t = r["table"][row]
        secs = (r["timing_s"][row]["scene_s"] + r["timing_s"][row]["render_s"]) / len(r["clips"]) if row in modes else 0
        fd = r["frechet"][row]["all"] if row in modes else 0.0
        rows.append([row, *(t[s]["miou"] for s in shifts), t["all"]["miou"], t["all"]["miou"] / gt, fd, secs])
        if row in modes:
            points.append((row, secs, t["all"]["miou"]))
    f = r["frechet_floor_world_halves"]
    floor = "too few images" if f is None else f"{f:.2f}"
    default = "generate" if "generate" in modes else modes[0]
    return Section(
        key="downstream",
        title="Downstream: the judge's mIoU on served scenes",
        columns=[
            "judged images",
            *(f"mIoU {s} m" for s in shifts),
            "mIoU all",
            "/ ground truth",
            "judge FD",
            "s / clip",
        ],
        rows=rows,
        default=default,
        why=f"{len(r['clips'])} held-out clip(s), {r['images_per_shift']} images per track. generate is the "
        "playground's default (a scene from the scenario alone); the oracle row renders the lifting of exact colour "
        "and depth, the ground-truth row is the judge on the world's own images (the reference).",
        pareto=Pareto("seconds per clip (scene + renders)", "judge mIoU vs exact labels", points, default=default),
        notes=[f"judge Fréchet distance floor (world images, two random halves): {floor}"],
        data={"miou": {row[0]: row[len(shifts) + 1] for row in rows}, "frechet": r["frechet"]},
    )
