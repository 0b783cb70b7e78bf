"""Layout prior: the latent a layout implies on average, so the DiT only has to generate what the layout leaves open.

    mu = LayoutPrior(layout (N, 7, H, W), caption (N, 384), view (N,))  ->  (N, C, H/ds, W/ds)

A convolutional U-Net regresses the normalised joint latent L of one camera image from its layout map
(world.layout_maps: drivable, markings, sidewalk, vehicle, vulnerable, heading, layout depth), with the caption
embedding (weather, time of day) and the camera index as FiLM conditioning. Trained with MSE it learns E[L | layout]:
road, markings, boxes and their depth where the layout states them, a plausible average elsewhere.

The DiT (DiTConfig.target = "prior_residual") then runs rectified flow on r = (L - mu) / residual_scale and the
sample is L = mu + residual_scale * r. This is CorrDiff's split (Mardani et al. 2023, regression mean + diffusion
residual): trained from scratch on two CPU cores, DiTs conditioned on the layout alone had not learned to follow it
after 1500 steps (a grey blur), while a regression reads the layout from its first steps, and the residual the flow
has to model is smaller and closer to noise-like texture. A weak DiT then degrades to the conditional mean, not to grey.
"""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from .configs import LayoutPriorConfig
from .vae import _groups  # the GroupNorm group count the VAE's ResBlocks use


class FiLMResBlock(nn.Module):
    """GroupNorm -> FiLM (scale, shift from the conditioning vector) -> SiLU -> 3x3 conv, twice, plus the skip."""

    def __init__(self, cin: int, cout: int, cond_dim: int):
        super().__init__()
        self.norm1 = nn.GroupNorm(_groups(cin), cin)
        self.conv1 = nn.Conv2d(cin, cout, 3, padding=1)
        self.norm2 = nn.GroupNorm(_groups(cout), cout)
        self.film = nn.Linear(cond_dim, 2 * cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1)
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()
        nn.init.zeros_(self.film.weight)  # starts as a plain ResBlock
        nn.init.zeros_(self.film.bias)

    def forward(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        scale, shift = self.film(c)[:, :, None, None].chunk(2, dim=1)
        h = self.conv2(F.silu(self.norm2(h) * (1 + scale) + shift))
        return self.skip(x) + h


class LayoutPrior(nn.Module):
    def __init__(self, cfg: LayoutPriorConfig):
        super().__init__()
        self.cfg = cfg
        w = cfg.widths
        n_down = len(w) - 2  # widths[0] full resolution, widths[-2] the latent grid, widths[-1] one level below it
        if 2**n_down != cfg.downsample:
            raise ValueError(
                f"LayoutPrior: widths {w} give {2**n_down}x down-sampling, the latent is {cfg.downsample}x"
            )
        self.caption = nn.Linear(cfg.caption_dim, cfg.cond_dim)
        self.view = nn.Embedding(cfg.max_views, cfg.cond_dim)
        self.cond = nn.Sequential(nn.SiLU(), nn.Linear(cfg.cond_dim, cfg.cond_dim))
        self.stem = nn.Conv2d(cfg.in_channels, w[0], 3, padding=1)
        self.down = nn.ModuleList(nn.Conv2d(w[i], w[i + 1], 3, stride=2, padding=1) for i in range(n_down))
        self.down_blocks = nn.ModuleList(FiLMResBlock(w[i + 1], w[i + 1], cfg.cond_dim) for i in range(n_down))
        # context one level below the latent grid (sky, facades: what is far from any layout pixel)
        self.to_low = nn.Conv2d(w[-2], w[-1], 3, stride=2, padding=1)
        self.low = nn.ModuleList(FiLMResBlock(w[-1], w[-1], cfg.cond_dim) for _ in range(cfg.blocks))
        self.up = FiLMResBlock(w[-2] + w[-1], w[-2], cfg.cond_dim)
        self.mid = nn.ModuleList(FiLMResBlock(w[-2], w[-2], cfg.cond_dim) for _ in range(cfg.blocks))
        self.norm = nn.GroupNorm(_groups(w[-2]), w[-2])
        self.head = nn.Conv2d(w[-2], cfg.out_channels, 3, padding=1)

    def forward(self, layout: torch.Tensor, caption: torch.Tensor, view: torch.Tensor) -> torch.Tensor:
        """layout (N, Cl, H, W), caption (N, caption_dim), view (N,) camera index -> mu (N, C, H/ds, W/ds)."""
        cfg = self.cfg
        if layout.shape[1] != cfg.in_channels:
            raise ValueError(f"LayoutPrior: expected {cfg.in_channels} layout channels, got {layout.shape[1]}")
        H, W = layout.shape[-2:]
        if H % (2 * cfg.downsample) or W % (2 * cfg.downsample):
            raise ValueError(f"LayoutPrior: layout {H}x{W} not divisible by {2 * cfg.downsample}")
        c = self.cond(self.caption(caption.float()) + self.view(view.long().clamp(0, cfg.max_views - 1)))
        h = F.silu(self.stem(torch.nan_to_num(layout.float())))
        for conv, blk in zip(self.down, self.down_blocks):
            h = blk(conv(h), c)
        low = self.to_low(h)
        for blk in self.low:
            low = blk(low, c)
        h = self.up(torch.cat([h, F.interpolate(low, size=h.shape[-2:], mode="nearest")], 1), c)
        for blk in self.mid:
            h = blk(h, c)
        return self.head(F.silu(self.norm(h)))

    def clip(self, control: torch.Tensor, caption: torch.Tensor) -> torch.Tensor:
        """control (B, T, V, Cl, H, W), caption (B, caption_dim) -> mu (B, T, V, C, h, w), camera index = v."""
        B, T, V = control.shape[:3]
        view = torch.arange(V, device=control.device).repeat(B * T)
        cap = caption[:, None].expand(B, T * V, caption.shape[-1]).reshape(B * T * V, -1)
        mu = self(control.reshape(B * T * V, *control.shape[3:]), cap, view)
        return mu.reshape(B, T, V, *mu.shape[1:])
