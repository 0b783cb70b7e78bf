"""Where the oracle scene loses the judge's mIoU (web/docs/downstream.md, "What limits generate's ratio"): the judge
(`evaluation.downstream`) on the world's images and on renders of the oracle scene built several ways, the same
views, against the world's exact labels.

    python -m worldsplat.evaluation.oracle_gap [--clips 0,1,2,3] [--frames 1,3] [--shifts 0,2] [--png PATH]
    python -m worldsplat.evaluation.oracle_gap --fit-cost [--scenario default]

Rows (test clips at the models' image, 112x64, 4 frames, as `worldsplat judge eval` makes them):
- ground truth: the world's own images;
- oracle served: `pipeline.scene.generate_scene(mode="oracle")` as the playground serves it (its colours fitted);
- oracle unfitted / oracle fitted: the same scene with the lifting's colours as the pixels' own (`lift(fit_iters=0)`)
  and fitted at each lifting camera (`lift(fit_iters=FIT_ITERS)`, `gaussians.lift.fit_colours`: the served one);
- frame alone (fitted): frame t's six views lifted and nothing else (no aggregation, no objects), rendered at frame
  t's cameras: the lifting and splatting alone.
Per row and track: mIoU over the present classes, each class group's, the share of road pixels read as an agent,
lane-marking IoU, the share of curb pixels read as sidewalk, the render's mean alpha and the share of pixels with
alpha < 0.9 (holes and partial cover, black behind), and per class the mean Rec. 601 luma (render vs world).

`--fit-cost`: the fit's CPU time per view (time.process_time, one thread, back to back in one process) on frame 0's
views of a scenario: the render weights by the generic pairs path (`raster.pair_weights`) and on the lifted view's
stencil (`raster.aligned_weights`), the lifting with and without the fit, and the ratios.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path

import numpy as np

import worldsplat.pipeline.pixels as pixels_module
import worldsplat.pipeline.scene as scene_module
from worldsplat.core.scenario import resolve_scenario
from worldsplat.evaluation.downstream import (
    GROUND_TRUTH,
    GROUPS,
    NUM_CLASSES,
    confusion,
    parse_rows,
    save_sheet,
    summary,
    tile_sheet,
)
from worldsplat.gaussians.lift import FIT_ITERS, lift
from worldsplat.gaussians.raster import aligned_weights, pair_weights, render_view
from worldsplat.pipeline.render import render_scene_track, single_frame_gaussians
from worldsplat.world import build_world, simulate
from worldsplat.world.classes import AGENT_CLASSES, CLASS_NAMES, CURB, LANE_MARKING, PALETTE, ROAD, SIDEWALK
from worldsplat.world.dataset import clip_scenario
from worldsplat_models.judge import load_judge, segment
from worldsplat_models.weights import weights_dir

ROWS = (GROUND_TRUTH, "oracle served", "oracle unfitted", "oracle fitted", "frame alone", "frame alone fitted")
LUMA = np.array([0.299, 0.587, 0.114])


@contextlib.contextmanager
def lifting(fit_iters: int | None):
    """The served lifting (`pipeline.pixels.lift_views`: the oracle's and reconstruct's) with `fit_iters` forced
    (None: as served)."""
    if fit_iters is None:
        yield
        return
    served = pixels_module.FIT_ITERS
    pixels_module.FIT_ITERS = fit_iters
    try:
        yield
    finally:
        pixels_module.FIT_ITERS = served


def frame_alone(world, t: int, shift: float, fit_iters: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame t's six views lifted by the served lifting with `fit_iters` (nothing else), rendered at frame t's cameras on the track: rgb, alpha (V, H, W)."""
    with lifting(fit_iters):
        g = single_frame_gaussians(simulate(world, 0.0, frames=[t]), 0)
    views = [render_view(g, rc.at(world.ego_to_world[t], shift)) for rc in world.rig]
    return np.stack([v.rgb for v in views]), np.stack([v.alpha for v in views])


class Sums:
    """Per row and track: the judge's confusion, and per true class the summed luma, alpha and alpha < 0.9."""

    def __init__(self):
        self.conf, self.luma, self.alpha, self.low, self.n = {}, {}, {}, {}, {}

    def add(self, judge, key, rgb: np.ndarray, labels: np.ndarray, alpha: np.ndarray | None) -> np.ndarray:
        pred = segment(judge, rgb)
        z = lambda: np.zeros(NUM_CLASSES)  # noqa: E731
        for d in (self.luma, self.alpha, self.low, self.n):
            d.setdefault(key, z())
        self.conf[key] = self.conf.get(key, 0) + confusion(pred, labels)
        luma = rgb.astype(np.float64) @ LUMA
        a = np.ones(labels.shape) if alpha is None else alpha
        for c in range(NUM_CLASSES):
            m = labels == c
            self.n[key][c] += m.sum()
            self.luma[key][c] += luma[m].sum()
            self.alpha[key][c] += a[m].sum()
            self.low[key][c] += (a[m] < 0.9).sum()
        return pred

    def row(self, key) -> dict:
        conf, n = self.conf[key], np.maximum(self.n[key], 1)
        s = summary(conf)
        return {
            **s,
            "road_as_agent": float(conf[ROAD, list(AGENT_CLASSES)].sum() / max(conf[ROAD].sum(), 1)),
            "lane_iou": s["per_class"][CLASS_NAMES[LANE_MARKING]],
            "curb_as_sidewalk": float(conf[CURB, SIDEWALK] / max(conf[CURB].sum(), 1)),
            "mean_alpha": float(self.alpha[key].sum() / n.sum()),
            "alpha_below_0.9": float(self.low[key].sum() / n.sum()),
            "luma": (self.luma[key] / n).tolist(),
            "class_pixels": self.n[key].astype(int).tolist(),
        }


def measure(clips, frames, shifts, rows=ROWS, png: Path | None = None, progress=print) -> dict:
    judge = load_judge(weights_dir() / "judge_small.safetensors")
    sums, tiles = Sums(), []
    builds = {"oracle served": None, "oracle unfitted": 0, "oracle fitted": FIT_ITERS}
    for ci in clips:
        sc = clip_scenario("test", ci, frames=4)
        world = build_world(sc)
        t0 = time.perf_counter()
        scenes = {}
        for row, fit in builds.items():
            if row in rows:
                with lifting(fit):
                    scenes[row] = scene_module.generate_scene(sc, mode="oracle")
        for s in shifts:
            clip = simulate(world, s, frames=list(frames))
            first = {}
            for row in rows:
                if row == GROUND_TRUTH:
                    rgb, alpha = clip.rgb, None
                elif row in scenes:
                    r = render_scene_track(scenes[row], s, frames=list(frames))
                    rgb, alpha = r.rgb, r.alpha
                else:
                    fit = FIT_ITERS if row.endswith("fitted") else 0
                    parts = [frame_alone(world, t, s, fit) for t in frames]
                    rgb, alpha = np.stack([p[0] for p in parts]), np.stack([p[1] for p in parts])
                pred = sums.add(judge, (row, s), rgb, clip.semantic, alpha)
                first[row] = (rgb[0, 0], pred[0, 0])
            if png is not None and ci == clips[0]:
                tiles.append(
                    [x for row in rows for x in (first[row][0], PALETTE[first[row][1]])]
                    + [PALETTE[clip.semantic[0, 0]]]
                )
        progress(f"clip {ci}: {time.perf_counter() - t0:.1f} s")
    if png is not None:
        save_sheet(tile_sheet(tiles), png)
    return {
        "clips": list(clips),
        "frames": list(frames),
        "shifts": list(shifts),
        "rows": list(rows),
        "table": {row: {str(s): sums.row((row, s)) for s in shifts} for row in rows},
    }


def markdown(r: dict) -> str:
    groups = list(GROUPS)
    out = [
        f"test clips {r['clips']}, frames {r['frames']}, six cameras; judge mIoU against the world's exact labels",
    ]
    for s in r["shifts"]:
        out += [
            "",
            f"track {s} m:",
            "",
            "| row | mIoU | "
            + " | ".join(groups)
            + " | road as agent | lane IoU | curb as sidewalk | mean alpha | alpha < 0.9 |",
            "|" + "---|" * (len(groups) + 7),
        ]
        for row in r["rows"]:
            t = r["table"][row][str(s)]
            g = [t["groups"][k] for k in groups]
            out.append(
                f"| {row} | {t['miou']:.3f} | "
                + " | ".join("-" if v is None else f"{v:.3f}" for v in g)
                + f" | {t['road_as_agent']:.3f} | {t['lane_iou'] or 0:.3f} | {t['curb_as_sidewalk']:.3f} | "
                f"{t['mean_alpha']:.3f} | {t['alpha_below_0.9']:.3f} |"
            )
        out += ["", "mean luma per class (" + " / ".join(r["rows"]) + "):", ""]
        ref = r["table"][r["rows"][0]][str(s)]
        for c, name in enumerate(CLASS_NAMES):
            if ref["class_pixels"][c]:
                out.append(
                    f"- {name} ({ref['class_pixels'][c]} px): "
                    + " / ".join(f"{r['table'][row][str(s)]['luma'][c]:.1f}" for row in r["rows"])
                )
    return "\n".join(out)


def fit_cost(scenario: str = "default", repeats: int = 3) -> dict:
    """CPU seconds per view (mean over frame 0's views, `repeats` rounds, each view's steps back to back)."""
    sc = resolve_scenario(scenario)
    clip = simulate(build_world(sc), 0.0, frames=[0])
    steps = {
        "pair_weights": lambda a: pair_weights(lift(*a), a[3]),
        "aligned_weights": lambda a: aligned_weights(lift(*a), a[3]),
        "lift": lambda a: lift(*a),
        "lift fitted": lambda a: lift(*a, fit_iters=FIT_ITERS),
    }
    cpu = dict.fromkeys(steps, 0.0)
    V = clip.rgb.shape[1]
    views = [(clip.rgb[0, v], clip.depth[0, v], clip.dynamic[0, v], clip.camera(0, v)) for v in range(V)]
    steps["lift fitted"](views[0])  # warm (scipy import)
    for _ in range(repeats):
        for a in views:
            for k, f in steps.items():
                t0 = time.process_time()
                f(a)
                cpu[k] += time.process_time() - t0
    per = {k: v / (repeats * V) for k, v in cpu.items()}
    H, W = clip.rgb.shape[2:4]
    return {"scenario": scenario, "image": f"{W}x{H}", "views": V, "cpu_s_per_view": per}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--clips", default="0,1,2,3", help="test clips (the judge eval's)")
    p.add_argument("--frames", default="1,3")
    p.add_argument("--shifts", default="0,2", help="lateral track shifts (m)")
    p.add_argument("--rows", default=",".join(ROWS[1:]), help="rows beside the ground truth")
    p.add_argument(
        "--png",
        type=Path,
        default=None,
        help="the first clip's first frame, CAM_FRONT, per track (rows) and row (columns: image, judge labels)",
    )
    p.add_argument("--fit-cost", action="store_true", help="the fit's CPU time per view instead (see the docstring)")
    p.add_argument("--scenario", default="default", help="--fit-cost: a preset name or scenario file")
    a = p.parse_args(argv)
    if a.fit_cost:
        r = fit_cost(a.scenario)
        c = r["cpu_s_per_view"]
        print(f"{r['scenario']} ({r['image']}, {r['views']} views), CPU s per view: "
              + ", ".join(f"{k} {v:.4f}" for k, v in c.items()))  # fmt: skip
        print(f"weights: pair_weights / aligned_weights = {c['pair_weights'] / c['aligned_weights']:.2f}x; "
              f"lift fitted / lift = {c['lift fitted'] / c['lift']:.1f}x")  # fmt: skip
        return 0
    ints = lambda x: [int(v) for v in x.split(",")]  # noqa: E731
    rows = parse_rows(p, a.rows, ROWS)
    shifts = [float(v) for v in a.shifts.split(",")]
    print(markdown(measure(ints(a.clips), ints(a.frames), shifts, rows, a.png)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
