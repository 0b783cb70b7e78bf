"""Rectified flow (paper §3.2): the interpolation, the training loss and the Euler sampler, apart from the network.

Convention (the paper's): s in [0, 1], s = 0 is pure noise and s = 1 is data,
    z(s) = (1 - s) * eps + s * x,        the network g(z, s, c) regresses the velocity  x - eps.
Training draws s from a logit-normal (sigmoid of N(0, 1)), then applies the timestep shift.
Sampling integrates dz/ds = g from s = 0 to 1 with N Euler steps on a shifted grid.

Timestep shift (OpenSora v1.2 / SD3 form) acts on the noise level sigma = 1 - s:
    sigma' = r * sigma / (1 + (r - 1) * sigma),  r >= 1 spends more steps at high noise.
All timestep arithmetic is float32 even under autocast (fp16 there produced NaN in OpenSora, PR #523).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

# model(z, s, cond) -> velocity; cond may be None for the unconditional branch of CFG.
VelocityFn = Callable[[torch.Tensor, torch.Tensor, object], torch.Tensor]


def shift_noise_level(sigma: torch.Tensor, shift: float) -> torch.Tensor:
    if not shift > 0:
        raise ValueError(f"timestep shift must be positive, got {shift}")
    sigma = sigma.float()
    return shift * sigma / (1.0 + (shift - 1.0) * sigma)


def interpolate(x: torch.Tensor, eps: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """z(s) = (1 - s) eps + s x, with s broadcast over all but the batch dimension."""
    s = s.float().reshape(-1, *([1] * (x.dim() - 1)))
    return ((1.0 - s) * eps.float() + s * x.float()).to(x.dtype)


def sample_training_s(
    batch: int, shift: float = 1.0, generator: torch.Generator | None = None, device=None
) -> torch.Tensor:
    """Logit-normal s (sigmoid of a standard normal), then the timestep shift on sigma = 1 - s."""
    s = torch.sigmoid(torch.randn(batch, generator=generator, device=device))
    return 1.0 - shift_noise_level(1.0 - s, shift)


def sample_near_source_s(batch: int, generator: torch.Generator | None = None, device=None) -> torch.Tensor:
    """s = u^2 with u uniform: a third of the draws fall in s < 0.1. For a flow that starts from an informative
    source (the enhancer's render bridge) and is sampled in 1-4 steps, the first step at s = 0 carries most of the
    result, and the logit-normal puts almost no mass there (P(s < 0.1) = 1.4 %)."""
    return torch.rand(batch, generator=generator, device=device) ** 2


def training_loss(
    model: VelocityFn,
    x: torch.Tensor,
    cond,
    shift: float = 1.0,
    generator: torch.Generator | None = None,
    eps: torch.Tensor | None = None,
    s: torch.Tensor | None = None,
) -> torch.Tensor:
    """Mean squared error between g(z(s), s, c) and x - eps."""
    if eps is None:
        eps = torch.randn(x.shape, generator=generator, device=x.device, dtype=x.dtype)
    if s is None:
        s = sample_training_s(x.shape[0], shift, generator, x.device)
    z = interpolate(x, eps, s)
    v = model(z, s, cond)
    return torch.mean((v.float() - (x.float() - eps.float())) ** 2)


def sampling_grid(steps: int, shift: float = 1.0) -> torch.Tensor:
    """s_0 = 0 < s_1 < ... < s_N = 1 (float32), uniform in sigma then shifted."""
    if not isinstance(steps, int) or steps < 1:
        raise ValueError(f"sampler steps must be a positive integer, got {steps!r}")
    sigma = torch.linspace(1.0, 0.0, steps + 1, dtype=torch.float32)
    return 1.0 - shift_noise_level(sigma, shift)


@torch.no_grad()
def sample(
    model: VelocityFn,
    noise: torch.Tensor,
    cond,
    steps: int = 8,
    shift: float = 1.0,
    cfg_scale: float = 1.0,
    uncond=None,
    callback: Callable[[int, int], None] | None = None,
) -> torch.Tensor:
    """Euler integration from s = 0 (noise) to s = 1 (data).

    With cfg_scale != 1 the velocity is g_u + cfg_scale * (g_c - g_u), where g_u uses `uncond` (the dropped
    condition the model was trained with)."""
    if not torch.isfinite(noise).all():
        raise ValueError("sampler: the initial noise contains NaN or Inf")
    grid = sampling_grid(steps, shift).to(noise.device)
    z = noise.float()
    for k in range(steps):
        s = grid[k].expand(noise.shape[0])
        v = model(z, s, cond).float()
        if cfg_scale != 1.0:
            v_u = model(z, s, uncond).float()
            v = v_u + cfg_scale * (v - v_u)
        z = z + (grid[k + 1] - grid[k]) * v
        if callback is not None:
            callback(k + 1, steps)
    return z
