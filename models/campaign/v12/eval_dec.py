"""v12: E-dec vs D-dec (the refinement bar) for one or more enhancer files on the same held-out samples.

The samples are `evaluation.nvs.prepare_samples`'s (the served decoder's reconstruction rendered on the shifted
track; cached), scored as `worldsplat eval nvs` scores E-dec and D-dec (all pixels of every camera and frame).
The served blend (`+holes`: the output only in the render's holes) is scored too.
Usage: python eval_dec.py CACHE COUNT SHIFTS ENHANCER.safetensors [...]   (prints per clip and the mean)
"""
import json
import sys
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.metrics import psnr
from worldsplat.evaluation.nvs import prepare_samples
from worldsplat.pipeline.inference import load_models
from worldsplat.training.pairs import load_sample, split_seeds
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import enhance, load_enhancer

cache, count = Path(sys.argv[1]), int(sys.argv[2])
shifts = tuple(float(s) for s in sys.argv[3].split(","))
files = sys.argv[4:]
torch.set_num_threads(int(__import__("os").environ.get("THREADS", "1")))
models = load_models(None)
enh = {f: load_enhancer(f) for f in files}
rows = {f: {s: [] for s in shifts} for f in ["D-dec"] + files + [f + "+holes" for f in files]}
for seed in split_seeds("test", count):
    for s, path in zip(shifts, prepare_samples(cache, "test", seed, shifts, models)):
        sample = load_sample(path)
        cap = caption_encoder.encode_captions([sample["caption"]])[0]
        T, V, H, W, _ = sample["target"].shape
        gt = sample["target"].reshape(-1, H, W, 3)
        rd, ad = sample["render_dec"], sample["alpha_dec"].astype(np.float32)
        rows["D-dec"][s].append(psnr(rd.reshape(-1, H, W, 3), gt))
        for f, (m, vae) in enh.items():
            out = enhance(m, vae, rd, ad, sketch=sample["sketch"], boxes=sample, traj=sample["traj"],
                          caption_emb=cap, steps=1, seed=seed)
            rows[f][s].append(psnr(out.reshape(-1, H, W, 3), gt))
            a = np.clip(ad, 0, 1)[..., None]  # the served blend: the model's output only in the render's holes
            held = np.round(a * rd + (1 - a) * out).astype(np.uint8)
            rows[f + "+holes"][s].append(psnr(held.reshape(-1, H, W, 3), gt))
        print(seed, s, {k: round(v[s][-1], 3) for k, v in rows.items()}, flush=True)
res = {k: {str(s): float(np.mean(v[s])) for s in shifts} for k, v in rows.items()}
for f in files + [f + "+holes" for f in files]:
    print(f, "E-dec - D-dec:", {s: round(res[f][s] - res["D-dec"][s], 3) for s in res[f]},
          "first 2 clips:", {str(s): round(float(np.mean(rows[f][s][:2]) - np.mean(rows["D-dec"][s][:2])), 3) for s in shifts})
print(json.dumps(res))
