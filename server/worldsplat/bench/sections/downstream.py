"""Downstream value of the served scenes: the judge (a segmentation model of the world's classes trained on world
images only) and its BEV head on renders of each mode's scene, raw and refined on the track with each blend, against
the world's exact labels, the world's own images as the reference row (paper Table a1, web/docs/downstream.md).

Knob: the served mode (and the refinement blend). The cost is the seconds to make, render and refine a clip's scene;
the error axis is the judge's mIoU on its renders (all tracks), beside the judge Fréchet distance to the world's
images and the BEV head's mean IoU (drivable area, vehicles).
"""

from __future__ import annotations

from worldsplat.bench.report import Pareto, Section
from worldsplat.core.paths import runs_dir
from worldsplat.evaluation.downstream import GROUND_TRUTH, domain_gap, gap_by_group, refined_row
from worldsplat.pipeline.refine import refine_available
from worldsplat.pipeline.scene import available_modes
from worldsplat_models.judge import load_judge
from worldsplat_models.judge_bev import load_bev
from worldsplat_models.weights import weights_dir

BLENDS = ("none", "holes", "mix")
# the world's own images blurred as a splat render draws: the dilation alone, a lifted pixel at its own camera (px)
BLURS = (0.55, 0.89)


def _seconds(r: dict, row: str) -> float:
    """Seconds per clip of a row: its mode's scene and renders, plus the refinement for a refined row."""
    mode = next((m for m in r["modes"] if row == m or row.startswith(f"{m} refined ")), None)
    if mode is None:
        return 0.0
    t = r["timing_s"][mode]
    refine = t.get("refine_s", 0.0) / max(1, len(r["blends"])) if row != mode else 0.0
    return (t["scene_s"] + t["render_s"] + refine) / len(r["clips"])


def _gap_notes(r: dict) -> list[str]:
    """Each raw mode's mIoU gap to the ground truth split by class group (the parts sum to the gap)."""
    ref = r["table"][GROUND_TRUTH]["all"]
    notes = []
    for m in r["modes"]:
        parts = gap_by_group(ref, r["table"][m]["all"])
        notes.append(
            f"{m}: mIoU gap {ref['miou'] - r['table'][m]['all']['miou']:.3f} to the ground truth, by class group "
            + ", ".join(f"{g} {v:.3f}" for g, v in parts.items())
        )
    return notes


def run(quick: bool) -> Section:
    judge = load_judge(weights_dir() / "judge_small.safetensors")
    bev_path = weights_dir() / "judge_bev_small.safetensors"
    have = available_modes()
    if quick:  # one frame of one clip, the three front cameras, the rig's track: seconds
        modes = tuple(m for m in ("oracle", "generate") if m in have)
        kw = dict(count=1, shifts=(0.0,), cameras=["CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"], clip_frames=1)
    else:
        modes = tuple(m for m in ("oracle", "reconstruct", "generate") if m in have)
        kw = dict(
            count=2,
            shifts=(0.0, 2.0, -2.0, 4.0, -4.0),
            frames=[1, 3],
            cache=runs_dir() / "judge_renders",
            blends=BLENDS if refine_available() else (),
            bev_head=load_bev(bev_path) if bev_path.exists() else None,
            blurs=BLURS,
        )
    r = domain_gap(judge, "test", modes=modes, progress=False, **kw)
    shifts = [str(s) for s in r["shifts"]]
    gt = r["table"][GROUND_TRUTH]["all"]["miou"]
    bev = bool(r["bev_layers"])
    rows, points = [], []
    for row in r["rows"]:
        t = r["table"][row]
        secs = _seconds(r, row)
        fd = r["frechet"][row]["all"] if row != GROUND_TRUTH else 0.0
        extra = [t["all"]["bev_miou"], t["all"].get("box_map")] if bev else []
        rows.append([row, *(t[s]["miou"] for s in shifts), t["all"]["miou"], t["all"]["miou"] / gt, fd, *extra, secs])
        if not row.startswith(GROUND_TRUTH):  # the world's images, sharp or blurred, are references, not knobs
            points.append((row, secs, t["all"]["miou"]))
    f = r["frechet_floor_world_halves"]
    floor = "too few images" if f is None else f"{f:.2f}"
    default = "generate" if "generate" in modes else modes[0]
    if r["blends"] and "generate" in modes:
        default = refined_row("generate", "mix")
    return Section(
        key="downstream",
        title="Downstream: the judge's mIoU on served scenes",
        columns=[
            "judged images",
            *(f"mIoU {s} m" for s in shifts),
            "mIoU all",
            "/ ground truth",
            "judge FD",
            *(["BEV mIoU", "vehicle box mAP"] if bev else []),
            "s / clip",
        ],
        rows=rows,
        default=default,
        why=f"{len(r['clips'])} held-out clip(s), {r['images_per_shift']} images per track. generate is the "
        "playground's default (a scene from the scenario alone), refined with the served blend (mix) on a shifted "
        "track; the oracle row renders the lifting of exact colour and depth, the ground-truth row is the judge on "
        "the world's own images (the reference), and its blurred rows those images through a splat's blur (what "
        "exact content keeps when drawn as splats).",
        pareto=Pareto(
            "seconds per clip (scene + renders + refinement)",
            "judge mIoU vs exact labels",
            points,
            default,
            curve=False,
        ),
        notes=[f"judge Fréchet distance floor (world images, two random halves): {floor}"]
        + _gap_notes(r)
        + ([f"BEV mIoU: mean IoU of {', '.join(r['bev_layers'])} on the BEV head's grid"] if bev else []),
        data={"miou": {row[0]: row[len(shifts) + 1] for row in rows}, "frechet": r["frechet"]},
    )
