"""Refinement blends on NVS samples: D-dec, E-dec at velocity scales gamma (full output and the served holes blend),
and the delta blend at gamma 1. Usage: refine_blends.py SHIFTS COUNT GAMMAS SPLIT (e.g. 0,2,4 2 1.0 test)."""
import sys, numpy as np, torch
from pathlib import Path
from worldsplat.evaluation.nvs import load_enhancers, prepare_samples, load_sample, image_metrics, split_seeds
from worldsplat.pipeline.inference import load_models
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import enhance, _resize, encode_images, decode_latents
torch.set_num_threads(2); torch.set_grad_enabled(False)
shifts = [float(x) for x in sys.argv[1].split(",")]
count = int(sys.argv[2])
W = Path("/work/main/models/weights")
models = load_enhancers(W); gen = load_models(W)
import worldsplat_models.enhancer as E
_orig = E.rflow.sample
GAMMAS = [float(x) for x in sys.argv[3].split(",")]
split = sys.argv[4]
model, vae = models["mixed"]
h, w = model.cfg.data.height, model.cfg.data.width
res = {}
for seed in split_seeds(split, count):
    for s, path in zip(shifts, prepare_samples(Path("/work/campaign/v11/nvs_cache"), "test", seed, shifts, gen)):
        smp = load_sample(path)
        cap = caption_encoder.encode_captions([smp["caption"]])[0]
        rd, ad = smp["render_dec"], smp["alpha_dec"].astype(np.float32)
        T, V, H, Wd, _ = rd.shape
        refs = {}
        for g in GAMMAS:
            E.rflow.sample = lambda m, z0, cond, g=g, **kw: _orig(lambda z, s_, c: g * m(z, s_, c), z0, cond, **kw)
            refs[g] = enhance(model, vae, rd, ad, sketch=smp["sketch"], boxes=smp, traj=smp["traj"], caption_emb=cap, steps=1, seed=seed)
        E.rflow.sample = _orig
        ref = refs[1.0]
        # the VAE's own round trip of the render, at the model's size, then to the render's size
        r_small = _resize(torch.as_tensor(rd).float().reshape(-1, H, Wd, 3).permute(0, 3, 1, 2) / 255.0, (h, w), "area")
        base = decode_latents(vae, encode_images(vae, r_small.permute(0, 2, 3, 1))).reshape(T, V, h, w, 3)
        up = lambda x: _resize(torch.as_tensor(x).float().reshape(-1, h, w, 3).permute(0, 3, 1, 2), (H, Wd), "bilinear").permute(0, 2, 3, 1).numpy().reshape(T, V, H, Wd, 3)
        # ref is already at H,W (enhance finishes to the render's size); base needs upsampling
        delta = ref.astype(np.float32) - up(base)
        a = np.clip(ad, 0, 1)[..., None]
        outs = {
            "D-dec": rd,
            "E-dec": ref,
            "E-dec+holes": np.round(a * rd + (1 - a) * ref).astype(np.uint8),
            "E-dec+delta": np.clip(np.round(a * (rd + delta) + (1 - a) * ref), 0, 255).astype(np.uint8),
        }
        for g, x in refs.items():
            outs[f"E-dec g{g}"] = x
            outs[f"E-dec+holes g{g}"] = np.round(a * rd + (1 - a) * x).astype(np.uint8)
        gt = smp["target"].reshape(-1, H, Wd, 3)
        holes = ad.reshape(-1, H, Wd) < 0.5
        for k, x in outs.items():
            res.setdefault(k, {}).setdefault(s, []).append(image_metrics(x.reshape(-1, H, Wd, 3), gt, holes)["psnr"])
        print(seed, s, {k: round(v[s][-1], 2) for k, v in res.items()}, flush=True)
for k, v in res.items():
    print(k, {s: round(float(np.mean(x)), 3) for s, x in v.items()})
for k in [k for k in res if k != "D-dec"]:
    print(k, "- D-dec", {s: round(float(np.mean(res[k][s]) - np.mean(res["D-dec"][s])), 3) for s in shifts})
