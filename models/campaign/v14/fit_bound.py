"""How far can the aggregated Gaussians themselves go? Per-scene gradient fit of the window's pixel-aligned
Gaussians (VAE colour and depth, one per pixel, all 4 frames; paper eq. 3 union with hard dynamic masks) to a
target video, then PSNR vs GT at frame 1, 0 m, with the served renderer. A bound for any feed-forward decoder that
places these Gaussians, not a product path (reconstruct stays one feed-forward pass).

usage: python models/campaign/v14/fit_bound.py DATA CLIP STEPS TARGET [SAVE.pt]   (TARGET: vae | gt)
env FIT=col,op,scale,pos (default all): the parameter groups fitted
"""

import os
import sys
import time

import numpy as np
import torch

from worldsplat.core.metrics import psnr
from worldsplat.evaluation.models import _img, clip_view, rig_of
from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.raster import rasterize
from worldsplat.pipeline.inference import encode_clip, load_models, pixel_guide
from worldsplat.training.data import ShardDataset
from worldsplat.training.loop import cull_to_camera
from worldsplat_models.vae import denormalize_depth

torch.set_num_threads(2)
data, ci, steps, target = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
ds = ShardDataset(data, "test")
m = load_models("models/weights")
s = ds[ci]
clip = clip_view(s, rig_of(s))
with torch.no_grad():
    L = encode_clip(m, clip.rgb, clip.depth, clip.dynamic)
    g = pixel_guide(m, L)
T, V, _, H, W = g.shape
vcol = ((g[:, :, 0:3] + 1) / 2).clamp(0, 1).permute(0, 1, 3, 4, 2)
vdep = denormalize_depth(g[:, :, 3], m.data.depth_near, m.data.depth_far).double().numpy()
vdyn = g[:, :, 4].numpy() > 0.5
means, fps, frame, dyn = [], [], [], []
for t in range(T):
    for v in range(V):
        cam = clip.camera(t, v)
        o, d = cam.pixel_rays()
        z = np.minimum(vdep[t, v], m.data.depth_far)
        means.append((o[None, None] + z[..., None] * d).reshape(-1, 3))
        fps.append(z.reshape(-1) / cam.fx)
        frame.append(np.full(H * W, t))
        dyn.append(vdyn[t, v].reshape(-1))
means = torch.tensor(np.concatenate(means), dtype=torch.float32)
fp = torch.tensor(np.concatenate(fps), dtype=torch.float32)
frame = torch.tensor(np.concatenate(frame))
dyn = torch.tensor(np.concatenate(dyn))
N = len(means)
p_off = torch.zeros(N, 3, requires_grad=True)
p_ls = torch.zeros(N, 3, requires_grad=True)  # log scale relative to 0.3 footprint
p_col = torch.logit(vcol.reshape(-1, 3).clamp(0.01, 0.99)).clone().requires_grad_(True)
p_op = torch.full((N,), 4.0, requires_grad=True)
q = torch.zeros(N, 4)
q[:, 0] = 1
tgt = vcol if target == "vae" else torch.as_tensor(s["rgb"]).float() / 255
groups = {"col": (p_col, 0.05), "op": (p_op, 0.1), "scale": (p_ls, 0.02), "pos": (p_off, 0.002)}
fit = os.environ.get("FIT", "col,op,scale,pos").split(",")
opt = torch.optim.Adam([{"params": [groups[k][0]], "lr": groups[k][1]} for k in fit])


def scene(t):
    keep = ~dyn | (frame == t)
    sc = (0.3 * fp)[:, None] * torch.exp(p_ls)
    off = p_off * fp[:, None] * 10  # offsets in units of 0.1 footprint per unit
    return Gaussians((means + off)[keep], q[keep], sc[keep], torch.sigmoid(p_op)[keep], torch.sigmoid(p_col)[keep])


def evaluate():
    with torch.no_grad():
        gs = scene(1)
        out = []
        for v in range(V):
            r = rasterize(cull_to_camera(gs, clip.camera(1, v)), clip.camera(1, v))["rgb"].clamp(0, 1)
            out.append(psnr(_img((r * 255).round().byte().numpy()), _img(s["rgb"][1, v])))
        return float(np.mean(out))


t0 = time.time()
print(f"clip {ci} N {N} step 0 psnr_gt_frame1 {evaluate():.2f}", flush=True)
gen = torch.Generator().manual_seed(0)
for it in range(1, steps + 1):
    t = int(torch.randint(0, T, (1,), generator=gen))
    vs = torch.randperm(V, generator=gen)[:2].tolist()
    gs = scene(t)
    loss = 0.0
    for v in vs:
        cam = clip.camera(t, v)
        r = rasterize(cull_to_camera(gs, cam), cam)["rgb"]
        loss = loss + (r - tgt[t, v]).abs().mean()
    opt.zero_grad()
    loss.backward()
    opt.step()
    if it % 50 == 0 or it == steps:
        print(
            f"clip {ci} step {it} loss {float(loss.detach()) / 2:.4f} psnr_gt_frame1 {evaluate():.2f} ({time.time() - t0:.0f} s)",
            flush=True,
        )

if len(sys.argv) > 5:
    torch.save(
        {
            "frame": frame,
            "dyn": dyn,
            "fp": fp,
            "vcol": vcol.reshape(-1, 3),
            "off": p_off.detach(),
            "ls": p_ls.detach(),
            "col": torch.sigmoid(p_col.detach()),
            "op": torch.sigmoid(p_op.detach()),
        },
        sys.argv[5],
    )
