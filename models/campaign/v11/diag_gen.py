"""Generate: served aggregated scene vs each frame's own Gaussians, test clips 0-2, frame 1."""
import sys, dataclasses, numpy as np, torch
from PIL import Image
from worldsplat.evaluation.models import clip_view, rig_of, _img, shard_condition_dict
from worldsplat.core.metrics import psnr
from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.aggregate import Economy
from worldsplat.pipeline.inference import load_models, to_scene4d, condition_tensors, sample_latents, decode_generated, pixel_guide
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset
torch.set_num_threads(2); torch.set_grad_enabled(False)
ds = ShardDataset("/work/campaign/v9/data", "test")
m = load_models(sys.argv[1])
rows = {}; ims = []
def add(k, v): rows.setdefault(k, []).append(v)
def opa(g, o): return Gaussians(g.means, g.quats, g.scales, torch.full_like(g.opacities, o), g.colors, g.extras)
for i in range(3):
    s = ds[i]; z = ds.load(i); rig = rig_of(s); clip = clip_view(s, rig); t = 1; V = 6; T = s["rgb"].shape[0]
    ego = s["ego_to_world"].astype(np.float64)
    cond = condition_tensors(m, shard_condition_dict(s, z), ego)
    L = sample_latents(m, cond, steps=8, seed=0)
    dec = decode_generated(m, L, cond, rig, ego, np.arange(T) / 4.0, {})
    g = pixel_guide(m, L)
    vae = ((g[t, :, 0:3] + 1) * 127.5).clamp(0, 255).round().permute(0, 2, 3, 1).numpy().astype(np.uint8)
    add("vae_decode", np.mean([psnr(_img(vae[v]), _img(s["rgb"][t, v])) for v in range(V)]))
    sc = to_scene4d(dec); tr = render_scene_track(sc, 0.0, frames=[t]).rgb
    add("served", np.mean([psnr(_img(tr[0, v]), _img(s["rgb"][t, v])) for v in range(V)]))
    gf = dec.frame(t)
    own = [render_view(gf, clip.camera(t, v)).rgb for v in range(V)]
    add("frame_t", np.mean([psnr(_img(own[v]), _img(s["rgb"][t, v])) for v in range(V)]))
    own1 = [render_view(opa(gf, 1.0), clip.camera(t, v)).rgb for v in range(V)]
    add("frame_t_o1", np.mean([psnr(_img(own1[v]), _img(s["rgb"][t, v])) for v in range(V)]))
    print(i, {k: round(float(v[-1]), 2) for k, v in rows.items()}, flush=True)
    for v in (0, 1, 2):
        ims.append(np.concatenate([s["rgb"][t, v], vae[v], tr[0, v], own[v], own1[v]], 1))
print("mean", {k: round(float(np.mean(v)), 2) for k, v in rows.items()})
im = np.concatenate(ims, 0); Image.fromarray(im).resize((im.shape[1] * 2, im.shape[0] * 2), Image.NEAREST).save(sys.argv[2])
