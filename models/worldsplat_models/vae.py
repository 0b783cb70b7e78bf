"""Multi-modal VAE (paper §3.2): one convolutional KL-VAE shared by RGB, depth and the dynamic mask.

Each modality is a 3-channel image in [-1, 1] (depth and mask replicated to 3 channels, as the paper does with a
shared pretrained VAE) and is encoded separately; the joint latent is L = concat(L_img, L_depth, L_seg) along
channels. `latent_mean`/`latent_std` (buffers, fitted after training) normalise L to roughly unit variance for the
DiT and the Gaussian decoder.

Depth normalisation (one definition, used by data, decoder and metrics): log depth over [near, far] metres,
    n = 2 * (log d - log near) / (log far - log near) - 1, clamped to [-1, 1]; sky (inf) -> far -> +1.
"""

from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F

from .configs import VAEConfig

LOGVAR_RANGE = (-30.0, 20.0)


def normalize_depth(depth: torch.Tensor, near: float, far: float) -> torch.Tensor:
    """Metric camera-z depth (inf = sky, NaN treated as sky) -> [-1, 1]."""
    d = torch.nan_to_num(depth.float(), nan=far, posinf=far, neginf=near).clamp(near, far)
    return (2.0 * (torch.log(d) - math.log(near)) / (math.log(far) - math.log(near)) - 1.0).clamp(-1.0, 1.0)


def denormalize_depth(n: torch.Tensor, near: float, far: float) -> torch.Tensor:
    n = torch.nan_to_num(n.float(), nan=1.0).clamp(-1.0, 1.0)
    return torch.exp(math.log(near) + (n + 1.0) * 0.5 * (math.log(far) - math.log(near)))


def _groups(c: int) -> int:
    for g in (8, 4, 2, 1):
        if c % g == 0:
            return g
    return 1


class ResBlock(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.norm1 = nn.GroupNorm(_groups(cin), cin)
        self.conv1 = nn.Conv2d(cin, cout, 3, padding=1)
        self.norm2 = nn.GroupNorm(_groups(cout), cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1)
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x):
        h = self.conv1(F.silu(self.norm1(x)))
        h = self.conv2(F.silu(self.norm2(h)))
        return self.skip(x) + h


class Encoder(nn.Module):
    def __init__(self, cfg: VAEConfig):
        super().__init__()
        ch = cfg.channels
        u = cfg.unshuffle
        # space-to-depth first: the full-resolution convolutions dominate the cost on CPU
        self.stem = (
            nn.Sequential(nn.PixelUnshuffle(u), nn.Conv2d(cfg.in_channels * u * u, ch[0], 3, padding=1))
            if u > 1
            else nn.Conv2d(cfg.in_channels, ch[0], 3, padding=1)
        )
        layers = []
        cin = ch[0]
        for c in ch:
            for _ in range(cfg.blocks):
                layers.append(ResBlock(cin, c))
                cin = c
            layers.append(nn.Conv2d(c, c, 3, stride=2, padding=1))
        self.down = nn.Sequential(*layers)
        self.mid = ResBlock(cin, cin)
        self.norm = nn.GroupNorm(_groups(cin), cin)
        self.out = nn.Conv2d(cin, 2 * cfg.latent_channels, 3, padding=1)

    def forward(self, x):
        h = self.mid(self.down(self.stem(x)))
        return self.out(F.silu(self.norm(h)))


class Decoder(nn.Module):
    def __init__(self, cfg: VAEConfig):
        super().__init__()
        ch = tuple(reversed(cfg.channels))
        self.stem = nn.Conv2d(cfg.latent_channels, ch[0], 3, padding=1)
        self.mid = ResBlock(ch[0], ch[0])
        layers = []
        cin = ch[0]
        for c in ch:
            layers += [nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv2d(cin, c, 3, padding=1)]
            layers += [ResBlock(c, c) for _ in range(cfg.blocks)]
            cin = c
        self.up = nn.Sequential(*layers)
        self.norm = nn.GroupNorm(_groups(cin), cin)
        u = cfg.unshuffle
        self.out = (
            nn.Sequential(nn.Conv2d(cin, cfg.in_channels * u * u, 3, padding=1), nn.PixelShuffle(u))
            if u > 1
            else nn.Conv2d(cin, cfg.in_channels, 3, padding=1)
        )

    def forward(self, z):
        h = self.up(self.mid(self.stem(z)))
        return self.out(F.silu(self.norm(h)))


class MultiModalVAE(nn.Module):
    def __init__(self, cfg: VAEConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = Encoder(cfg)
        self.decoder = Decoder(cfg)
        n = cfg.joint_channels
        self.register_buffer("latent_mean", torch.zeros(n))
        self.register_buffer("latent_std", torch.ones(n))

    # --- single modality (B, 3, H, W) in [-1, 1] <-> (B, c, H/8, W/8) -----------------------------------------
    # The convolutions run in channels-last layout: on CPU (oneDNN) encode / decode take 0.64 / 0.69 of their time in
    # the default layout at 112x200 (one thread), agreeing within 1e-5; results come back contiguous.
    def encode_dist(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        self._check_image(x)
        h = self.encoder(x.contiguous(memory_format=torch.channels_last)).contiguous()
        mean, logvar = h.chunk(2, dim=1)
        return mean, logvar.clamp(*LOGVAR_RANGE)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Deterministic encoding (the posterior mean), as used at inference and for the latent datasets."""
        return self.encode_dist(x)[0]

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        return self.decoder(z.contiguous(memory_format=torch.channels_last)).contiguous()

    def forward(self, x: torch.Tensor, generator: torch.Generator | None = None):
        """Training pass: reconstruction, KL term per element."""
        mean, logvar = self.encode_dist(x)
        z = mean + torch.exp(0.5 * logvar) * torch.randn(mean.shape, generator=generator, dtype=mean.dtype)
        recon = self.decode(z)
        kl = 0.5 * torch.mean(mean.float() ** 2 + logvar.float().exp() - 1.0 - logvar.float())
        return recon, kl

    def _check_image(self, x: torch.Tensor) -> None:
        d = self.cfg.downsample
        if x.dim() != 4 or x.shape[1] != self.cfg.in_channels:
            raise ValueError(f"VAE: expected (B, {self.cfg.in_channels}, H, W), got {tuple(x.shape)}")
        if x.shape[2] % d or x.shape[3] % d:
            raise ValueError(f"VAE: image size {x.shape[2]}x{x.shape[3]} must be divisible by {d}")

    # --- joint multi-modal latent L ---------------------------------------------------------------------------
    def encode_joint(self, rgb: torch.Tensor, depth_n: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """rgb (B,3,H,W) in [-1,1], depth_n (B,1,H,W) normalised depth, mask (B,1,H,W) in {0,1}
        -> normalised L (B, 3c, H/8, W/8)."""
        parts = [
            self.encode(rgb),
            self.encode(depth_n.expand(-1, 3, -1, -1)),
            self.encode((mask.float() * 2 - 1).expand(-1, 3, -1, -1)),
        ]
        L = torch.cat(parts, dim=1)
        return (L - self.latent_mean.view(1, -1, 1, 1)) / self.latent_std.view(1, -1, 1, 1)

    def decode_joint(self, L: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalised L -> rgb (B,3,H,W) in [-1,1], normalised depth (B,1,H,W), mask probability (B,1,H,W)."""
        c = self.cfg.latent_channels
        L = L * self.latent_std.view(1, -1, 1, 1) + self.latent_mean.view(1, -1, 1, 1)
        rgb = self.decode(L[:, :c]).clamp(-1, 1)
        depth = self.decode(L[:, c : 2 * c]).mean(1, keepdim=True).clamp(-1, 1)
        mask = ((self.decode(L[:, 2 * c :]).mean(1, keepdim=True) + 1) * 0.5).clamp(0, 1)
        return rgb, depth, mask
