"""v13 experiment: the VAE round trip of each mix sample's render (encode, decode with the enhancer's bundled VAE,
as `enhance` reads the render), written beside it as `<sample>_vaed.npz` (key "vaed"): a mix input feature.
Usage: python make_vae_render.py CACHE [ENHANCER.safetensors]"""
import os
import sys
from pathlib import Path

import numpy as np
import torch

from worldsplat.training.pairs import load_sample
from worldsplat_models.enhancer import decode_latents, encode_images, load_enhancer
from worldsplat_models.weights import weights_dir

cache = Path(sys.argv[1])
file = sys.argv[2] if len(sys.argv) > 2 else str(weights_dir() / "enhancer_small.safetensors")
torch.set_num_threads(int(os.environ.get("THREADS", "1")))
_, vae = load_enhancer(file)
for split in ("val", "test"):
    for enh in sorted((cache / split).glob("*_eval_enh.npz")):
        p = enh.with_name(enh.name.replace("_enh.npz", ".npz"))
        out = p.with_name(p.stem + "_vaed.npz")
        if out.exists():
            continue
        s = load_sample(p)
        T, V, H, W, _ = s["render_dec"].shape
        with torch.no_grad():
            z = encode_images(vae, torch.from_numpy(s["render_dec"].reshape(-1, H, W, 3)).float() / 255.0)
            rt = decode_latents(vae, z).reshape(T, V, H, W, 3)
        tmp = out.with_suffix(".tmp.npz")
        np.savez(tmp, vaed=rt)
        os.replace(tmp, out)
        print(out.name, flush=True)
