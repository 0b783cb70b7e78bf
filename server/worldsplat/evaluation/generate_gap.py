"""Where generate's judge mIoU is lost: the generated content or how it is represented and rendered
(web/docs/downstream.md, "Generate's gap: content or representation"). The judge (`evaluation.downstream`) on the
world's images and on generate's content at each stage of the served path, the same views, against the world's
exact labels.

    python -m worldsplat.evaluation.generate_gap [--clips 0,1,2,3] [--frames 1,3] [--shifts 0,2] [--png PATH]

Rows (test clips at the models' image, 112x64, 4 frames, as `worldsplat judge eval` makes them; generate's scene
is `pipeline.scene.generate_scene(mode="generate")` as served, its models' calls recorded on the way):
- ground truth: the world's own images;
- world redrawn: the world with the appearance its seed drew (paints, lit windows, the sun's direction,
  the rain) drawn again (`world.appearance.redraw_appearance`), its labels the same: what a generator that samples
  the world's own distribution perfectly shows, the ceiling of a sampler of these conditions;
- world through the VAE: the world's images encoded and decoded by the VAE (`inference.encode_clip`, `pixel_guide`):
  what the latent space keeps of the world, the best a generator of latents could show (at the rig only);
- world at 1/k: the world's images area-averaged to 1/k of their width and height and bilinearly up-sampled back
  (`world_at`): how much of its detail the judge needs, the scale the VAE's row is read against (at the rig only);
- generated images: the VAE's decoding of the generated latents (`inference.pixel_guide`, `pixels.served_maps`),
  the generator's own pictures of each keyframe's six views: its content with no 3D (at the rig only);
- served: the served scene rendered on the track (`pipeline.render.render_scene_track`);
- lifted / lifted fitted: a frame's six generated images lifted per pixel at their decoded depth (the oracle's
  lifting, `gaussians.lift.lift`, no aggregation, no objects), unfitted and fitted at the lifting camera
  (`lift(fit_iters=FIT_ITERS)`), rendered at that frame's cameras on the track;
- served fitted to generated: the served scene with its static Gaussians' colours fitted jointly to the generated
  images at every keyframe's six cameras (`gaussians.colour_fit.fit_scene_static`: one colour per Gaussian, the objects untouched);
- served fitted to world: the same fit to the world's images (what the served Gaussians could show with the
  world's colours: the representation's ceiling).
"ground truth" vs "generated images" is the content's loss, "generated images" vs "served" the representation's.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

import worldsplat.pipeline.inference as inference
import worldsplat.pipeline.scene as scene_module
from worldsplat.evaluation.downstream import (
    GROUND_TRUTH,
    GROUPS,
    confusion,
    parse_rows,
    save_sheet,
    summary,
    tile_sheet,
)
from worldsplat.evaluation.scene_quality import TEMPERATURE_HELP, gaussians_from
from worldsplat.gaussians.colour_fit import fit_scene_static
from worldsplat.gaussians.lift import FIT_ITERS, lift
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.types import Gaussians
from worldsplat.pipeline import pixels
from worldsplat.pipeline.render import render_scene_track
from worldsplat.world import build_world, simulate
from worldsplat.world.appearance import redraw_appearance
from worldsplat.world.classes import PALETTE
from worldsplat.world.dataset import clip_scenario
from worldsplat_models.judge import load_judge, segment
from worldsplat_models.weights import load_weights, weights_dir

GENERATED = "generated images"
REDRAWN = "world redrawn"
REDRAW_SEED = 1  # the redraw's seed per clip is this + the clip's index
VAE_WORLD = "world through the VAE"
DETAIL_ROWS = {"world at 1/1.5": 1.5, "world at 1/2": 2.0, "world at 1/3": 3.0}
ROWS = (
    GROUND_TRUTH,
    REDRAWN,
    *DETAIL_ROWS,
    VAE_WORLD,
    GENERATED,
    "served",
    "lifted",
    "lifted fitted",
    "served fitted to generated",
    "served fitted to world",
)
EXACT = "exact labels"  # the figure's last line
# rows with no 3D: judged at the rig (shift 0) only
RIG_ONLY = (*DETAIL_ROWS, VAE_WORLD, GENERATED)


def rows_at(shift: float, rows=ROWS) -> list[str]:
    """The rows judged on the track shifted `shift` m: every row at the rig, the 2D rows nowhere else."""
    return [r for r in rows if shift == 0 or r not in RIG_ONLY]


@contextlib.contextmanager
def recording():
    """Within: every `inference.generate` call's DecodedFrames appended to the yielded list (the served scene is
    built unchanged)."""
    calls: list = []
    served = inference.generate

    def generate(*a, **k):
        dec = served(*a, **k)
        calls.append(dec)
        return dec

    inference.generate = generate
    try:
        yield calls
    finally:
        inference.generate = served


def generated_views(models, decs, frame_times: np.ndarray, size: tuple[int, int]) -> dict[int, tuple]:
    """Per scene frame drawn by the models: the VAE's decoding of its generated latents at the rig's image
    (`pixels.served_maps`): rgb (V,H,W,3) float in [0,1], depth (V,H,W) camera z (sky +inf), dynamic (V,H,W), and
    the frame's ego pose as the decoded Gaussians place it."""
    d = models.data
    out = {}
    for dec in decs:
        with torch.no_grad():
            guide = inference.pixel_guide(models, dec.latents)
        T, V = guide.shape[:2]
        rgb, depth, dyn = pixels.served_maps(guide.reshape(-1, *guide.shape[2:]), size, d.depth_near, d.depth_far)
        for i, ft in enumerate(dec.frame_times[:T]):
            t = int(np.argmin(np.abs(np.asarray(frame_times) - ft)))
            sl = slice(i * V, (i + 1) * V)
            out[t] = (rgb[sl], depth[sl], dyn[sl], np.asarray(dec.ego_to_world[i]))
    return out


def vae_round_trip(models, clip) -> np.ndarray:
    """The clip's images (T,V,H,W,3) uint8 encoded and decoded by the VAE, at the clip's image."""
    T, V, H, W = clip.depth.shape
    with torch.no_grad():
        L = inference.encode_clip(models, clip.rgb, clip.depth, clip.dynamic)
        guide = inference.pixel_guide(models, L)
    d = models.data
    rgb = pixels.served_maps(guide.reshape(-1, *guide.shape[2:]), (H, W), d.depth_near, d.depth_far)[0]
    return to_uint8(rgb).reshape(T, V, H, W, 3)


def world_at(rgb: np.ndarray, k: float) -> np.ndarray:
    """Images (..., H, W, 3) uint8 area-averaged to 1/k of their size and bilinearly up-sampled back: the world's own
    content with the detail finer than k pixels removed."""
    H, W = rgb.shape[-3:-1]
    x = torch.from_numpy(rgb.reshape(-1, H, W, 3)).permute(0, 3, 1, 2).float()
    low = torch.nn.functional.interpolate(x, size=(round(H / k), round(W / k)), mode="area")
    y = torch.nn.functional.interpolate(low, size=(H, W), mode="bilinear", align_corners=False)
    return y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy().reshape(rgb.shape)


def lifted_frame(rig, ego: np.ndarray, rgb, depth, dyn, shift: float, fit_iters: int) -> tuple[np.ndarray, ...]:
    """A frame's views lifted per pixel at their depth (nothing else), rendered at the frame's cameras shifted
    `shift` m: rgb (V,H,W,3) uint8, alpha (V,H,W)."""
    g = Gaussians.cat([lift(rgb[v], depth[v], dyn[v], rc.at(ego), fit_iters=fit_iters) for v, rc in enumerate(rig)])
    views = [render_view(g, rc.at(ego, shift)) for rc in rig]
    return np.stack([v.rgb for v in views]), np.stack([v.alpha for v in views])


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.round(np.asarray(rgb) * 255.0), 0, 255).astype(np.uint8)


class Scores:
    """Per (row, shift): the judge's confusion against the exact labels, pooled and per clip."""

    def __init__(self):
        self.conf: dict = {}
        self.per_clip: dict = {}

    def add(self, key, pred: np.ndarray, labels: np.ndarray, clip: int = 0) -> None:
        c = confusion(pred, labels)
        self.conf[key] = self.conf.get(key, 0) + c
        per = self.per_clip.setdefault(key, {})
        per[clip] = per.get(clip, 0) + c

    def table(self, rows, shifts) -> dict:
        return {
            row: {
                str(s): {
                    **summary(self.conf[(row, s)]),
                    "clips": {str(k): summary(c)["miou"] for k, c in self.per_clip[(row, s)].items()},
                }
                for s in shifts
                if (row, s) in self.conf
            }
            for row in rows
        }


def measure(
    clips,
    frames,
    shifts,
    rows=ROWS,
    steps: int = 8,
    png: Path | None = None,
    progress=print,
    vae: Path | None = None,
    gaussians: str | None = None,
    judge: Path | None = None,
) -> dict:
    """Every row of every clip (see the module); `vae`: the row "world through the VAE" through these VAE weights
    instead of the served VAE (another down-sampling or latent width, `worldsplat train-campaign vae`); `gaussians`:
    generate's scene built from that source of Gaussians (`inference.GAUSSIANS`; None: as served); `judge`: the
    judge's weights (None: `weights_dir()`'s, where $WORLDSPLAT_WEIGHTS also points the models)."""
    with gaussians_from("generate", gaussians):
        return _measure(clips, frames, shifts, rows, steps, png, progress, vae, judge)


def _measure(clips, frames, shifts, rows, steps, png, progress, vae, judge_path) -> dict:
    judge = load_judge(judge_path or weights_dir() / "judge_small.safetensors")
    models = inference.load_models()
    world_models = models if vae is None else dataclasses.replace(models, vae=load_weights(vae, "vae").eval())
    scores, tiles, timing = Scores(), {}, {}
    for ci in clips:
        sc = clip_scenario("test", ci, frames=4)
        world = build_world(sc)
        H, W = world.rig[0].height, world.rig[0].width
        t0 = time.perf_counter()
        with recording() as decs:
            scene = scene_module.generate_scene(sc, mode="generate", steps=steps)
        gen = generated_views(models, decs, world.frame_times, (H, W))
        missing = [t for t in frames if t not in gen]
        if missing:
            raise ValueError(f"clip {ci}: frames {missing} were not drawn by the models (keyframes {sorted(gen)})")
        # the decoded Gaussians' frames are the scene's
        pose_err = max(float(np.abs(gen[t][3] - scene.ego_to_world[t]).max()) for t in gen)
        t1 = time.perf_counter()
        fitted = {}
        if "served fitted to generated" in rows:
            fitted["served fitted to generated"] = fit_scene_static(scene, {t: gen[t][0] for t in gen})
        if "served fitted to world" in rows:
            rig_clip = simulate(world, 0.0, frames=sorted(gen))
            fitted["served fitted to world"] = fit_scene_static(
                scene, {t: rig_clip.rgb[i].astype(np.float64) / 255.0 for i, t in enumerate(sorted(gen))}
            )
        t2 = time.perf_counter()
        for s in shifts:
            clip = simulate(world, s, frames=list(frames))
            first = {}
            for row in rows_at(s, rows):
                if row == GROUND_TRUTH:
                    rgb = clip.rgb
                elif row == REDRAWN:
                    rgb = simulate(redraw_appearance(world, REDRAW_SEED + ci), s, frames=list(frames)).rgb
                elif row in DETAIL_ROWS:
                    rgb = world_at(clip.rgb, DETAIL_ROWS[row])
                elif row == VAE_WORLD:
                    rgb = vae_round_trip(world_models, clip)
                elif row == GENERATED:
                    rgb = np.stack([to_uint8(gen[t][0]) for t in frames])
                elif row == "served":
                    rgb = render_scene_track(scene, s, frames=list(frames)).rgb
                elif row in fitted:
                    rgb = render_scene_track(fitted[row], s, frames=list(frames)).rgb
                else:
                    fit = FIT_ITERS if row == "lifted fitted" else 0
                    rgb = np.stack([lifted_frame(world.rig, gen[t][3], *gen[t][:3], s, fit)[0] for t in frames])
                pred = segment(judge, rgb)
                scores.add((row, s), pred, clip.semantic, ci)
                first[row] = (rgb[0, 0], pred[0, 0])
            if png is not None and ci == clips[0]:
                first[EXACT] = (PALETTE[clip.semantic[0, 0]], None)
                tiles[s] = first
        timing[ci] = {"scene_s": round(t1 - t0, 1), "fit_s": round(t2 - t1, 1),
                      "judge_s": round(time.perf_counter() - t2, 1), "pose_err": pose_err}  # fmt: skip
        progress(f"clip {ci}: {timing[ci]}")
    if png is not None:
        _figure(tiles, [*rows, EXACT], png)
    return {
        "clips": list(clips),
        "frames": list(frames),
        "shifts": list(shifts),
        "rows": list(rows),
        "steps": steps,
        "vae": None if vae is None else str(vae),
        "gaussians": inference.GAUSSIANS["generate"],
        "temperature": dataclasses.asdict(inference.REGION_TEMPERATURE),
        "models": str(models.weights_dir),
        "table": scores.table(rows, shifts),
        "timing": timing,
    }


def _figure(tiles: dict, rows: list[str], path: Path) -> None:
    """One line per row (the exact labels last), per track its image and the judge's labels (white: not judged)."""
    blank = np.full_like(next(iter(tiles.values()))[GROUND_TRUTH][0], 255)
    lines = []
    for row in rows:
        ims = []
        for first in tiles.values():
            img, pred = first.get(row, (blank, None))
            ims += [img, blank if pred is None else PALETTE[pred]]
        lines.append(ims)
    save_sheet(tile_sheet(lines), path)


def markdown(r: dict) -> str:
    groups = list(GROUPS)
    shifts = [str(s) for s in r["shifts"]]
    gt = r["table"][GROUND_TRUTH]
    head = "| row | " + " | ".join(f"mIoU {s} m | / GT" for s in shifts) + " | " + " | ".join(groups) + " |"
    out = [
        f"test clips {r['clips']}, frames {r['frames']}, six cameras, {r['steps']} steps; judge mIoU against the "
        f"world's exact labels; groups at {shifts[0]} m",
        "",
        head,
        "|" + "---|" * (1 + 2 * len(shifts) + len(groups)),
    ]
    for row in r["rows"]:
        t = r["table"][row]
        cells = []
        for s in shifts:
            if s in t:
                cells += [f"{t[s]['miou']:.3f}", f"{t[s]['miou'] / gt[s]['miou']:.2f}"]
            else:
                cells += ["-", "-"]
        g0 = t.get(shifts[0], {}).get("groups", {})
        gcells = ["-" if g0.get(k) is None else f"{g0[k]:.3f}" for k in groups]
        out.append(f"| {row} | " + " | ".join(cells + gcells) + " |")
    s0 = shifts[0]
    clips = list(gt[s0].get("clips", {}))
    if clips:
        out += ["", f"per clip at {s0} m, mIoU / the ground truth's on the same clip:", ""]
        out += ["| row | " + " | ".join(f"clip {k}" for k in clips) + " |", "|" + "---|" * (1 + len(clips))]
        for row in r["rows"]:
            per = r["table"][row].get(s0, {}).get("clips", {})
            cells = [f"{per[k] / gt[s0]['clips'][k]:.2f}" if per.get(k) is not None else "-" for k in clips]
            out.append(f"| {row} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--clips", default="0,1,2,3", help="test clips (the judge eval's)")
    p.add_argument("--frames", default="1,3")
    p.add_argument("--shifts", default="0,2", help="lateral track shifts (m)")
    p.add_argument("--steps", type=int, default=8)
    p.add_argument("--rows", default=",".join(ROWS[1:]), help="rows beside the ground truth")
    p.add_argument("--vae", type=Path, default=None, help='"world through the VAE" through these VAE weights')
    p.add_argument("--gaussians", default=None, help="generate's source of Gaussians (default: as served)")
    p.add_argument(
        "--judge", type=Path, default=None, help="the judge's weights file (default: judge_small in the weights folder)"
    )
    p.add_argument("--temperature", default=None, help=TEMPERATURE_HELP)
    p.add_argument("--out", type=Path, default=None, help="write the table (markdown) and the rows (json) here")
    p.add_argument(
        "--png",
        type=Path,
        default=None,
        help="the first clip's first frame, CAM_FRONT: per row (lines) and track (columns: image, judge labels)",
    )
    a = p.parse_args(argv)
    ints = lambda x: [int(v) for v in x.split(",")]  # noqa: E731
    rows = parse_rows(p, a.rows, ROWS)
    if a.temperature is not None:
        try:
            inference.REGION_TEMPERATURE = inference.RegionTemperature.parse(a.temperature)
        except ValueError as e:
            p.error(str(e))
    shifts = [float(v) for v in a.shifts.split(",")]
    r = measure(ints(a.clips), ints(a.frames), shifts, rows, a.steps, a.png, vae=a.vae, gaussians=a.gaussians,
                judge=a.judge)  # fmt: skip
    md = markdown(r)
    print(md)
    if a.out is not None:
        import json  # noqa: PLC0415

        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "generate_gap.md").write_text(md + "\n")
        (a.out / "generate_gap.json").write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
