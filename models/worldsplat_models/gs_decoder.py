"""Latent Gaussian decoder (paper §3.3): multi-modal latent L + Plucker ray map -> pixel-aligned 3D Gaussians.

Tokens on the latent grid (one per latent pixel, L concatenated with the Plucker rays of that pixel) pass through
blocks of cross-view spatial attention (all views of a frame), temporal attention (all frames of a view/position)
and an MLP; then up-sampling conv blocks (each re-reads the Plucker rays at its resolution) lead to one Gaussian
per pixel of a grid at image/`gaussian_stride` resolution, with bounded, documented activations:

| output | activation | bound |
|---|---|---|
| depth d | exp(log near + sigmoid(x) (log far - log near)) | [near, far] = [0.5, 80] m |
| offset | max_offset * tanh(x) | |offset_i| < 0.5 m |
| scale | clamp(footprint(d) * (a + (b - a) sigmoid(x)), scale_min, scale_max) | [1e-3, 3] m; footprint = d / f_grid |
| rotation | q = x + (1, 0, 0, 0), q / max(norm q, 1e-6), predicted in the camera frame then rotated to world | unit |
| opacity | sigmoid(x + 2) | (0, 1) |
| colour | sigmoid(x) | (0, 1) |
| dynamic logit | clamp(x, -15, 15) | |
Non-finite raw outputs are zeroed before activation. Mean = ray origin + d * ray direction (unit camera z, so d is
camera-z depth as in the world's depth maps) + offset.
"""

from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F

from .configs import GSDecoderConfig
from .dit import Attention, sincos_2d
from .geometry import matrix_to_quaternion, pixel_rays, plucker, quaternion_multiply
from .vae import ResBlock

HEAD_CHANNELS = {"offset": 3, "quat": 4, "scale": 3, "opacity": 1, "color": 3, "depth": 1, "dynamic": 1}


def safe_normalize_quaternion(q: torch.Tensor) -> torch.Tensor:
    """The rotation head's activation: bias towards identity then normalise; a zero or non-finite input becomes the
    identity rotation. (Not `geometry.normalize_quaternion`: that one rounds differently, and the shipped weights'
    outputs and the exported ONNX graph are this function's.)"""
    q = torch.nan_to_num(q.float(), nan=0.0, posinf=0.0, neginf=0.0)
    q = q + torch.tensor([1.0, 0.0, 0.0, 0.0], device=q.device)
    n = q.norm(dim=-1, keepdim=True)
    ident = torch.tensor([1.0, 0.0, 0.0, 0.0], device=q.device).expand_as(q)
    return torch.where(n > 1e-6, q / n.clamp_min(1e-6), ident)


def _resize(x: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Area-resample a pixel guide to a grid (identity at equal size)."""
    if x.shape[-2:] == (h, w):
        return x
    return F.adaptive_avg_pool2d(x, (h, w)) if x.shape[-2] > h else F.interpolate(x, size=(h, w), mode="nearest")


def _bilinear(x: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Bilinearly resample a pixel guide to a finer grid (the refined head's prior)."""
    return F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)


def _guide_prior(g: torch.Tensor, channels: int) -> torch.Tensor:
    """Raw-head base from the pixel guide: the colour, depth and dynamic pre-activations that reproduce the
    VAE-decoded rgb, depth and mask exactly, so the heads learn residuals (zeros elsewhere)."""
    prior = torch.zeros(g.shape[0], channels, *g.shape[-2:], dtype=g.dtype, device=g.device)
    names, sizes = list(HEAD_CHANNELS), list(HEAD_CHANNELS.values())
    start = {n: sum(sizes[:i]) for i, n in enumerate(names)}
    rgb01 = ((g[:, 0:3] + 1) * 0.5).clamp(0.01, 0.99)
    d01 = ((g[:, 3:4] + 1) * 0.5).clamp(0.005, 0.995)
    m01 = g[:, 4:5].clamp(0.02, 0.98)
    c0, d0, k0 = start["color"], start["depth"], start["dynamic"]
    prior[:, c0 : c0 + 3] = torch.log(rgb01 / (1 - rgb01))
    prior[:, d0 : d0 + 1] = torch.log(d01 / (1 - d01))
    prior[:, k0 : k0 + 1] = torch.log(m01 / (1 - m01))
    return prior


class Block(nn.Module):
    """Pre-LN cross-view spatial attention, temporal attention and MLP."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.norm_s, self.spatial = nn.LayerNorm(dim), Attention(dim, heads)
        self.norm_t, self.temporal = nn.LayerNorm(dim), Attention(dim, heads)
        hidden = int(dim * mlp_ratio)
        self.norm_m = nn.LayerNorm(dim)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(approximate="tanh"), nn.Linear(hidden, dim))

    def forward(self, x: torch.Tensor, T: int) -> torch.Tensor:
        B, _, VS, D = x.shape
        x = x + self.spatial(self.norm_s(x).reshape(B * T, VS, D)).reshape(B, T, VS, D)
        h = self.norm_t(x).transpose(1, 2).reshape(B * VS, T, D)
        x = x + self.temporal(h).reshape(B, VS, T, D).transpose(1, 2)
        return x + self.mlp(self.norm_m(x))


class GaussianDecoder(nn.Module):
    def __init__(self, cfg: GSDecoderConfig):
        super().__init__()
        self.cfg = cfg
        D = cfg.dim
        p = cfg.patch
        self.embed = nn.Linear((cfg.in_channels + 6) * p * p, D)
        self.view_embed = nn.Parameter(torch.zeros(cfg.max_views, D))
        self.frame_embed = nn.Parameter(torch.zeros(cfg.max_frames, D))
        nn.init.normal_(self.view_embed, std=0.02)
        nn.init.normal_(self.frame_embed, std=0.02)
        self.blocks = nn.ModuleList(Block(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.depth))
        self.norm = nn.LayerNorm(D)
        ups = []
        cin = D
        extra = 6 + cfg.guide_channels + (cfg.in_channels if cfg.reread_latent else 0)
        for c in cfg.up_channels:
            ups.append(nn.ModuleDict({"conv": nn.Conv2d(cin + extra, c, 3, padding=1), "res": ResBlock(c, c)}))
            cin = c
        self.ups = nn.ModuleList(ups)
        self.head = nn.Conv2d(cin, sum(HEAD_CHANNELS.values()), 3, padding=1)
        nn.init.normal_(self.head.weight, std=1e-3)
        nn.init.zeros_(self.head.bias)

    @torch.no_grad()
    def pass_through_up(self, i: int) -> None:
        """Make up-sampling block i pass its input features through (nearest-upsampled): a decoder grown by a block
        from a trained one starts as that decoder on the finer grid, where its pixel-guide prior is per pixel."""
        up = self.ups[i]
        conv, res = up["conv"], up["res"]
        c_in = self.cfg.dim if i == 0 else self.cfg.up_channels[i - 1]  # the features come first in the concat
        if conv.out_channels != c_in:
            raise ValueError(f"pass_through_up: block {i} maps {c_in} feature channels to {conv.out_channels}")
        conv.weight.zero_()
        conv.bias.zero_()
        conv.weight[torch.arange(c_in), torch.arange(c_in), 1, 1] = 1.0
        res.conv2.weight.zero_()  # ResBlock(c, c) = x + branch(x): a zero last conv makes it the identity
        res.conv2.bias.zero_()

    def forward(
        self,
        L: torch.Tensor,
        intrinsics: torch.Tensor,
        cam_to_world: torch.Tensor,
        image_hw: tuple[int, int],
        guide: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """L (B,T,V,C,h,w) normalised latents; intrinsics (B,T,V,4) fx,fy,cx,cy of the image_hw image;
        cam_to_world (B,T,V,4,4); guide (B,T,V,5,H',W') the VAE-decoded rgb [-1,1], normalised depth [-1,1] and
        mask [0,1] when `guide_channels` = 5 -> Gaussian fields, each (B,T,V,gh,gw,k) (k dropped when 1), in
        world metres (`refine_fields`: the same on a finer grid)."""
        cfg = self.cfg
        B, T, V, C, h, w = L.shape
        if cfg.guide_channels and (guide is None or guide.shape[3] != cfg.guide_channels):
            raise ValueError(f"Gaussian decoder: expects a pixel guide of {cfg.guide_channels} channels")
        p = cfg.patch
        if h % p or w % p:
            raise ValueError(f"Gaussian decoder: latent size {h}x{w} not divisible by patch {p}")
        if C != cfg.in_channels:
            raise ValueError(f"Gaussian decoder: expected {cfg.in_channels} latent channels, got {C}")
        if V > cfg.max_views or T > cfg.max_frames:
            raise ValueError(f"Gaussian decoder: {V} views x {T} frames exceeds max {cfg.max_views} x {cfg.max_frames}")
        D = cfg.dim
        o, d = pixel_rays(intrinsics, cam_to_world, image_hw, (h, w))
        rays = plucker(o, d, cfg.ray_scale).to(L.dtype)  # (B,T,V,6,h,w)
        hp, wp = h // p, w // p
        x = torch.cat([L, rays], dim=3).reshape(B, T, V, C + 6, hp, p, wp, p)
        x = x.permute(0, 1, 2, 4, 6, 3, 5, 7).reshape(B, T, V, hp, wp, (C + 6) * p * p)
        pos = (
            sincos_2d(hp, wp, D, L.device).reshape(1, 1, 1, hp, wp, D)
            + self.view_embed[:V].reshape(1, 1, V, 1, 1, D)
            + self.frame_embed[:T].reshape(1, T, 1, 1, 1, D)
        )
        tok = (self.embed(x) + pos.to(x.dtype)).reshape(B, T, V * hp * wp, D)
        for blk in self.blocks:
            tok = blk(tok, T)
        f = self.norm(tok).reshape(B * T * V, hp, wp, D).permute(0, 3, 1, 2)
        gh, gw = hp, wp
        L_img = L.reshape(B * T * V, C, h, w)
        g_img = None if guide is None else guide.reshape(B * T * V, *guide.shape[3:]).to(f.dtype)
        for up in self.ups:
            gh, gw = gh * 2, gw * 2
            f = F.interpolate(f, scale_factor=2.0, mode="nearest")
            o_g, d_g = pixel_rays(intrinsics, cam_to_world, image_hw, (gh, gw))
            parts = [f, plucker(o_g, d_g, cfg.ray_scale).reshape(B * T * V, 6, gh, gw).to(f.dtype)]
            if cfg.reread_latent:
                parts.append(F.interpolate(L_img, size=(gh, gw), mode="nearest"))
            if cfg.guide_channels:
                parts.append(_resize(g_img, gh, gw))
            f = up["res"](up["conv"](torch.cat(parts, dim=1)))
        raw = self.head(f)
        if cfg.guide_channels:
            raw = raw + _guide_prior(_resize(g_img, gh, gw), raw.shape[1])
        raw = raw.reshape(B, T, V, -1, gh, gw).permute(0, 1, 2, 4, 5, 3)
        o_g, d_g = pixel_rays(intrinsics, cam_to_world, image_hw, (gh, gw))
        fx_grid = intrinsics[..., 0].float() * (gw / image_hw[1])
        return self.activate(raw, o_g, d_g, fx_grid, cam_to_world)

    def activate(
        self,
        raw: torch.Tensor,
        origins: torch.Tensor,
        dirs: torch.Tensor,
        fx_grid: torch.Tensor,
        cam_to_world: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """Raw head output (B,T,V,gh,gw,16) -> bounded Gaussian parameters (float32, autocast off)."""
        with torch.autocast(device_type=raw.device.type, enabled=False):
            return self._activate(raw.float(), origins.float(), dirs.float(), fx_grid.float(), cam_to_world.float())

    def _activate(self, raw, origins, dirs, fx_grid, cam_to_world):
        return activate_fields(self.cfg, raw, origins, dirs, fx_grid, cam_to_world)


def activate_fields(cfg: GSDecoderConfig, raw, origins, dirs, fx_grid, cam_to_world) -> dict[str, torch.Tensor]:
    """The heads' activations (module docstring): raw (B,T,V,gh,gw,16), ray origins (B,T,V,3) and directions
    (B,T,V,gh,gw,3), the grid's focal length fx_grid (B,T,V), cam_to_world (B,T,V,4,4) -> the Gaussian fields."""
    raw = torch.nan_to_num(raw.float(), nan=0.0, posinf=0.0, neginf=0.0)
    parts = dict(zip(HEAD_CHANNELS, raw.split(list(HEAD_CHANNELS.values()), dim=-1)))
    ln, lf = math.log(cfg.depth_near), math.log(cfg.depth_far)
    depth = torch.exp(ln + torch.sigmoid(parts["depth"][..., 0]) * (lf - ln))
    offset = cfg.max_offset * torch.tanh(parts["offset"])
    means = origins[..., None, None, :] + depth[..., None] * dirs + offset
    a, b = cfg.pixel_scale_range
    footprint = depth / fx_grid[..., None, None]
    scales = (footprint[..., None] * (a + (b - a) * torch.sigmoid(parts["scale"]))).clamp(cfg.scale_min, cfg.scale_max)
    q_cam = safe_normalize_quaternion(parts["quat"])
    q_c2w = matrix_to_quaternion(cam_to_world[..., :3, :3])[..., None, None, :].expand_as(q_cam)
    quats = quaternion_multiply(q_c2w, q_cam)
    quats = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    return {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": torch.sigmoid(parts["opacity"][..., 0] + cfg.opacity_bias),
        "colors": torch.sigmoid(parts["color"]),
        "depth": depth,
        "dynamic_logit": parts["dynamic"][..., 0].clamp(-15.0, 15.0),
    }


# A cell whose 3x3 neighbourhood's depths span more than this ratio lies on a depth edge: its r x r Gaussians keep its
# own raw maps (nearest) instead of blending them with the other side's (a blend is a Gaussian in mid-air, in front of
# the farther surface: on test:2 such Gaussians between a wall and a van behind it hid 0.3 of the van's pixels).
REFINE_EDGE_DEPTH_RATIO = 1.25


def _logit(p: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    p = p.clamp(eps, 1.0 - eps)
    return torch.log(p) - torch.log1p(-p)


def raw_fields(cfg: GSDecoderConfig, fields: dict, origins, dirs, fx_grid, cam_to_world) -> torch.Tensor:
    """The inverse of `activate_fields`: the decoder's fields (its outputs, ONNX's too) -> raw (B,T,V,gh,gw,16) that
    activate to them (exactly, up to float rounding, where no bound clamps; a clamped value comes back at the bound,
    the rotation with w >= 0)."""
    ln, lf = math.log(cfg.depth_near), math.log(cfg.depth_far)
    depth = fields["depth"].float()
    r_depth = _logit((torch.log(depth) - ln) / (lf - ln))
    offset = fields["means"].float() - origins[..., None, None, :] - depth[..., None] * dirs
    r_offset = torch.atanh((offset / cfg.max_offset).clamp(-1 + 1e-6, 1 - 1e-6))
    a, b = cfg.pixel_scale_range
    footprint = depth / fx_grid[..., None, None]
    r_scale = _logit((fields["scales"].float() / footprint[..., None] - a) / (b - a))
    q_c2w = matrix_to_quaternion(cam_to_world[..., :3, :3].float())[..., None, None, :]
    conj = q_c2w * torch.tensor([1.0, -1.0, -1.0, -1.0])
    q_cam = quaternion_multiply(conj.expand_as(fields["quats"]), fields["quats"].float())
    q_cam = torch.where(q_cam[..., :1] < 0, -q_cam, q_cam)
    r_quat = q_cam - torch.tensor([1.0, 0.0, 0.0, 0.0])
    r_opacity = _logit(fields["opacities"].float()) - cfg.opacity_bias
    r_color = _logit(fields["colors"].float())
    r_dyn = fields["dynamic_logit"].float()
    parts = {"offset": r_offset, "quat": r_quat, "scale": r_scale, "opacity": r_opacity[..., None],
             "color": r_color, "depth": r_depth[..., None], "dynamic": r_dyn[..., None]}  # fmt: skip
    return torch.cat([parts[k] for k in HEAD_CHANNELS], dim=-1)


@torch.no_grad()
def refine_fields(
    cfg: GSDecoderConfig,
    fields: dict,
    intrinsics: torch.Tensor,
    cam_to_world: torch.Tensor,
    image_hw: tuple[int, int],
    r: int,
    guide: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """The decoder's fields (B,T,V,gh,gw,k) on an r x finer grid: their raw maps (`raw_fields`) up-sampled
    bilinearly and activated on the finer grid's rays, so each cell becomes r x r Gaussians of 1/r its footprint on
    the surface the decoder put there (scales in footprints of the finer grid). With a pixel guide (B,T,V,5,H',W')
    the colour, depth and dynamic residuals over the guide's prior are up-sampled and the prior is read at the finer
    grid (bilinearly): the VAE's decoding supplies the finer colours. Across a depth edge (REFINE_EDGE_DEPTH_RATIO)
    a cell's own raw maps are kept (nearest), so no Gaussian lands between the two surfaces. Works on any backend's
    outputs (torch, ONNX)."""
    if r == 1:
        return fields
    B, T, V, gh, gw = fields["depth"].shape
    o, d = pixel_rays(intrinsics, cam_to_world, image_hw, (gh, gw))
    fx = intrinsics[..., 0].float() * (gw / image_hw[1])
    raw = raw_fields(cfg, fields, o, d, fx, cam_to_world).reshape(B * T * V, gh, gw, -1).permute(0, 3, 1, 2)
    g = None if guide is None or not cfg.guide_channels else guide.reshape(B * T * V, *guide.shape[3:]).float()
    if g is not None:
        raw = raw - _guide_prior(_resize(g, gh, gw), raw.shape[1])
    fh, fw = gh * r, gw * r
    z = fields["depth"].reshape(B * T * V, 1, gh, gw).float()
    edge = F.max_pool2d(z, 3, stride=1, padding=1) > REFINE_EDGE_DEPTH_RATIO * -F.max_pool2d(-z, 3, stride=1, padding=1)
    edge = F.interpolate(edge.float(), size=(fh, fw), mode="nearest") > 0.5
    smooth = F.interpolate(raw, size=(fh, fw), mode="bilinear", align_corners=False)
    raw = torch.where(edge, F.interpolate(raw, size=(fh, fw), mode="nearest"), smooth)
    if g is not None:
        raw = raw + _guide_prior(_resize(g, fh, fw) if g.shape[-2] >= fh else _bilinear(g, fh, fw), raw.shape[1])
    raw = raw.reshape(B, T, V, -1, fh, fw).permute(0, 1, 2, 4, 5, 3)
    o_f, d_f = pixel_rays(intrinsics, cam_to_world, image_hw, (fh, fw))
    fx_f = intrinsics[..., 0].float() * (fw / image_hw[1])
    return activate_fields(cfg, raw, o_f, d_f, fx_f, cam_to_world.float())
