"""v13: held-out samples for the pixel mix (`eval_mix.py`'s samples plus the enhancer's full output E beside each).

For clips [START, START+COUNT) of SPLIT: `evaluation.nvs.prepare_samples` (the decoder scene's render on the shifted
track with its alpha and depth, and the exact ground truth there), then the served enhancer's output (1 step, the
clip's seed) written as `<sample>_enh.npz` (key "enh", uint8 T,V,H,W,3). SHIFTS "a,b" for every clip, or "alt":
(+1, -3) on even clips and (-2, +4) on odd ones (the training pairs' range, both sides).
Usage: python make_mix_data.py CACHE SPLIT START COUNT SHIFTS [ENHANCER.safetensors]
"""

import os
import sys
from pathlib import Path

import numpy as np
import torch

from worldsplat.evaluation.nvs import prepare_samples
from worldsplat.pipeline.inference import load_models
from worldsplat.training.pairs import load_sample, split_seeds
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import enhance, load_enhancer
from worldsplat_models.weights import weights_dir

cache, split, start, count, shift_arg = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
file = sys.argv[6] if len(sys.argv) > 6 else str(weights_dir() / "enhancer_small.safetensors")
torch.set_num_threads(int(os.environ.get("THREADS", "1")))
models = load_models(None)
m_enh, vae = load_enhancer(file)
for i, seed in enumerate(split_seeds(split, count, start)):
    if shift_arg == "alt":
        shifts = (1.0, -3.0) if (start + i) % 2 == 0 else (-2.0, 4.0)
    else:
        shifts = tuple(float(s) for s in shift_arg.split(","))
    for s, path in zip(shifts, prepare_samples(cache, split, seed, shifts, models)):
        out = path.with_name(path.stem + "_enh.npz")
        if out.exists():
            continue
        sample = load_sample(path)
        cap = caption_encoder.encode_captions([sample["caption"]])[0]
        enh = enhance(m_enh, vae, sample["render_dec"], sample["alpha_dec"], sketch=sample["sketch"], boxes=sample,
                      traj=sample["traj"], caption_emb=cap, steps=1, seed=seed)
        tmp = out.with_suffix(".tmp.npz")
        np.savez(tmp, enh=enh)
        os.replace(tmp, out)
        print(split, start + i, seed, s, flush=True)
