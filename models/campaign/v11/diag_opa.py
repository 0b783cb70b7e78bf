import sys, numpy as np, torch
from worldsplat.evaluation.models import clip_view, rig_of, _img
from worldsplat.core.metrics import psnr
from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.raster import render_view
from worldsplat.pipeline.inference import load_models, reconstruct, to_scene4d
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset
torch.set_num_threads(1); torch.set_grad_enabled(False)
ds = ShardDataset("/work/campaign/v9/data", "test")
m = load_models(sys.argv[1])
rows = {}
def add(k, v): rows.setdefault(k, []).append(v)
def opa(g, o): return Gaussians(g.means, g.quats, g.scales, torch.full_like(g.opacities, o), g.colors, g.extras)
for i in range(3):
    s = ds[i]; rig = rig_of(s); clip = clip_view(s, rig); t = 1; V = 6
    dec = reconstruct(clip, m)
    print("opacity quantiles", np.quantile(dec.gaussians[t][0].opacities.numpy(), [0.1, 0.5, 0.9]).round(2), "scale/footprint")
    for o in (None, 1.0):
        tag = "" if o is None else "_o1"
        add("own" + tag, np.mean([psnr(_img(render_view(dec.gaussians[t][v] if o is None else opa(dec.gaussians[t][v], o), clip.camera(t, v)).rgb), _img(s["rgb"][t, v])) for v in range(V)]))
        gf = dec.frame(t) if o is None else opa(dec.frame(t), o)
        add("frame" + tag, np.mean([psnr(_img(render_view(gf, clip.camera(t, v)).rgb), _img(s["rgb"][t, v])) for v in range(V)]))
    sc = to_scene4d(dec); tr = render_scene_track(sc, 0.0, frames=[t])
    add("served", np.mean([psnr(_img(tr.rgb[0, v]), _img(s["rgb"][t, v])) for v in range(V)]))
    add("served_alpha_lt09", float((tr.alpha[0] < 0.9).mean()) if hasattr(tr, "alpha") else -1)
    print(i, {k: round(v[-1], 3) for k, v in rows.items()}, flush=True)
print("mean", {k: round(float(np.mean(v)), 3) for k, v in rows.items()})
