"""v12: the served enhancer trained on from its weights on many more decoder pairs (`make_dec_pairs.py`).

Warm start from models/weights/enhancer_small.safetensors (same config, same frozen VAE); the pool grows while the
pair generator runs (`--grow` as in session 8); decoder pairs are drawn twice as often as oracle ones (each `_dec`
item is in the degraded pool twice): E-dec is what the playground refines and what the bar measures.
Usage: python train_dec.py PAIRS WORK STEPS LR OUT.safetensors
"""
import sys
import time
from pathlib import Path

import torch

from worldsplat.training.enhancer import complete_seeds, encode_pair, train
from worldsplat.training.pairs import load_sample
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import load_enhancer, save_enhancer
from worldsplat_models.weights import weights_dir

pairs, work, steps, lr, out = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), Path(sys.argv[5])
torch.set_num_threads(int(__import__("os").environ.get("THREADS", "1")))
init = weights_dir() / "enhancer_small.safetensors"
model, vae = load_enhancer(init)
cfg = model.cfg
seen: set[int] = set()


def load_new():
    files = sorted((pairs / "train").glob("seed*.npz"))
    found = sorted({int(f.name[4:12]) for f in files})
    new = [s for s in complete_seeds(pairs, found, True, 1) if s not in seen]
    seen.update(new)
    d, c = [], []
    for f in [f for f in files if int(f.name[4:12]) in new]:
        s = load_sample(f)
        cap = caption_encoder.encode_captions([s["caption"]])[0]
        is_clean = f.name.endswith("_clean.npz")
        item = encode_pair(vae, s, "3d" if is_clean else "4d", cfg.data.max_boxes, cap)
        if is_clean:
            c.append(item)
        else:
            d += [item, item] if f.name.endswith("_dec.npz") else [item]
    print(f"pool +{len(new)} clips -> {len(seen)} clips", flush=True)
    return d, c


t0 = time.time()
degraded, clean = load_new()
model.train()
train(model, degraded, clean, steps, work, "enhancer_v12", lr=lr, seed=12, grow=load_new, grow_every=100)
meta = {
    "provenance": {
        "campaign": "v12",
        "init": "enhancer_small.safetensors (session 8, 4500 steps)",
        "steps": steps,
        "lr": lr,
        "clips": len(seen),
        "pairs": "make_dec_pairs.py: oracle + decoder (_dec, drawn 2x) pairs of every seed, clean every other pair",
        "wall_s": round(time.time() - t0, 1),
    }
}
save_enhancer(model, vae, out, meta)
print("saved", out, flush=True)
