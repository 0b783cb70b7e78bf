"""v13: E-dec vs D-dec for the served enhancer under a soft blend of its output and the render.

out = a*m*D + (1 - a*m)*E, where D is the decoder scene's render on the shifted track, a its alpha (coverage), E the
enhancer's full output, m the render's weight where it covers: m = 0 is the paper's form (the model everywhere),
m = 1 the session-12 "holes" blend. The errors of E (a VAE-decoded latent) and D (a splat render) are only partly
correlated, so a convex mix can beat both. m is chosen on one split (val) and reported on another (test).
Samples are `evaluation.nvs.prepare_samples`'s (cached in CACHE), scored as `worldsplat eval nvs` scores them.
Usage: python eval_mix.py CACHE SPLIT COUNT SHIFTS [ENHANCER.safetensors]   (prints JSON: psnr[m][shift] - D-dec)
"""

import json
import os
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
from worldsplat_models.weights import weights_dir

cache, split, count = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3])
shifts = tuple(float(s) for s in sys.argv[4].split(","))
file = sys.argv[5] if len(sys.argv) > 5 else str(weights_dir() / "enhancer_small.safetensors")
torch.set_num_threads(int(os.environ.get("THREADS", "1")))
models = load_models(None)
m_enh, vae = load_enhancer(file)
mixes = [round(0.1 * i, 1) for i in range(11)]
rows = {k: {s: [] for s in shifts} for k in ["D-dec"] + [f"m={m}" for m in mixes]}
for seed in split_seeds(split, count):
    for s, path in zip(shifts, prepare_samples(cache, split, seed, shifts, models)):
        sample = load_sample(path)
        cap = caption_encoder.encode_captions([sample["caption"]])[0]
        T, V, H, W, _ = sample["target"].shape
        gt = sample["target"].reshape(-1, H, W, 3)
        rd = sample["render_dec"].astype(np.float32)
        a = np.clip(sample["alpha_dec"].astype(np.float32), 0, 1)[..., None]
        rows["D-dec"][s].append(psnr(sample["render_dec"].reshape(-1, H, W, 3), gt))
        out = enhance(m_enh, vae, sample["render_dec"], sample["alpha_dec"], sketch=sample["sketch"], boxes=sample,
                      traj=sample["traj"], caption_emb=cap, steps=1, seed=seed).astype(np.float32)
        for m in mixes:
            mixed = np.round(a * m * rd + (1 - a * m) * out).astype(np.uint8)
            rows[f"m={m}"][s].append(psnr(mixed.reshape(-1, H, W, 3), gt))
        print(seed, s, {k: round(v[s][-1], 3) for k, v in rows.items()}, flush=True)
mean = {k: {str(s): float(np.mean(v[s])) for s in shifts} for k, v in rows.items()}
gain = {k: {s: round(mean[k][s] - mean["D-dec"][s], 3) for s in mean[k]} for k in mean if k != "D-dec"}
for k, g in gain.items():
    print(k, g)
print(json.dumps({"split": split, "count": count, "file": file, "mean_psnr": mean, "gain_vs_ddec": gain}))
