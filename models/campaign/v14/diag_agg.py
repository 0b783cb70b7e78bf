"""The served aggregation (paper eq. 3 + economy) on exact geometry: how much of reconstruct's gap is aggregation.
GT colour + GT depth, one opaque Gaussian per pixel (std 0.3 footprint) per frame-view; test clips, frame 1, 0 m.

usage: python models/campaign/v14/diag_agg.py DATA [CLIPS]   (needs diag_ceiling.py's helpers beside it; the "fuse"
rows need session 11's visibility fusion applied: models/campaign/v11/fusion.py + fusion_aggregate.diff)
"""

import dataclasses
import sys

import numpy as np
import torch

sys.path.insert(0, "models/campaign/v14")
from diag_ceiling import build, clip_view, rig_of  # noqa: E402

from worldsplat.core.metrics import psnr  # noqa: E402
from worldsplat.evaluation.models import _img  # noqa: E402
from worldsplat.gaussians import Gaussians  # noqa: E402
from worldsplat.gaussians.aggregate import Economy  # noqa: E402
from worldsplat.pipeline.inference import to_scene4d  # noqa: E402
from worldsplat.pipeline.render import render_scene_track  # noqa: E402
from worldsplat.pipeline.scene import oracle_scene  # noqa: E402
from worldsplat.training.data import ShardDataset  # noqa: E402

FUSION = "fuse" in {f.name for f in dataclasses.fields(Economy)}  # only with session 11's diff applied

rows: dict = {}


def add(k, v):
    rows.setdefault(k, []).append(v)


def only_frames(dec, keep):
    gs = [[g if t in keep else Gaussians.empty() for g in r] for t, r in enumerate(dec.gaussians)]
    return dataclasses.replace(
        dec, gaussians=gs, dynamic_logits=[[x.extras[:, 0] if len(x) else torch.zeros(0) for x in r] for r in gs]
    )


def sc(s, scene, t=1):
    tr = render_scene_track(scene, 0.0, frames=[t]).rgb
    return float(np.mean([psnr(_img(tr[0, v]), _img(s["rgb"][t, v])) for v in range(6)]))


def main(data: str, n: int) -> None:
    ds = ShardDataset(data, "test")
    for i in range(n):
        s = ds[i]
        clip = clip_view(s, rig_of(s))
        gcol = s["rgb"].astype(np.float32) / 255.0
        gdep = np.asarray(s["depth"], np.float64)
        gdyn = np.asarray(s["dynamic"], np.float32)
        eco = Economy.for_decoded(1.0)
        for k, surf in ((0.3, False), (0.15, False), (0.3, True), (0.5, True)):
            dec = build(clip, gcol, gdep, gdyn, k=k, surfel=surf)
            k = f"{k}{'s' if surf else ''}"
            add(f"k{k} agg", sc(s, to_scene4d(dec, economy=eco)))
            if FUSION:
                add(f"k{k} agg fuse", sc(s, to_scene4d(dec, economy=dataclasses.replace(eco, fuse=True))))
            add(f"k{k} frame t only", sc(s, to_scene4d(only_frames(dec, {1}), economy=eco)))
            add(f"k{k} frames t,t+1", sc(s, to_scene4d(only_frames(dec, {1, 2}), economy=eco)))
            add(f"k{k} frames t-1,t", sc(s, to_scene4d(only_frames(dec, {0, 1}), economy=eco)))
        add("oracle mode (served lifting)", sc(s, oracle_scene(clip)))
        print(i, {k: round(v[-1], 2) for k, v in rows.items()}, flush=True)
    print("mean", {k: round(float(np.mean(v)), 2) for k, v in rows.items()})


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 3)
