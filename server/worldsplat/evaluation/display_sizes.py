"""Reconstruct mode at display sizes other than the model image: PSNR and gap fraction of the served scene at the rig
cameras, per decoded scale floor (web/docs/models.md, "Scale floor at display sizes").

    python -m worldsplat.evaluation.display_sizes [--weights W] [--preset urban_straight] \
        [--sizes 112x64,200x112,400x224] [--floors 0,0.3,0.5] [--frames 0,4]

One line per (size, floor): static Gaussians of the served scene, mean PSNR over the 6 cameras and the frames, and
the fraction of pixels with alpha < 0.9 (where the background shows between Gaussians).
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from worldsplat.core.metrics import psnr
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians import rasterize
from worldsplat.pipeline import inference as inf
from worldsplat.world import build_world, simulate


def measure(models, preset: str, size: tuple[int, int], floor: float, frames=(0, 4)) -> dict:
    sc = load_preset(preset)
    sc = sc.model_copy(update={"image": sc.image.model_copy(update={"width": size[0], "height": size[1]})})
    clip = simulate(build_world(sc))
    served = inf.DECODED_SCALE_FLOOR_MODEL_PX
    inf.DECODED_SCALE_FLOOR_MODEL_PX = floor  # scale_floor reads it at call time; restored below
    try:
        scene = inf.to_scene4d(inf.reconstruct(clip, models))
    finally:
        inf.DECODED_SCALE_FLOOR_MODEL_PX = served
    ps, gaps = [], []
    for t in frames:
        for v in range(len(clip.rig)):
            with torch.no_grad():
                out = rasterize(scene.at_frame(t), scene.camera(t, v))
            ps.append(psnr(out["rgb"].clamp(0, 1), torch.as_tensor(clip.rgb[t, v]).float() / 255))
            gaps.append(float((out["alpha"] < 0.9).float().mean()))
    return {
        "size": f"{size[0]}x{size[1]}",
        "floor_model_px": floor,
        "static": len(scene.static),
        "psnr": float(np.mean(ps)),
        "alpha_below_0.9": float(np.mean(gaps)),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", default=None)
    p.add_argument("--preset", default="urban_straight")
    p.add_argument("--sizes", default="112x64,200x112,400x224")
    p.add_argument("--floors", default="0,0.3,0.5")
    p.add_argument("--frames", default="0,4")
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    models = inf.load_models(a.weights)
    frames = tuple(int(x) for x in a.frames.split(","))
    for s in a.sizes.split(","):
        w, h = (int(x) for x in s.split("x"))
        for f in a.floors.split(","):
            print(json.dumps(measure(models, a.preset, (w, h), float(f), frames)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
