import sys, dataclasses, numpy as np, torch
from worldsplat.evaluation.models import clip_view, rig_of, _img
from worldsplat.core.metrics import psnr
from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.aggregate import Economy
from worldsplat.pipeline.inference import load_models, reconstruct, to_scene4d, encode_clip, pixel_guide, DecodedFrames
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset
from worldsplat.pipeline.conditions import rig_tensors
from worldsplat_models.gs_decoder import pixel_rays
from worldsplat_models.vae import denormalize_depth
torch.set_num_threads(2); torch.set_grad_enabled(False)
ds = ShardDataset("/work/campaign/v9/data", "test")
W = sys.argv[1]; shifts = [0.0, 2.0]
m = load_models(W)
rows = {}
def add(k, v): rows.setdefault(k, []).append(v)
def opa(dec, o):
    gs = [[Gaussians(g.means, g.quats, g.scales, torch.full_like(g.opacities, o), g.colors, g.extras) for g in r] for r in dec.gaussians]
    return dataclasses.replace(dec, gaussians=gs)
def guide_dec(clip, rig, k):
    L = encode_clip(m, clip.rgb, clip.depth, clip.dynamic); g = pixel_guide(m, L); H, Wd = g.shape[-2:]
    T, V = g.shape[:2]
    intr, c2w = rig_tensors(rig, clip.ego_to_world, (H, Wd)); o, d = pixel_rays(intr, c2w, (H, Wd), (H, Wd))
    gs = [[None] * V for _ in range(T)]
    for tt in range(T):
        for v in range(V):
            dep = denormalize_depth(g[tt, v, 3], m.data.depth_near, m.data.depth_far).reshape(-1)
            means = o[tt, v].reshape(1, 3) + dep[:, None] * d[tt, v].reshape(-1, 3)
            sc = (dep / float(intr[tt, v, 0]) * k)[:, None].expand(-1, 3).contiguous()
            q = torch.zeros(len(dep), 4); q[:, 0] = 1
            gs[tt][v] = Gaussians(means, q, sc, torch.ones(len(dep)), ((g[tt, v, 0:3] + 1) / 2).clamp(0, 1).reshape(3, -1).T, g[tt, v, 4].reshape(-1, 1).clamp(0, 1))
    return DecodedFrames(gs, [[x.extras[:, 0] for x in r] for r in gs], clip.frame_times, rig, clip.ego_to_world, L, {}, model_width=Wd)
for i in range(3):
    s = ds[i]; rig = rig_of(s); clip = clip_view(s, rig); t = 1; V = 6
    gt = {0.0: s} | {float(x["shift_m"]): x for x in ds.shifted(i)}
    dec = reconstruct(clip, m)
    eco = Economy.for_decoded(1.0)
    cands = {"dec": dec, "dec_o1": opa(dec, 1.0)}
    if len(sys.argv) > 2:
        cands = {"guide_k0.3": guide_dec(clip, rig, 0.3), "guide_k0.5": guide_dec(clip, rig, 0.5)}
    for name, dd in cands.items():
        for fuse in (False, True):
            sc = to_scene4d(dd, economy=dataclasses.replace(eco, fuse=fuse))
            for sh in shifts:
                tr = render_scene_track(sc, sh, frames=[t]).rgb
                add(f"{name}{'_fuse' if fuse else ''}@{sh:g}", np.mean([psnr(_img(tr[0, v]), _img(gt[sh]["rgb"][t, v])) for v in range(V)]))
            add(f"{name}{'_fuse' if fuse else ''}#static", len(sc.static))
    print(i, {k: round(float(v[-1]), 2) for k, v in rows.items()}, flush=True)
print("mean", {k: round(float(np.mean(v)), 2) for k, v in rows.items()})
