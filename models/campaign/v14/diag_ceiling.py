"""Reconstruct's ceilings under the served renderer: per-pixel opaque Gaussians from GT or VAE colour and depth,
own view vs the aggregated 4D scene, and a non-learned cross-frame depth fusion. Test clips 0-2, frame 1, 0 m.

usage: python models/campaign/v14/diag_ceiling.py DATA [CLIPS]
"""

import sys

import numpy as np
import torch

from worldsplat.core.metrics import psnr
from worldsplat.evaluation.models import _img, clip_view, rig_of
from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.aggregate import Economy
from worldsplat.gaussians.raster import render_view
from worldsplat.pipeline.inference import DecodedFrames, encode_clip, load_models, pixel_guide, to_scene4d
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset
from worldsplat_models.vae import denormalize_depth

sys.path.insert(0, "models/campaign/v14")
from surfels import surfel_gaussians  # noqa: E402

torch.set_num_threads(2)
torch.set_grad_enabled(False)
m = load_models("models/weights")
FAR = float(m.data.depth_far)


def points(cam, depth):
    o, d = cam.pixel_rays()
    return (o[None, None] + depth[..., None] * d).reshape(-1, 3)


def build(clip, col, dep, dyn, k=0.3, surfel=False):
    """col (T,V,H,W,3) in [0,1], dep (T,V,H,W) metres, dyn (T,V,H,W) in [0,1] -> DecodedFrames of opaque per-pixel Gaussians."""
    T, V = dep.shape[:2]
    gs = [[None] * V for _ in range(T)]
    for t in range(T):
        for v in range(V):
            cam = clip.camera(t, v)
            z = np.minimum(dep[t, v], FAR)
            if surfel:
                P = points(cam, z).reshape(*z.shape, 3)
                gs[t][v] = surfel_gaussians(P, z / cam.fx, col[t, v], dyn[t, v], k=k)
                continue
            means = torch.as_tensor(points(cam, z), dtype=torch.float32)
            fp = torch.as_tensor(z.reshape(-1) / cam.fx, dtype=torch.float32)
            sc = (fp * k)[:, None].expand(-1, 3).contiguous()
            q = torch.zeros(len(fp), 4)
            q[:, 0] = 1
            c = torch.as_tensor(col[t, v].reshape(-1, 3), dtype=torch.float32)
            pd = torch.as_tensor(dyn[t, v].reshape(-1, 1), dtype=torch.float32)
            gs[t][v] = Gaussians(means, q, sc, torch.ones(len(fp)), c, pd)
    return DecodedFrames(
        gs,
        [[x.extras[:, 0] for x in r] for r in gs],
        clip.frame_times,
        clip.rig,
        clip.ego_to_world,
        None,
        {},
        model_width=dep.shape[3],
    )


def fuse_depth(clip, dep, dyn, tol=0.15, iters=1):
    """Each static pixel's depth -> the mean log depth of every frame-view's static point that lands on it within
    `tol` (log ratio) of its own depth: the copies of one surface agree across frames."""
    T, V, H, W = dep.shape
    out = dep.copy()
    for _ in range(iters):
        src = []
        for t in range(T):
            for v in range(V):
                keep = dyn[t, v].reshape(-1) < 0.5
                src.append(points(clip.camera(t, v), np.minimum(out[t, v], FAR))[keep])
        P = np.concatenate(src)
        new = out.copy()
        for t in range(T):
            for v in range(V):
                cam = clip.camera(t, v)
                uv, z = cam.project(P)
                ok = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
                u, vv, z = uv[ok, 0].astype(int), uv[ok, 1].astype(int), z[ok]
                own = out[t, v][vv, u]
                agree = np.abs(np.log(z / own)) < tol
                idx = vv[agree] * W + u[agree]
                s = np.bincount(idx, np.log(z[agree]), H * W)
                n = np.bincount(idx, None, H * W)
                fused = np.where(n > 0, np.exp(s / np.maximum(n, 1)), out[t, v].reshape(-1)).reshape(H, W)
                stat = dyn[t, v] < 0.5
                new[t, v] = np.where(stat, fused, out[t, v])
        out = new
    return out


rows: dict = {}


def add(k, v):
    rows.setdefault(k, []).append(v)


def score(clip, s, dec, t, tag):
    own = np.mean(
        [psnr(_img(render_view(dec.gaussians[t][v], clip.camera(t, v)).rgb), _img(s["rgb"][t, v])) for v in range(6)]
    )
    add(tag + " own", own)
    for name, eco in (("agg", None), ("agg-noeco", Economy(enabled=False))):
        tr = render_scene_track(to_scene4d(dec, economy=eco), 0.0, frames=[t]).rgb
        add(f"{tag} {name}", np.mean([psnr(_img(tr[0, v]), _img(s["rgb"][t, v])) for v in range(6)]))


def main(data: str, n: int) -> None:
    ds = ShardDataset(data, "test")
    for i in range(n):
        s = ds[i]
        rig = rig_of(s)
        clip = clip_view(s, rig)
        t = 1
        L = encode_clip(m, clip.rgb, clip.depth, clip.dynamic)
        g = pixel_guide(m, L)  # T,V,5,H,W
        vcol = ((g[:, :, 0:3] + 1) / 2).clamp(0, 1).permute(0, 1, 3, 4, 2).numpy()
        vdep = denormalize_depth(g[:, :, 3], m.data.depth_near, m.data.depth_far).numpy().astype(np.float64)
        vdyn = g[:, :, 4].clamp(0, 1).numpy()
        gcol = s["rgb"].astype(np.float32) / 255.0
        gdep = np.asarray(s["depth"], np.float64)
        gdyn = np.asarray(s["dynamic"], np.float32)
        add("vae image", np.mean([psnr(torch.as_tensor(vcol[t, v]), _img(s["rgb"][t, v])) for v in range(6)]))
        add("vae depth absrel<80", float(np.mean(np.abs(vdep - gdep)[gdep < 80] / gdep[gdep < 80])))
        score(clip, s, build(clip, gcol, gdep, gdyn), t, "GTcol GTdep")
        score(clip, s, build(clip, vcol, gdep, vdyn), t, "VAEcol GTdep")
        score(clip, s, build(clip, vcol, vdep, vdyn), t, "VAEcol VAEdep")
        fd = fuse_depth(clip, vdep, vdyn)
        gd80 = gdep < 80
        add("fused depth absrel<80", float(np.mean(np.abs(fd - gdep)[gd80] / gdep[gd80])))
        score(clip, s, build(clip, vcol, fd, vdyn), t, "VAEcol fuseddep")
        print(i, {k: round(v[-1], 3) for k, v in rows.items()}, flush=True)
    print("mean", {k: round(float(np.mean(v)), 3) for k, v in rows.items()})


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 3)
