"""Image metrics shared by training losses, model cards and reports: PSNR, SSIM, depth AbsRel, mask IoU.

Images are float tensors in [0, 1] with channels last (..., H, W, C) unless noted.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def psnr(a: torch.Tensor, b: torch.Tensor, peak: float = 1.0) -> float:
    mse = float(torch.mean((a.float() - b.float()) ** 2))
    return float("inf") if mse == 0 else 10.0 * math.log10(peak * peak / mse)


def _gauss_window(size: int = 11, sigma: float = 1.5, device=None) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float32, device=device) - (size - 1) / 2
    g = torch.exp(-x ** 2 / (2 * sigma ** 2))
    return g / g.sum()


def ssim_map(a: torch.Tensor, b: torch.Tensor, size: int = 11) -> torch.Tensor:
    """SSIM map of (N, C, H, W) images in [0, 1] with an 11x11 Gaussian window (sigma 1.5), reflect padding."""
    C1, C2 = 0.01 ** 2, 0.03 ** 2
    c = a.shape[1]
    g = _gauss_window(size, device=a.device)
    kx = g.view(1, 1, 1, size).expand(c, 1, 1, size)
    ky = g.view(1, 1, size, 1).expand(c, 1, size, 1)
    pad = size // 2

    def blur(x):
        x = F.pad(x, (pad, pad, pad, pad), mode="reflect")
        return F.conv2d(F.conv2d(x, kx, groups=c), ky, groups=c)

    a, b = a.float(), b.float()
    mu_a, mu_b = blur(a), blur(b)
    saa = blur(a * a) - mu_a ** 2
    sbb = blur(b * b) - mu_b ** 2
    sab = blur(a * b) - mu_a * mu_b
    return ((2 * mu_a * mu_b + C1) * (2 * sab + C2)) / ((mu_a ** 2 + mu_b ** 2 + C1) * (saa + sbb + C2))


def ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of channels-last images (..., H, W, C) in [0, 1] (differentiable)."""
    H, W, C = a.shape[-3:]
    a4 = a.reshape(-1, H, W, C).permute(0, 3, 1, 2)
    b4 = b.reshape(-1, H, W, C).permute(0, 3, 1, 2)
    return ssim_map(a4, b4, size=min(11, (min(H, W) // 2) * 2 - 1)).mean()


def depth_abs_rel(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor | None = None,
                  max_depth: float = 80.0) -> float:
    """mean |pred - gt| / gt over pixels with finite gt below max_depth (sky and the far range excluded)."""
    gt = gt.float()
    ok = torch.isfinite(gt) & (gt > 0) & (gt < max_depth) & torch.isfinite(pred)
    if valid is not None:
        ok &= valid.bool()
    if not bool(ok.any()):
        return float("nan")
    return float(((pred.float() - gt).abs() / gt)[ok].mean())


def mask_iou(pred: torch.Tensor, gt: torch.Tensor) -> float:
    """IoU of two boolean masks; 1.0 when both are empty."""
    p, g = pred.bool(), gt.bool()
    union = int((p | g).sum())
    return 1.0 if union == 0 else int((p & g).sum()) / union
