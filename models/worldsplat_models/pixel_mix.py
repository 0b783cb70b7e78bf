"""Pixel mix: the refined novel-track frame as a per-pixel convex mix of the render and the enhancer's output.

The enhancer's output E is a VAE decoding: right in the render's holes and ghosts, but it carries the VAE's blur
(its own-view ceiling is ~26 dB at the model image). The render D of the 4D Gaussians is sharp where it is right and
wrong in holes, behind disocclusions and where the Gaussians disagree. Their errors are only partly correlated, so
a mix beats either alone (measured: `web/docs/refinement.md`, "Figures"). This small convolutional net reads
(D, E, |D - E|, alpha) at the model image and says, per pixel, how much of the render to keep:

    out = w * D + (1 - w) * E,      w = alpha * gate,   gate = sigmoid(net(D, E, |D - E|, alpha))

The alpha factor makes holes (alpha 0) take E by construction; a constant gate of 1 is the "holes" blend, of 0
the paper's form (E everywhere). The last layer starts at zero (w = alpha / 2). At a display size above the model
image the mix is made at the model image and up-sampled, and the render's detail above that band is added back
where the render covers (`mix`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F


@dataclass
class PixelMixConfig:
    width: int = 24  # channels of the hidden layers
    dilations: tuple[int, ...] = (1, 2, 4)  # 3x3 layers; receptive field 1 + 2 * sum(dilations) pixels


class PixelMix(nn.Module):
    IN = 10  # D rgb, E rgb, |D - E| rgb, alpha

    def __init__(self, cfg: PixelMixConfig | None = None):
        super().__init__()
        self.cfg = cfg or PixelMixConfig()
        layers, c = [], self.IN
        for d in self.cfg.dilations:
            layers += [nn.Conv2d(c, self.cfg.width, 3, padding=d, dilation=d), nn.ReLU()]
            c = self.cfg.width
        self.body = nn.Sequential(*layers)
        self.head = nn.Conv2d(c, 1, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, render: torch.Tensor, refined: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """render, refined (N,3,H,W) in [0,1], alpha (N,1,H,W) -> the gate (N,1,H,W) in (0,1); the render's weight
        is alpha * gate."""
        x = torch.cat([render, refined, (render - refined).abs(), alpha.clamp(0, 1)], 1)
        return torch.sigmoid(self.head(self.body(x)))

    def blend(self, render: torch.Tensor, refined: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """The mixed image (N,3,H,W) at one size (training and tests)."""
        w = alpha.clamp(0, 1) * self(render, refined, alpha)
        return w * render + (1 - w) * refined


def _images(x: np.ndarray) -> torch.Tensor:
    """(..., H, W, 3) uint8 -> (N, 3, H, W) float in [0, 1]."""
    H, W = x.shape[-3:-1]
    return torch.from_numpy(np.ascontiguousarray(x)).reshape(-1, H, W, 3).permute(0, 3, 1, 2).float() / 255.0


@torch.no_grad()
def mix_gate(net: PixelMix, render: np.ndarray, refined: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """The gate (..., H, W) float32 in (0, 1) for same-size uint8 frames (..., H, W, 3) and alpha (..., H, W)."""
    if render.shape != refined.shape or render.shape[:-1] != np.shape(alpha):
        raise ValueError(
            f"pixel mix needs same-size frames: render {render.shape}, refined {refined.shape}, alpha {np.shape(alpha)}"
        )
    H, W = render.shape[-3:-1]
    a = torch.from_numpy(np.ascontiguousarray(alpha, np.float32)).reshape(-1, 1, H, W)
    g = net(_images(render), _images(refined), a)
    return g.reshape(np.shape(alpha)).numpy()


def mix(
    net: PixelMix,
    refined: np.ndarray,
    render_low: np.ndarray,
    alpha_low: np.ndarray,
    render: np.ndarray,
    alpha: np.ndarray,
) -> np.ndarray:
    """The mixed frames at the render's size (uint8 (..., H, W, 3)). The mix is made at the model image (refined,
    render_low, alpha_low: (..., h, w)). At a larger size it is up-sampled (bilinear) and the render's own detail
    above the model image's band, render - up(render_low), is added back where the full-size render covers (alpha):
    the model never saw those frequencies, so they come from the render alone, and its edges stay as sharp as the
    render's (the plain up-sampled mix scored 0.05 dB higher at 200x112 and looked visibly softer; refinement.md)."""
    g = mix_gate(net, render_low, refined, alpha_low)
    w = (np.clip(np.asarray(alpha_low, np.float32), 0, 1) * g)[..., None]
    out = w * render_low + (1 - w) * refined.astype(np.float32)
    H, W = render.shape[-3:-1]
    h, wd = refined.shape[-3:-1]
    if (h, wd) != (H, W):

        def up(x: np.ndarray) -> np.ndarray:
            t = torch.from_numpy(np.ascontiguousarray(x, np.float32)).reshape(-1, h, wd, 3).permute(0, 3, 1, 2)
            u = F.interpolate(t, (H, W), mode="bilinear", align_corners=False)
            return u.permute(0, 2, 3, 1).numpy().reshape(*render.shape)

        a = np.clip(np.asarray(alpha, np.float32), 0, 1)[..., None]
        out = up(out) + a * (render.astype(np.float32) - up(render_low))
    return np.clip(np.round(out), 0, 255).astype(np.uint8)
