"""Where does reconstruct lose against the VAE? test clips, frame 1, 0 m."""
import sys, numpy as np, torch
from worldsplat.evaluation.models import clip_view, rig_of, _img
from worldsplat.core.metrics import psnr
from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.raster import render_view
from worldsplat.pipeline.inference import load_models, reconstruct, to_scene4d, encode_clip, pixel_guide
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset
from worldsplat.gaussians.aggregate import Economy
torch.set_num_threads(1); torch.set_grad_enabled(False)
W = sys.argv[1]
ds = ShardDataset("/work/campaign/v9/data", "test")
m = load_models(W)
rows = {}
def add(k, v): rows.setdefault(k, []).append(v)
for i in range(3):
    s = ds[i]; rig = rig_of(s); clip = clip_view(s, rig)
    T, V = s["rgb"].shape[:2]; t = 1
    dec = reconstruct(clip, m)
    # VAE decode
    L = dec.latents
    g = pixel_guide(m, L)  # (T,V,5,H,W)
    rgb = ((g[t, :, 0:3] + 1) * 127.5).clamp(0, 255).round().permute(0, 2, 3, 1).numpy().astype(np.uint8)
    import torch.nn.functional as F
    H, Wd = s["rgb"].shape[2:4]
    add("vae", np.mean([psnr(_img(np.asarray(F.interpolate(torch.as_tensor(rgb[v]).permute(2,0,1)[None].float(), size=(H,Wd), mode='bilinear')[0].permute(1,2,0).round().clamp(0,255).byte())), _img(s["rgb"][t, v])) for v in range(V)]))
    sc = to_scene4d(dec)
    tr = render_scene_track(sc, 0.0, frames=[t]).rgb
    add("served", np.mean([psnr(_img(tr[0, v]), _img(s["rgb"][t, v])) for v in range(V)]))
    sc0 = to_scene4d(dec, economy=Economy(enabled=False))
    tr = render_scene_track(sc0, 0.0, frames=[t]).rgb
    add("no_economy", np.mean([psnr(_img(tr[0, v]), _img(s["rgb"][t, v])) for v in range(V)]))
    gf = dec.frame(t)
    add("frame_t_only", np.mean([psnr(_img(render_view(gf, clip.camera(t, v)).rgb), _img(s["rgb"][t, v])) for v in range(V)]))
    add("own_view_only", np.mean([psnr(_img(render_view(dec.gaussians[t][v], clip.camera(t, v)).rgb), _img(s["rgb"][t, v])) for v in range(V)]))
    print(i, {k: round(v[-1], 2) for k, v in rows.items()}, flush=True)
print("mean", {k: round(float(np.mean(v)), 2) for k, v in rows.items()})
