"""The error map behind models.md v14 item 1: GT colour + GT depth, one opaque Gaussian per pixel, rendered at frame 1
of test clip 0 (three front cameras) from frame 1's views alone and from the aggregated window; rows GT | frame t only |
its |error| x4 | aggregated | its |error| x4.

usage: python models/campaign/v14/look_edges.py D OUT.png
"""

import sys

import numpy as np
from PIL import Image

sys.path.insert(0, "models/campaign/v14")
from diag_agg import only_frames
from diag_ceiling import build, clip_view, rig_of

from worldsplat.gaussians.aggregate import Economy
from worldsplat.pipeline.inference import to_scene4d
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset

ds = ShardDataset(sys.argv[1], "test")
s = ds[0]
clip = clip_view(s, rig_of(s))
dec = build(
    clip, s["rgb"].astype(np.float32) / 255, np.asarray(s["depth"], np.float64), np.asarray(s["dynamic"], np.float32)
)
eco = Economy.for_decoded(1.0)
rows = []
gt = s["rgb"][1, :3].astype(np.float32)
for sc in (to_scene4d(only_frames(dec, {1}), economy=eco), to_scene4d(dec, economy=eco)):
    r = render_scene_track(sc, 0.0, frames=[1]).rgb[0, :3].astype(np.float32)  # uint8 -> float
    err = np.abs(r - gt).mean(-1, keepdims=True).repeat(3, -1) * 4
    rows.append(np.concatenate([np.concatenate(list(r), 1), np.concatenate(list(np.clip(err, 0, 255)), 1)], 0))
img = np.concatenate([np.concatenate(list(gt), 1)] + rows, 0).astype(np.uint8)
Image.fromarray(img).resize((img.shape[1] * 3, img.shape[0] * 3), Image.NEAREST).save(sys.argv[2])
