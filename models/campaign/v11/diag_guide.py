"""Ceiling of per-pixel Gaussians built straight from the VAE's decoding (colour, depth, mask), no decoder."""
import sys, numpy as np, torch
from worldsplat.evaluation.models import clip_view, rig_of, _img
from worldsplat.core.metrics import psnr
from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.raster import render_view
from worldsplat.pipeline.inference import load_models, encode_clip, pixel_guide, DecodedFrames, to_scene4d
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset
from worldsplat_models.gs_decoder import pixel_rays
from worldsplat_models.vae import denormalize_depth
from worldsplat.pipeline.conditions import rig_tensors
torch.set_num_threads(2); torch.set_grad_enabled(False)
ds = ShardDataset("/work/campaign/v9/data", "test")
m = load_models("models/weights")
rows = {}
def add(k, v): rows.setdefault(k, []).append(v)
for i in range(3):
    s = ds[i]; rig = rig_of(s); clip = clip_view(s, rig); t = 1; V = 6
    T = s["rgb"].shape[0]
    L = encode_clip(m, clip.rgb, clip.depth, clip.dynamic)
    g = pixel_guide(m, L)  # T,V,5,H,W
    H, W = g.shape[-2:]
    intr, c2w = rig_tensors(rig, clip.ego_to_world, (H, W))
    o, d = pixel_rays(intr, c2w, (H, W), (H, W))  # T,V,3,H,W? check
    for k, op in ((0.3, 1.0), (0.5, 1.0), (0.5, 0.9), (0.8, 1.0)):
        gs = [[None] * V for _ in range(T)]
        for tt in range(T):
            for v in range(V):
                dep = denormalize_depth(g[tt, v, 3], m.data.depth_near, m.data.depth_far).reshape(-1)
                oo = o[tt, v].reshape(1, 3).expand(H * W, 3)
                dd = d[tt, v].reshape(-1, 3)
                means = oo + dep[:, None] * dd
                fp = dep / float(intr[tt, v, 0])
                sc = (fp * k)[:, None].expand(-1, 3).contiguous()
                q = torch.zeros(len(dep), 4); q[:, 0] = 1
                col = ((g[tt, v, 0:3] + 1) / 2).clamp(0, 1).reshape(3, -1).T
                pd = g[tt, v, 4].reshape(-1, 1).clamp(0, 1)
                gs[tt][v] = Gaussians(means, q, sc, torch.full((len(dep),), op), col, pd)
        own = np.mean([psnr(_img(render_view(gs[t][v], clip.camera(t, v)).rgb), _img(s["rgb"][t, v])) for v in range(V)])
        add(f"own_k{k}_o{op}", own)
        if op == 1.0 and k == 0.5:
            dec = DecodedFrames(gs, [[x.extras[:, 0] for x in r] for r in gs], clip.frame_times, rig, clip.ego_to_world, L, {}, model_width=W)
            tr = render_scene_track(to_scene4d(dec), 0.0, frames=[t]).rgb
            add(f"agg_k{k}", np.mean([psnr(_img(tr[0, v]), _img(s["rgb"][t, v])) for v in range(V)]))
    print(i, {kk: round(vv[-1], 2) for kk, vv in rows.items()}, flush=True)
print("mean", {kk: round(float(np.mean(vv)), 2) for kk, vv in rows.items()})
