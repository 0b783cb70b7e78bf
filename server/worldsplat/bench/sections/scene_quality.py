"""The served scene against the world's exact images, per mode (`worldsplat.evaluation.scene_quality`): Gaussians per
served pixel, static-pixel PSNR, luma SSIM, agents seen and agent silhouette IoU on a canvas 2x the served image.

Knob: the served mode. The cost is the seconds to build the scene; the error axis is the static-pixel PSNR.
"""

from __future__ import annotations

from worldsplat.bench.report import Pareto, Section
from worldsplat.evaluation import appearance_ceiling
from worldsplat.evaluation import scene_quality as sq
from worldsplat.pipeline.scene import available_modes
from worldsplat.world import build_world

QUICK_SERVED = {"width": 100, "height": 56, "frames": 1, "fps": 4.0}
CEILING_DRAWS = 8  # redraws of each scenario's appearance for the note on what a generator can reach


def run(quick: bool) -> Section:
    have = available_modes()
    if quick:  # one held-out scenario at half the served size, one frame, the oracle only: seconds
        modes = ["oracle"]
        specs, served, frames = ["test:0"], QUICK_SERVED, [0]
    else:
        modes = [m for m in sq.ALL_MODES if m in have]
        specs, served, frames = sq.DEFAULT_SCENARIOS.split(","), sq.SERVED, None
    rows_in = [sq.measure(s, m, frames, served=served) for m in modes for s in specs]
    summ = sq.summary(rows_in)
    rows, points = [], []
    for mode, s in summ.items():
        rows.append([mode, *(s[k] for k, _, _ in sq.FIGURES), s["agents_eligible"]])
        points.append((mode, s["scene_s"], s["static_psnr_db"]))
    default = "generate" if "generate" in summ else modes[0]
    size = f"{served['width']}x{served['height']}"
    notes = [] if quick else [ceiling_note(specs, served)]
    return Section(
        key="scene_quality",
        title="Served scene quality against exact images",
        columns=["mode", *(name for _, name, _ in sq.FIGURES), "agents scored"],
        rows=rows,
        default=default,
        why=f"{len(specs)} held-out scenario(s) served at {size}, rendered by the reference rasterizer on a canvas "
        f"{sq.SCALE}x per side at every rig camera, frame 0 (silhouettes: every frame). generate is the "
        "playground's default; the oracle row lifts exact colour and depth (the representation's ceiling).",
        pareto=Pareto("seconds to build the scene", "static-pixel PSNR (dB)", points, default=default, curve=False),
        notes=notes,
        data={"summary": summ},
    )


def ceiling_note(specs: list[str], served: dict) -> str:
    """What any generator of the scenarios' conditions reaches against the same truth
    (`evaluation.appearance_ceiling`): a redraw of each world's appearance and the redraws' mean."""
    rows = {s: appearance_ceiling.ceiling(build_world(sq.scenario_of(s, served)), CEILING_DRAWS) for s in specs}
    m = appearance_ceiling.pooled(rows)
    return (
        f"What a generator of these conditions can reach against the same truth (`python -m "
        f"worldsplat.evaluation.appearance_ceiling`, {CEILING_DRAWS} redraws of each world's paints, lit windows, sun "
        f"and rain): a redraw (a perfect sampler) {m['redraw_static_psnr_db']:.2f} dB / SSIM "
        f"{m['redraw_luma_ssim']:.3f}; the redraws' mean (the conditional mean) "
        f"{m['mean_inf_static_psnr_db']:.2f} dB / {m['mean_luma_ssim']:.3f}; agents seen by a redraw "
        f"{m['redraw_agents_seen_share']:.2f} (every agent where it is: the contrast against another draw decides)."
    )
