"""Training of the pixel mix (worldsplat_models.pixel_mix): a plain loop over held-out novel-track samples.

A sample is one clip seen from a shifted track: the decoder scene's render there (D, its alpha), the served
enhancer's full output (E) and the world's exact view (the target); all at the model image. The mix is fitted to
the target by MSE; the best step by a selection set's PSNR is kept (the net is small and the data few).

    samples = load_mix_samples(paths)                    # (D, E, alpha, target) image stacks
    net, log = train_pixel_mix(train, select, steps=3000)

The samples come from splits the enhancer never trained on (val); the refinement bar is reported on test.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import torch

from worldsplat.training.pairs import load_sample
from worldsplat_models.pixel_mix import PixelMix, PixelMixConfig


def enhanced_path(sample: Path) -> Path:
    """Where a sample's enhancer output is cached (beside the sample)."""
    sample = Path(sample)
    return sample.with_name(sample.stem + "_enh.npz")


def load_mix_samples(paths) -> dict[str, torch.Tensor]:
    """Stacks render / refined / target (N,3,H,W) in [0,1] and alpha (N,1,H,W) of every image of the samples."""
    parts: dict[str, list[np.ndarray]] = {"render": [], "refined": [], "alpha": [], "target": []}
    for p in paths:
        s = load_sample(p)
        with np.load(enhanced_path(p)) as f:
            enh = f["enh"]
        H, W = s["target"].shape[-3:-1]
        parts["render"].append(s["render_dec"].reshape(-1, H, W, 3))
        parts["refined"].append(enh.reshape(-1, H, W, 3))
        parts["target"].append(s["target"].reshape(-1, H, W, 3))
        parts["alpha"].append(s["alpha_dec"].astype(np.float32).reshape(-1, H, W, 1))
    out = {}
    for k, v in parts.items():
        x = torch.from_numpy(np.concatenate(v)).permute(0, 3, 1, 2).float()
        out[k] = x if k == "alpha" else x / 255.0
    return out


def mean_psnr(net: PixelMix, data: dict[str, torch.Tensor], per: int = 24) -> float:
    """Mean over groups of `per` images (a clip-shift's frames and cameras, as the refinement bar averages) of the
    PSNR of the mixed images, rounded to uint8 as served."""
    with torch.no_grad():
        out = (net.blend(data["render"], data["refined"], data["alpha"]) * 255).round().clamp(0, 255)
    err = ((out - data["target"] * 255) ** 2).reshape(-1, per, *out.shape[1:]).mean(dim=(1, 2, 3, 4))
    return float((10 * torch.log10(255.0**2 / err.clamp_min(1e-10))).mean())


def train_pixel_mix(
    train: dict[str, torch.Tensor],
    select: dict[str, torch.Tensor],
    steps: int = 3000,
    lr: float = 2e-3,
    batch: int = 16,
    seed: int = 0,
    cfg: PixelMixConfig | None = None,
    every: int = 100,
    log=print,
) -> tuple[PixelMix, list[dict]]:
    """Adam on MSE against the target, random images per step; returns the net of the best selection PSNR and the
    log (step, train loss, selection PSNR)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = PixelMix(cfg)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    n = train["render"].shape[0]
    best, best_psnr, history = copy.deepcopy(net), mean_psnr(net, select), []
    history.append({"step": 0, "select_psnr": best_psnr})
    for step in range(1, steps + 1):
        i = torch.from_numpy(rng.choice(n, batch, replace=False))
        out = net.blend(train["render"][i], train["refined"][i], train["alpha"][i])
        loss = ((out - train["target"][i]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % every == 0 or step == steps:
            p = mean_psnr(net, select)
            history.append({"step": step, "loss": loss.item(), "select_psnr": p})
            log(f"step {step} loss {loss.item():.5f} select {p:.3f} dB")
            if p > best_psnr:
                best, best_psnr = copy.deepcopy(net), p
    return best.eval(), history
