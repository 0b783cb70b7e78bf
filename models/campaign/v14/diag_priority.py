"""Would a render-time frame priority (4DGS-like temporal opacity: at time t, frame t's static Gaussians in front of
the other frames' copies) reach the bar? Its best case is the scene of frame t's six views alone; measured here for
the VAE's colour and depth and for the served decoder, beside the aggregated window. Test clips, frame 1, 0 m.

usage: python models/campaign/v14/diag_priority.py D [CLIPS]
"""

import sys

import numpy as np

sys.path.insert(0, "models/campaign/v14")
from diag_agg import only_frames, sc  # noqa: E402
from diag_ceiling import FAR, build, clip_view, m, rig_of  # noqa: E402

from worldsplat.gaussians.aggregate import Economy  # noqa: E402
from worldsplat.pipeline.inference import encode_clip, pixel_guide, reconstruct, to_scene4d  # noqa: E402
from worldsplat.training.data import ShardDataset  # noqa: E402
from worldsplat_models.vae import denormalize_depth  # noqa: E402

rows: dict = {}


def add(k, v):
    rows.setdefault(k, []).append(v)


ds = ShardDataset(sys.argv[1], "test")
for i in range(int(sys.argv[2]) if len(sys.argv) > 2 else 3):
    s = ds[i]
    clip = clip_view(s, rig_of(s))
    L = encode_clip(m, clip.rgb, clip.depth, clip.dynamic)
    g = pixel_guide(m, L)
    vcol = ((g[:, :, 0:3] + 1) / 2).clamp(0, 1).permute(0, 1, 3, 4, 2).numpy()
    vdep = np.minimum(denormalize_depth(g[:, :, 3], m.data.depth_near, FAR).numpy().astype(np.float64), FAR)
    vdyn = g[:, :, 4].clamp(0, 1).numpy()
    eco = Economy.for_decoded(1.0)
    dec = build(clip, vcol, vdep, vdyn)
    add("VAE col+dep agg", sc(s, to_scene4d(dec, economy=eco)))
    add("VAE col+dep frame t only", sc(s, to_scene4d(only_frames(dec, {1}), economy=eco)))
    rec = reconstruct(clip, m)  # the served decoder, its own economy
    add("served decoder agg", sc(s, to_scene4d(rec)))
    add("served decoder frame t only", sc(s, to_scene4d(only_frames(rec, {1}))))
    print(i, {k: round(v[-1], 2) for k, v in rows.items()}, flush=True)
print("mean", {k: round(float(np.mean(v)), 2) for k, v in rows.items()})
