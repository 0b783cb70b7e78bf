"""v13: per test clip E-dec - D-dec of a pixel mix file (as train_mix.py scores it), to see the spread.
Usage: python per_clip.py CACHE MIX.safetensors [COUNT]"""
import json
import sys
from pathlib import Path

import numpy as np
import torch
from safetensors import safe_open

from worldsplat.training.pairs import split_seeds
from worldsplat.training.pixel_mix import enhanced_path, load_mix_samples, mean_psnr
from worldsplat_models.pixel_mix import PixelMix, PixelMixConfig

cache, mix_file = Path(sys.argv[1]), sys.argv[2]
count = int(sys.argv[3]) if len(sys.argv) > 3 else 6
with safe_open(mix_file, framework="pt") as f:
    cfg = json.loads(f.metadata()["config"])
    net = PixelMix(PixelMixConfig(**{**cfg, "dilations": tuple(cfg["dilations"])}))
    net.load_state_dict({k: f.get_tensor(k) for k in f.keys()})
net.eval()
rows, others = {}, {}
for seed in split_seeds("test", count):
    for shift in (0.0, 2.0, -2.0, 4.0, -4.0):
        p = cache / "test" / f"seed{seed:08d}_shift{shift:+.1f}_eval.npz"
        if not enhanced_path(p).exists():
            continue
        d = load_mix_samples([p])
        out = d["render"] * 255
        ddec = float(10 * np.log10(255.0**2 / ((out.round() - d["target"] * 255) ** 2).mean()))
        rows.setdefault(shift, []).append(round(mean_psnr(net, d) - ddec, 3))
        a = d["alpha"].clamp(0, 1)  # the v12 served blend (holes) and the full output, for comparison
        for name, w in (("holes", a), ("full", torch.zeros_like(a))):
            out = ((w * d["render"] + (1 - w) * d["refined"]) * 255).round()
            p = float(10 * torch.log10(255.0**2 / ((out - d["target"] * 255) ** 2).mean()))
            others.setdefault((name, shift), []).append(p - ddec)
for s, g in rows.items():
    print(s, g, "mean", round(float(np.mean(g)), 3), "clips 0-1", round(float(np.mean(g[:2])), 3),
          "| holes", round(float(np.mean(others["holes", s])), 3), "full", round(float(np.mean(others["full", s])), 3))
