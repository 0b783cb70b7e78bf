"""4D-aware diffusion transformer with a ControlNet branch (paper §3.2, Appendix A).

Input latents x: (B, T, V, C, h, w) for T frames of V views. Patchified to tokens of width `dim`; each block
- cross-view spatial attention: tokens of all V views of one frame attend to each other,
  (B, V, T, h, w, C) -> (B*T, V*h*w, C) (the paper's reordering);
- temporal attention: each view/position attends over the T frames, (B*V*h*w, T, C);
- cross-attention to the fused condition tokens of its frame (boxes, trajectory, caption; conditions.py);
- an MLP.
Self-attention and MLP are modulated by adaLN-zero from the flow time s. A ControlNet branch (copies of the first
`control_depth` blocks) reads the per-camera control latents (the sketch latent for generation; render + sketch
latents for the enhancement model), and adds its outputs to the main stream through zero-initialised projections,
so a fresh ControlNet leaves the base model unchanged.

Layout control (DiTConfig.control_at_input / refine_channels; the served generator, which generates the layout
prior's residual): the layout does not need ControlNet's protection of a pretrained base, so its hint tokens are
added to the main stream's input, and a small conv head at latent resolution (LatentRefiner) draws what a
4x4-latent token cannot (markings, box edges) from the hint encoder's latent-resolution features; no ControlNet
copies (control_depth 0).

The backbone is generic in `in_channels`, `control_channels` and `out_channels` (DiTConfig), so the enhancement
model is `DiT4D(DiTConfig(in_channels=4, control_channels=8, out_channels=4), num_classes)`.
"""

from __future__ import annotations

import copy
import math

import torch
import torch.nn as nn
import torch.nn.functional as F

from .conditions import ConditionEncoder
from .configs import DiTConfig


def sincos_1d(n: int, dim: int, device=None) -> torch.Tensor:
    pos = torch.arange(n, dtype=torch.float32, device=device)[:, None]
    freq = torch.exp(-math.log(10000.0) * torch.arange(dim // 2, dtype=torch.float32, device=device) / (dim // 2))
    return torch.cat([torch.sin(pos * freq), torch.cos(pos * freq)], dim=1)


def sincos_2d(h: int, w: int, dim: int, device=None) -> torch.Tensor:
    """(h*w, dim) fixed 2D position embedding (half the channels for rows, half for columns)."""
    ey = sincos_1d(h, dim // 2, device)[:, None, :].expand(h, w, -1)
    ex = sincos_1d(w, dim // 2, device)[None, :, :].expand(h, w, -1)
    return torch.cat([ey, ex], dim=-1).reshape(h * w, dim)


def timestep_embedding(s: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal embedding of the flow time s in [0, 1] (scaled to 0..1000 like DiT/OpenSora), float32."""
    half = dim // 2
    freq = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32, device=s.device) / half)
    a = (s.float() * 1000.0)[:, None] * freq[None]
    return torch.cat([torch.cos(a), torch.sin(a)], dim=-1)


class Attention(nn.Module):
    """Multi-head attention with LayerNorm on queries and keys (qk-norm, for bf16 stability)."""

    def __init__(self, dim: int, heads: int, kv_dim: int | None = None):
        super().__init__()
        if dim % heads:
            raise ValueError(f"attention: dim {dim} not divisible by heads {heads}")
        self.heads = heads
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(kv_dim or dim, 2 * dim)
        self.q_norm = nn.LayerNorm(dim // heads, eps=1e-6)
        self.k_norm = nn.LayerNorm(dim // heads, eps=1e-6)
        self.proj = nn.Linear(dim, dim)

    def forward(
        self, x: torch.Tensor, context: torch.Tensor | None = None, key_mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        B, N, D = x.shape
        ctx = x if context is None else context
        M = ctx.shape[1]
        hd = D // self.heads
        q = self.q_norm(self.q(x).reshape(B, N, self.heads, hd)).transpose(1, 2)
        k, v = self.kv(ctx).reshape(B, M, 2, self.heads, hd).unbind(2)
        k = self.k_norm(k).transpose(1, 2)
        v = v.transpose(1, 2)
        mask = None if key_mask is None else key_mask[:, None, None, :]
        o = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        return self.proj(o.transpose(1, 2).reshape(B, N, D))


def modulate(x, shift, scale):
    return x * (1 + scale) + shift


class DiTBlock(nn.Module):
    """Cross-view spatial attn -> temporal attn -> cross-attn to conditions -> MLP; adaLN-zero on s."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.norm_s = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.spatial = Attention(dim, heads)
        self.norm_t = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.temporal = Attention(dim, heads)
        self.norm_c = nn.LayerNorm(dim, eps=1e-6)
        self.cross = Attention(dim, heads)
        self.norm_m = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(approximate="tanh"), nn.Linear(hidden, dim))
        self.ada = nn.Sequential(nn.SiLU(), nn.Linear(dim, 9 * dim))
        nn.init.zeros_(self.ada[1].weight)
        nn.init.zeros_(self.ada[1].bias)

    def forward(self, x, t_emb, cond_tokens, cond_mask, T: int, V: int):
        """x (B, T, V*S, D); t_emb (B, D); cond_tokens (B*T, N, D); cond_mask (B*T, N)."""
        B, _, VS, D = x.shape
        m = self.ada(t_emb)[:, None, None, :].chunk(9, dim=-1)
        # cross-view spatial attention: one sequence of V*S tokens per frame
        h = modulate(self.norm_s(x), m[0], m[1]).reshape(B * T, VS, D)
        x = x + m[2] * self.spatial(h).reshape(B, T, VS, D)
        # temporal attention: one sequence of T tokens per view/position
        h = modulate(self.norm_t(x), m[3], m[4]).transpose(1, 2).reshape(B * VS, T, D)
        x = x + m[5] * self.temporal(h).reshape(B, VS, T, D).transpose(1, 2)
        # cross-attention to this frame's condition tokens
        h = self.norm_c(x).reshape(B * T, VS, D)
        x = x + self.cross(h, cond_tokens, cond_mask).reshape(B, T, VS, D)
        h = modulate(self.norm_m(x), m[6], m[7])
        return x + m[8] * self.mlp(h)


class HintEncoder(nn.Module):
    """Pixel-space layout map (N, C, H, W) -> one D-wide token per `factor` x `factor` pixels (N, S, D): a stack
    of stride-2 convolutions, as ControlNet's hint encoder, so thin lane markings survive to the token grid.

    stem_stride 1 starts with a 3x3 conv at full resolution; 2 lets the first conv down-sample already
    (its 3x3 window at stride 2 still reads every pixel): about 4x fewer FLOPs, the hint encoder having been the
    largest cost of a DiT step at 64x112."""

    def __init__(self, cin: int, dim: int, factor: int, stem_stride: int = 1):
        super().__init__()
        n = int(round(math.log2(factor)))
        if 2**n != factor:
            raise ValueError(f"HintEncoder: factor {factor} is not a power of two")
        if stem_stride not in (1, 2) or (stem_stride == 2 and n < 1):
            raise ValueError(f"HintEncoder: stem_stride must be 1 or 2 (<= factor {factor}), got {stem_stride}")
        widths = [min(32 * 2**i, dim) for i in range(n + 1)]  # widths[i]: channels at stride 2**i
        if stem_stride == 1:
            layers = [nn.Conv2d(cin, widths[0], 3, padding=1), nn.SiLU()]
        else:
            layers = [nn.Conv2d(cin, widths[1], 3, stride=2, padding=1), nn.SiLU()]
        for i in range(stem_stride - 1, n):
            layers += [nn.Conv2d(widths[i], widths[i + 1], 3, stride=2, padding=1), nn.SiLU()]
        layers.append(nn.Conv2d(widths[-1], dim, 1))
        self.net = nn.Sequential(*layers)
        self.widths = widths

    def forward(self, x: torch.Tensor, grid: tuple[int, int], fine_stride: int = 0):
        """-> tokens (N, S, D); with `fine_stride` also the feature map after that much down-sampling
        (N, widths[log2 fine_stride], H/fine_stride, W/fine_stride), for the latent-resolution head."""
        fine, stride = None, 1
        f = x
        for layer in self.net:
            f = layer(f)
            if isinstance(layer, nn.SiLU) and stride == fine_stride and fine is None:
                fine = f
            if isinstance(layer, nn.Conv2d) and layer.stride[0] == 2:
                stride *= 2
        if tuple(f.shape[-2:]) != tuple(grid):
            raise ValueError(f"HintEncoder: layout map gives a {tuple(f.shape[-2:])} grid, the tokens are {grid}")
        tokens = f.flatten(2).transpose(1, 2)
        if fine_stride:
            if fine is None:
                raise ValueError(f"HintEncoder: no feature map at stride {fine_stride}")
            return tokens, fine
        return tokens


class LatentRefiner(nn.Module):
    """Convolutional head at latent resolution: residual on the unpatchified token output, from [token output,
    z_s, layout features], with the flow time as a per-channel bias. The last conv starts at zero, so a fresh head
    leaves the token output as it is."""

    def __init__(self, latent_channels: int, out_channels: int, hint_channels: int, width: int, dim: int):
        super().__init__()
        # 1x1 in (the concatenation is wide, a 3x3 there was the costliest conv of a step), then two 3x3
        self.inp = nn.Conv2d(out_channels + latent_channels + hint_channels, width, 1)
        self.time = nn.Linear(dim, width)
        self.mid = nn.Conv2d(width, width, 3, padding=1)
        self.out = nn.Conv2d(width, out_channels, 3, padding=1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, out: torch.Tensor, z: torch.Tensor, hint: torch.Tensor, t_emb: torch.Tensor) -> torch.Tensor:
        """out (N, Co, h, w), z (N, C, h, w), hint (N, Ch, h, w), t_emb (N, dim) -> (N, Co, h, w)."""
        h = F.silu(self.inp(torch.cat([out, z, hint], 1)) + self.time(t_emb)[:, :, None, None])
        h = F.silu(self.mid(h))
        return out + self.out(h)


class DiT4D(nn.Module):
    def __init__(self, cfg: DiTConfig, num_classes: int = 17):
        super().__init__()
        self.cfg = cfg
        p, D = cfg.patch, cfg.dim
        self.patch_embed = nn.Linear(cfg.in_channels * p * p, D)
        self.view_embed = nn.Parameter(torch.zeros(cfg.max_views, D))
        self.frame_embed = nn.Parameter(torch.zeros(cfg.max_frames, D))
        nn.init.normal_(self.view_embed, std=0.02)
        nn.init.normal_(self.frame_embed, std=0.02)
        self.t_embed = nn.Sequential(nn.Linear(256, D), nn.SiLU(), nn.Linear(D, D))
        self.conditions = ConditionEncoder(num_classes, cfg.cond_dim, D, cfg.caption_dim, cfg.box_fourier)
        self.blocks = nn.ModuleList(DiTBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.depth))
        # ControlNet branch
        if cfg.control_depth > cfg.depth:
            raise ValueError("DiTConfig: control_depth cannot exceed depth")
        if cfg.control_hint:
            self.control_embed = HintEncoder(cfg.control_channels, D, cfg.control_hint, cfg.hint_stem_stride)
        else:
            self.control_embed = nn.Linear(cfg.control_channels * p * p, D)
        self.control_in = nn.Linear(D, D)
        self.control_blocks = nn.ModuleList(copy.deepcopy(self.blocks[i]) for i in range(cfg.control_depth))
        self.control_out = nn.ModuleList(nn.Linear(D, D) for _ in range(cfg.control_depth))
        for lin in [self.control_in, *self.control_out]:
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)
        if cfg.control_at_input or cfg.refine_channels:
            if not cfg.control_hint:
                raise ValueError("DiTConfig: control_at_input / refine_channels need pixel-space layout (control_hint)")
        if cfg.control_at_input:
            self.control_input = nn.Linear(D, D)  # layout tokens into the main stream, trained from the start
        self.fine_stride = cfg.control_hint // p
        if cfg.refine_channels:
            if self.fine_stride < 1 or cfg.control_hint % p:
                raise ValueError(f"DiTConfig: control_hint {cfg.control_hint} is not a multiple of patch {p}")
            hint_ch = self.control_embed.widths[int(round(math.log2(self.fine_stride)))]
            self.refiner = LatentRefiner(cfg.in_channels, cfg.out_channels, hint_ch, cfg.refine_channels, D)
        # output
        self.final_norm = nn.LayerNorm(D, elementwise_affine=False, eps=1e-6)
        self.final_ada = nn.Sequential(nn.SiLU(), nn.Linear(D, 2 * D))
        self.final = nn.Linear(D, cfg.out_channels * p * p)
        for lin in (self.final_ada[1], self.final):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)

    def _tokens(self, x: torch.Tensor, embed: nn.Linear) -> torch.Tensor:
        B, T, V, C, h, w = x.shape
        p = self.cfg.patch
        if h % p or w % p:
            raise ValueError(f"DiT: latent size {h}x{w} not divisible by patch {p}")
        x = x.reshape(B, T, V, C, h // p, p, w // p, p).permute(0, 1, 2, 4, 6, 3, 5, 7)
        return embed(x.reshape(B, T, V, (h // p) * (w // p), C * p * p))

    def forward(self, x: torch.Tensor, s: torch.Tensor, cond: dict) -> torch.Tensor:
        """x (B,T,V,C,h,w) noisy latents, s (B,) flow time in [0,1], cond: the ConditionEncoder fields plus
        "control" (B,T,V,Cc,h,w) and optional "drop" (B,) bool -> velocity (B,T,V,C_out,h,w)."""
        cfg = self.cfg
        B, T, V, C, h, w = x.shape
        if C != cfg.in_channels:
            raise ValueError(f"DiT: expected {cfg.in_channels} latent channels, got {C}")
        if V > cfg.max_views or T > cfg.max_frames:
            raise ValueError(f"DiT: {V} views x {T} frames exceeds max {cfg.max_views} x {cfg.max_frames}")
        p, D = cfg.patch, cfg.dim
        hp, wp = h // p, w // p
        S = hp * wp
        drop = cond.get("drop")
        pos = (
            sincos_2d(hp, wp, D, x.device)[None, None, None]
            + self.view_embed[:V][None, None, :, None]
            + self.frame_embed[:T][None, :, None, None]
        )
        tok = (self._tokens(x, self.patch_embed) + pos.to(x.dtype)).reshape(B, T, V * S, D)
        t_emb = self.t_embed(timestep_embedding(s, 256).to(tok.dtype))
        c_tok, c_mask = self.conditions(cond, drop)
        c_tok = c_tok.reshape(B * T, -1, D)
        c_mask = c_mask.reshape(B * T, -1)

        control = cond["control"]
        if drop is not None:
            control = torch.where(drop.bool().view(B, 1, 1, 1, 1, 1), torch.zeros_like(control), control)
        hint = None
        if cfg.control_hint:
            flat = control.reshape(B * T * V, *control.shape[3:])
            if cfg.refine_channels:
                ctl_tok, hint = self.control_embed(flat, (hp, wp), self.fine_stride)
            else:
                ctl_tok = self.control_embed(flat, (hp, wp))
        else:
            ctl_tok = self._tokens(control, self.control_embed)
        ctl_tok = ctl_tok.reshape(B, T, V * S, D)
        if cfg.control_at_input:
            tok = tok + self.control_input(ctl_tok)
        ctl = tok + self.control_in(ctl_tok)
        residuals = []
        for blk, out in zip(self.control_blocks, self.control_out):
            ctl = blk(ctl, t_emb, c_tok, c_mask, T, V)
            residuals.append(out(ctl))

        for i, blk in enumerate(self.blocks):
            tok = blk(tok, t_emb, c_tok, c_mask, T, V)
            if i < len(residuals):
                tok = tok + residuals[i]

        shift, scale = self.final_ada(t_emb)[:, None, None, :].chunk(2, dim=-1)
        out = self.final(modulate(self.final_norm(tok), shift, scale))
        Co = cfg.out_channels
        out = out.reshape(B, T, V, hp, wp, Co, p, p).permute(0, 1, 2, 5, 3, 6, 4, 7)
        out = out.reshape(B, T, V, Co, h, w)
        if cfg.refine_channels:
            t_rep = t_emb[:, None].expand(B, T * V, D).reshape(B * T * V, D)
            out = self.refiner(out.reshape(B * T * V, Co, h, w), x.reshape(B * T * V, C, h, w), hint, t_rep)
            out = out.reshape(B, T, V, Co, h, w)
        return out

    def init_control_from_base(self) -> None:
        """ControlNet convention: the control blocks start as copies of the base blocks."""
        for i, blk in enumerate(self.control_blocks):
            blk.load_state_dict(self.blocks[i].state_dict())


def dropped(cond: dict) -> dict:
    """The unconditional branch of classifier-free guidance: the same inputs with every condition dropped."""
    B = cond["box_mask"].shape[0]
    out = dict(cond)
    out["drop"] = torch.ones(B, dtype=torch.bool, device=cond["box_mask"].device)
    return out
