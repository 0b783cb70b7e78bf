"""How near any generator of a scenario's conditions can come to its ground truth: the appearance ceiling.

`generate` draws a scene from the layout, the caption, the weather and the time of day; the world's facade paints,
tree greens, sign faces, lit windows, sun direction and rain streaks are drawn from the seed and are in none of the
conditions (`world.appearance`). Scored against the one realisation the seed drew (`scene_quality`'s static PSNR and
luma SSIM, frame 0, every rig camera, on the 400x224 canvas, the world's own images with no Gaussians in between):

- **a redraw**: the world with its appearance drawn again (K times). A generator that samples the world's own
  distribution perfectly scores this, on average.
- **the mean of K redraws**: per pixel, the average of the K images, an estimate of the conditional mean. Under
  squared error no predictor of these conditions beats the conditional mean, so its PSNR is the ceiling of any
  generator, however it is trained; `mse_mean_inf` removes the estimate's own noise (mse of the K mean minus the
  pixels' variance over the redraws / K, the unbiased form).
- **agents seen by a redraw**: `scene_quality`'s test (cover and contrast against the exact image's) on each redraw,
  every agent at its exact pixels (cover 1): what the contrast half of the test asks of a perfect sampler, whose
  surroundings of an agent (paints, lit windows) are another draw than the ground truth's.

    python -m worldsplat.evaluation.appearance_ceiling [--scenarios test:0,test:1,test:2,preset:urban_straight]
        [--draws 16] [--parts materials,light] [--out FILE.json] [--png FILE.png [--views 0,1]]

`--png`: per scenario and view, the exact image, the served generate scene's render (`scene_quality.measure_frame`)
and a redraw, side by side on the canvas.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from worldsplat.core.metrics import psnr_from_mse
from worldsplat.evaluation.scene_quality import (
    DEFAULT_SCENARIOS,
    SCALE,
    STATIC_CLASSES,
    Truth,
    agent_view,
    candidates,
    ground_truth,
    luma_ssim,
    scaled,
    scenario_of,
    static_psnr,
)
from worldsplat.world import build_world
from worldsplat.world.appearance import PARTS, redraw_appearance
from worldsplat.world.simulate import render_views


def frame0_images(world, scale: int = SCALE) -> dict:
    """The world's frame 0 at every rig camera on the canvas `scale` x the served image: rgb, semantic."""
    cams = [scaled(rc.at(world.ego_to_world[0]), scale) for rc in world.rig]
    return render_views(world, 0, cams)


def ceiling(world, draws: int, parts: tuple[str, ...] = PARTS, scale: int = SCALE, seed: int = 1) -> dict:
    """One world's figures: `draws` redraws of its appearance (`world.appearance.redraw_appearance`) against its
    ground truth, frame 0 on the canvas."""
    if draws < 2:
        raise ValueError(f"appearance ceiling: draws must be >= 2 (the mean's noise is estimated), got {draws}")
    truth = ground_truth(world, 0, [scaled(rc.at(world.ego_to_world[0]), scale) for rc in world.rig])
    agents = candidates(world, 0, truth, scale)
    images = [frame0_images(redraw_appearance(world, seed * 100_003 + k, parts), scale)["rgb"] for k in range(draws)]
    seen = [agents_seen(truth, rgb, agents, scale) for rgb in images]
    n = len(agents)
    return {"draws": draws, "parts": list(parts), **figures(truth, images), "agents_eligible": n,
            "redraw_agents_seen": float(np.mean(seen)), "redraw_agents_seen_range": [min(seen), max(seen)],
            "redraw_agents_seen_share": float(np.mean(seen)) / n if n else float("nan")}  # fmt: skip


def agents_seen(truth: Truth, rgb: np.ndarray, agents: list[int], scale: int = SCALE) -> int:
    """How many of `agents` an image of the world's own geometry (every agent at its exact pixels) shows as seen by
    `scene_quality`'s test: the cover is whole, so the contrast against the ring around the agent decides."""
    return sum(agent_view(rgb, (truth.instance == k).astype(np.float32), truth, k, scale)["seen"] for k in agents)


def figures(truth: Truth, images) -> dict:
    """Each image (V,H,W,3 uint8) against `truth` (static PSNR, luma SSIM, averaged), and their per-pixel mean:
    its PSNR as measured, and with the mean's own noise removed (the squared error of a mean of K draws exceeds
    the conditional mean's by the pixels' variance over the draws / K)."""
    static = np.isin(truth.semantic, STATIC_CLASSES)
    acc = acc2 = None
    one_psnr, one_ssim = [], []
    for rgb in images:
        one_psnr.append(static_psnr(rgb, truth))
        one_ssim.append(luma_ssim(rgb, truth))
        x = rgb.astype(np.float64) / 255.0
        acc = x if acc is None else acc + x
        acc2 = x * x if acc2 is None else acc2 + x * x
    k = len(one_psnr)
    if k < 2:
        raise ValueError(f"appearance ceiling: at least 2 images are needed, got {k}")
    mean = acc / k
    var = np.maximum(acc2 / k - mean**2, 0.0) * k / (k - 1)  # per pixel, unbiased, over the draws
    err = (mean - truth.rgb.astype(np.float64) / 255.0) ** 2
    mse_k = float(err[static].mean())
    mse_inf = max(mse_k - float(var[static].mean()) / k, 0.0)
    mean_u8 = np.clip(np.rint(mean * 255.0), 0, 255).astype(np.uint8)
    return {
        "redraw_static_psnr_db": float(np.mean(one_psnr)),
        "redraw_static_psnr_db_range": [float(np.min(one_psnr)), float(np.max(one_psnr))],
        "redraw_luma_ssim": float(np.mean(one_ssim)),
        "mean_static_psnr_db": psnr_from_mse(mse_k),
        "mean_inf_static_psnr_db": psnr_from_mse(mse_inf),
        "mean_luma_ssim": luma_ssim(mean_u8, truth),
    }


FIGURES = (
    ("redraw_static_psnr_db", "a redraw, static PSNR dB"),
    ("redraw_luma_ssim", "a redraw, luma SSIM"),
    ("mean_static_psnr_db", "mean of K, static PSNR dB"),
    ("mean_inf_static_psnr_db", "mean (K -> inf), static PSNR dB"),
    ("mean_luma_ssim", "mean of K, luma SSIM"),
    ("redraw_agents_seen_share", "a redraw, agents seen"),
)


def table(rows: dict[str, dict]) -> str:
    """A markdown table, one row per scenario (and the mean over them, when given)."""
    lines = ["| scenario | " + " | ".join(name for _, name in FIGURES) + " |", "|---" * (len(FIGURES) + 1) + "|"]
    for spec, r in rows.items():
        lines.append(f"| {spec} | " + " | ".join(f"{r[k]:.3f}" if "ssim" in k else f"{r[k]:.2f}" for k, _ in FIGURES)
                     + " |")  # fmt: skip
    return "\n".join(lines)


def pooled(rows: dict[str, dict]) -> dict:
    """The mean over scenarios of each figure (as `scene_quality.summary` pools the served scenes': agents seen over
    the scenarios' agents)."""
    out = {k: float(np.mean([r[k] for r in rows.values()])) for k, _ in FIGURES if k != "redraw_agents_seen_share"}
    eligible = sum(r["agents_eligible"] for r in rows.values())
    seen = sum(r["redraw_agents_seen"] for r in rows.values())
    return {**out, "agents_eligible": eligible, "redraw_agents_seen": seen,
            "redraw_agents_seen_share": seen / eligible if eligible else float("nan")}  # fmt: skip


def sheet(specs: list[str], views: list[int], path: Path, seed: int = 1) -> None:
    """The --png figure: a row per (scenario, view): exact | generate as served | a redraw."""
    from PIL import Image  # noqa: PLC0415 - the figure only

    from worldsplat.evaluation.scene_quality import measure_frame  # noqa: PLC0415
    from worldsplat.pipeline.scene import generate_scene, preload  # noqa: PLC0415 - the models, for the figure only

    preload("generate")
    rows = []
    for spec in specs:
        sc = scenario_of(spec)
        world = build_world(sc)
        served = measure_frame(world, generate_scene(sc, mode="generate"), 0)["rgb"]
        redraw = frame0_images(redraw_appearance(world, seed * 100_003))["rgb"]
        gt = frame0_images(world)["rgb"]
        rows += [np.concatenate([gt[v], served[v], redraw[v]], 1) for v in views]
    Image.fromarray(np.concatenate(rows, 0)).save(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m worldsplat.evaluation.appearance_ceiling", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--scenarios", default=DEFAULT_SCENARIOS, help="comma-separated test:I / preset:NAME")
    ap.add_argument("--draws", type=int, default=16, help="redraws of each world's appearance (>= 2)")
    ap.add_argument("--parts", default=",".join(PARTS), help=f"what is drawn again: {', '.join(PARTS)}")
    ap.add_argument("--out", type=Path, help="write the figures as JSON here")
    ap.add_argument("--png", type=Path, help="write exact | generate as served | a redraw here")
    ap.add_argument("--views", default="0,1", help="the rig cameras of --png (indices)")
    a = ap.parse_args(argv)
    parts = tuple(p for p in a.parts.split(",") if p)
    rows = {}
    for spec in a.scenarios.split(","):
        rows[spec] = ceiling(build_world(scenario_of(spec)), a.draws, parts)
        print(spec, json.dumps({k: round(v, 3) for k, v in rows[spec].items() if isinstance(v, float)}), flush=True)
    rows["mean"] = pooled(rows)
    print(table(rows))
    if a.out:
        a.out.write_text(json.dumps(rows, indent=1))
    if a.png:
        sheet(a.scenarios.split(","), [int(v) for v in a.views.split(",")], a.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
