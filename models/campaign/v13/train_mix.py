"""v13: fit the pixel mix on val clips 6.., select on val clips 0-5 (2, 4 m), report on test clips 0-5 (0, 2, 4 m).

Every clip-shift with a cached enhancer output (`make_mix_data.py`) in CACHE is used. Prints per-shift E-dec - D-dec
for the mix, the holes blend (gate 1) and the full output (gate 0), and writes the net to OUT (a safetensors file
with its config and training log in the metadata; `ship_mix.py` bundles it into the enhancer file).
Usage: python train_mix.py CACHE STEPS OUT.safetensors
"""

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

from worldsplat.training.pairs import load_sample, split_seeds
from worldsplat.training.pixel_mix import enhanced_path, load_mix_samples, mean_psnr, train_pixel_mix
from worldsplat_models.weights import write_safetensors

cache, steps, out = Path(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3])
torch.set_num_threads(int(os.environ.get("THREADS", "2")))


def paths(split, start, count, shifts=None):
    seeds = set(split_seeds(split, count, start))
    found = [p for p in sorted((cache / split).glob("seed*_eval.npz"))
             if int(p.name[4:12]) in seeds and enhanced_path(p).exists()]
    if shifts is not None:
        found = [p for p in found if float(p.name.split("_shift")[1][:4]) in shifts]
    return found


train_p, select_p = paths("val", 6, 1000), paths("val", 0, 6, (2.0, 4.0))
print(f"train {len(train_p)} clip-shifts, select {len(select_p)}", flush=True)
t0 = time.time()
train, select = load_mix_samples(train_p), load_mix_samples(select_p)
net, history = train_pixel_mix(train, select, steps=steps)
wall = time.time() - t0


class Const(torch.nn.Module):  # a constant gate: 1 = the holes blend, 0 = the full output
    def __init__(self, g):
        super().__init__()
        self.g = g

    def blend(self, d, e, a):
        w = a.clamp(0, 1) * self.g
        return w * d + (1 - w) * e


report = {}
for shift in (0.0, 2.0, -2.0, 4.0, -4.0):
    tp = paths("test", 0, 6, (shift,))
    if not tp:
        continue
    data = load_mix_samples(tp)
    s = [load_sample(p) for p in tp]
    ddec = float(np.mean([10 * np.log10(255.0**2 / np.mean((x["render_dec"].astype(np.float64) - x["target"]) ** 2)) for x in s]))
    report[shift] = {"clips": len(tp), "D-dec": ddec, "mix": mean_psnr(net, data) - ddec,
                     "holes": mean_psnr(Const(1.0), data) - ddec, "full": mean_psnr(Const(0.0), data) - ddec,
                     "const0.5": mean_psnr(Const(0.5), data) - ddec}
    print(shift, {k: round(v, 3) for k, v in report[shift].items()}, flush=True)
sel = {"mix": mean_psnr(net, select), "holes": mean_psnr(Const(1.0), select), "full": mean_psnr(Const(0.0), select)}
print("select", sel, flush=True)
meta = {"kind": "pixel_mix", "config": json.dumps(dataclasses.asdict(net.cfg)),
        "provenance": json.dumps({"campaign": "v13", "steps": steps, "train_clip_shifts": len(train_p),
                                  "select_clip_shifts": len(select_p), "wall_s": round(wall, 1),
                                  "select_psnr": sel, "test_gain_vs_ddec": report, "history": history})}
write_safetensors({k: v.detach().float().contiguous() for k, v in net.state_dict().items()}, out, meta)
print("saved", out, flush=True)
