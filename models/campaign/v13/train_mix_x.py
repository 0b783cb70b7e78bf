"""v13 experiment: pixel mixes that also read the VAE round trip of the render V = VAE(D) (`make_vae_render.py`).
  y: the 2-way mix (D, E) with |E - V| and |D - V| as extra inputs (where E ~ V the enhancer changed nothing and
     the sharp render is the better source);
  x: a 3-way mix of D, E and the delta candidate clip(D + E - V) (the enhancer's edit applied to the sharp render).
Trains on val clips 6.., selects on val 0-5 at 2 / 4 m, prints test clips 0-5 E-dec - D-dec at 0, +-2, +-4 m.
Usage: python train_mix_x.py CACHE STEPS x|y"""
import copy
import os
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

from worldsplat.training.pairs import split_seeds
from worldsplat.training.pixel_mix import enhanced_path, load_mix_samples

cache, steps, kind = Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
torch.set_num_threads(int(os.environ.get("THREADS", "2")))


def paths(split, start, count, shifts=None):
    seeds = set(split_seeds(split, count, start))
    found = [p for p in sorted((cache / split).glob("seed*_eval.npz"))
             if int(p.name[4:12]) in seeds and enhanced_path(p).exists() and p.with_name(p.stem + "_vaed.npz").exists()]
    if shifts is not None:
        found = [p for p in found if float(p.name.split("_shift")[1][:4]) in shifts]
    return found


def load(ps):
    d = load_mix_samples(ps)
    v = [np.load(p.with_name(p.stem + "_vaed.npz"))["vaed"] for p in ps]
    H, W = v[0].shape[2:4]
    d["vaed"] = torch.from_numpy(np.concatenate([x.reshape(-1, H, W, 3) for x in v])).permute(0, 3, 1, 2).float() / 255
    return d


class Net(nn.Module):
    def __init__(self, out):
        super().__init__()
        c, layers = 19, []
        for dil in (1, 2, 4):
            layers += [nn.Conv2d(c, 24, 3, padding=dil, dilation=dil), nn.ReLU()]
            c = 24
        self.body, self.head = nn.Sequential(*layers), nn.Conv2d(24, out, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def blend(self, d, e, v, a):
        a = a.clamp(0, 1)
        x = torch.cat([d, e, v, (d - e).abs(), (e - v).abs(), (d - v).abs(), a], 1)
        h = self.head(self.body(x))
        if h.shape[1] == 1:
            w = a * torch.sigmoid(h)
            return w * d + (1 - w) * e
        p = torch.softmax(h, 1)
        wd, wx = a * p[:, :1], a * p[:, 2:3]
        return wd * d + wx * (d + e - v).clamp(0, 1) + (1 - wd - wx) * e


def score(net, data, per=24):
    with torch.no_grad():
        out = (net.blend(data["render"], data["refined"], data["vaed"], data["alpha"]) * 255).round()
    err = ((out - data["target"] * 255) ** 2).reshape(-1, per, *out.shape[1:]).mean(dim=(1, 2, 3, 4))
    return float((10 * torch.log10(255.0**2 / err)).mean())


train, select = load(paths("val", 6, 1000)), load(paths("val", 0, 6, (2.0, 4.0)))
print("train images", train["render"].shape[0], flush=True)
torch.manual_seed(0)
rng = np.random.default_rng(0)
net = Net(3 if kind == "x" else 1)
opt = torch.optim.Adam(net.parameters(), lr=2e-3)
sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
best, best_p = copy.deepcopy(net), score(net, select)
n = train["render"].shape[0]
for step in range(1, steps + 1):
    i = torch.from_numpy(rng.choice(n, 16, replace=False))
    out = net.blend(train["render"][i], train["refined"][i], train["vaed"][i], train["alpha"][i])
    loss = ((out - train["target"][i]) ** 2).mean()
    opt.zero_grad()
    loss.backward()
    opt.step()
    sched.step()
    if step % 250 == 0:
        p = score(net, select)
        print(step, round(loss.item(), 5), round(p, 3), flush=True)
        if p > best_p:
            best, best_p = copy.deepcopy(net), p
for shift in (0.0, 2.0, -2.0, 4.0, -4.0):
    tp = paths("test", 0, 6, (shift,))
    data = load(tp)
    per = []
    for j in range(len(tp)):
        sl = {k: v[j * 24:(j + 1) * 24] for k, v in data.items()}
        dd = float(10 * np.log10(1.0 / ((sl["render"] - sl["target"]) ** 2).mean()))
        per.append(round(score(best, sl) - dd, 3))
    print(kind, shift, per, "mean", round(float(np.mean(per)), 3), flush=True)
