"""Image metrics, one definition each, shared by training losses, model cards, evaluation, bench and reports: PSNR,
SSIM, depth AbsRel, mask IoU, and `image_metrics` (PSNR + SSIM + PSNR inside holes).

Images are channels last (..., H, W, C): float in [0, 1] (torch or numpy) or uint8 (scaled by 1/255).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F


def _unit(x) -> np.ndarray:
    """An image as float64 numpy in [0, 1] units (uint8 scaled by 1/255)."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu()
        return x.numpy().astype(np.float64) / (255.0 if x.dtype == torch.uint8 else 1.0)
    x = np.asarray(x)
    return x.astype(np.float64) / (255.0 if x.dtype == np.uint8 else 1.0)


def psnr(a, b, mask=None, peak: float = 1.0) -> float:
    """PSNR in dB of two images (float in [0, 1] or uint8); `mask` (..., H, W) bool selects the pixels scored
    (an empty selection scores inf, like identical images)."""
    d = (_unit(a) - _unit(b)) ** 2
    if mask is not None:
        d = d[np.asarray(mask.cpu() if isinstance(mask, torch.Tensor) else mask, bool)]
    return psnr_from_mse(float(d.mean()) if d.size else 0.0, peak)


def psnr_from_mse(mse: float, peak: float = 1.0) -> float:
    """PSNR in dB of a mean squared error (in units of `peak`); a pooled PSNR is this of the pooled squared errors."""
    return float("inf") if mse == 0 else 10.0 * math.log10(peak * peak / mse)


def _gauss_window(size: int = 11, sigma: float = 1.5, device=None) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float32, device=device) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def ssim_map(a: torch.Tensor, b: torch.Tensor, size: int = 11) -> torch.Tensor:
    """SSIM map of (N, C, H, W) images in [0, 1] with an 11x11 Gaussian window (sigma 1.5), reflect padding."""
    C1, C2 = 0.01**2, 0.03**2
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
    saa = blur(a * a) - mu_a**2
    sbb = blur(b * b) - mu_b**2
    sab = blur(a * b) - mu_a * mu_b
    return ((2 * mu_a * mu_b + C1) * (2 * sab + C2)) / ((mu_a**2 + mu_b**2 + C1) * (saa + sbb + C2))


def ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of channels-last images (..., H, W, C) in [0, 1] (differentiable)."""
    H, W, C = a.shape[-3:]
    a4 = a.reshape(-1, H, W, C).permute(0, 3, 1, 2)
    b4 = b.reshape(-1, H, W, C).permute(0, 3, 1, 2)
    return ssim_map(a4, b4, size=min(11, (min(H, W) // 2) * 2 - 1)).mean()


def depth_abs_rel(pred, gt, valid=None, max_depth: float = 80.0, min_depth: float = 0.0) -> float:
    """mean |pred - gt| / gt over pixels with finite gt in (min_depth, max_depth) (sky and the far range excluded);
    torch or numpy depths in metres."""
    pred, gt = (
        torch.as_tensor(np.asarray(pred) if not isinstance(pred, torch.Tensor) else pred),
        torch.as_tensor(np.asarray(gt) if not isinstance(gt, torch.Tensor) else gt),
    )
    gt = gt.float()
    ok = torch.isfinite(gt) & (gt > max(min_depth, 0.0)) & (gt < max_depth) & torch.isfinite(pred)
    if valid is not None:
        ok &= valid.bool()
    if not bool(ok.any()):
        return float("nan")
    return float(((pred.float() - gt).abs() / gt)[ok].mean())


def iou_counts(pred: torch.Tensor, gt: torch.Tensor) -> tuple[int, int]:
    """(intersection, union) pixel counts of two boolean masks (for an IoU pooled over many, `pooled_iou`)."""
    p, g = pred.bool(), gt.bool()
    return int((p & g).sum()), int((p | g).sum())


def mask_iou(pred: torch.Tensor, gt: torch.Tensor) -> float:
    """IoU of two boolean masks; 1.0 when both are empty."""
    return pooled_iou([iou_counts(pred, gt)])


def pooled_iou(counts: list[tuple[int, int]], empty: float = 1.0) -> float:
    """IoU pooled over many mask pairs: total intersection / total union of their `iou_counts`; `empty` when every
    union is empty (1.0: two empty masks agree; evaluation reports nan: nothing was scored)."""
    union = sum(u for _, u in counts)
    return empty if union == 0 else sum(i for i, _ in counts) / union


def image_metrics(pred, gt, holes=None) -> dict:
    """pred, gt (N,H,W,3) uint8 -> PSNR (dB, over all pixels), SSIM, and PSNR inside `holes` (N,H,W) bool
    (with the holes' fraction)."""
    p = torch.from_numpy(np.asarray(pred)).float() / 255
    g = torch.from_numpy(np.asarray(gt)).float() / 255
    out = {"psnr": psnr(p, g), "ssim": float(ssim(p, g))}
    if holes is not None:
        h = np.asarray(holes, bool)
        out["hole_frac"] = float(h.mean())
        out["psnr_holes"] = psnr(p, g, h) if bool(h.any()) else float("nan")
    return out
