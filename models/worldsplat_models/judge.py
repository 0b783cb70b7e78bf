"""The judge: a small perception model of the world's classes, trained on the world's exact labels, used to ask
whether generated images carry the scene a driving model needs (the paper's downstream evaluation, §4 / Table a1)
and as a feature space for distribution distances ("judge Fréchet distance": features of this model, not Inception).

One image of one camera in, the world's semantic classes per pixel out (every camera of a rig goes through the same
weights; the camera is not an input, so a render of any track is judged the same way). A U-Net of four levels:

    image (3, H, W) -> stem (w) -> down x3 (2w, 3w, 4w; stride 2 each) -> up x3 -> 1x1 -> classes

Each up step reduces the deeper level to the skip's channels (1x1, at the low resolution, where it is cheap),
up-samples it, adds the skip and mixes with one 3x3 convolution: about 0.1 GMAC per 64x112 image, so it trains in
minutes on two CPU cores.

`features(x)` returns the deepest level's channels averaged over the image (4w numbers per image): the
penultimate representation that the Fréchet distances are taken on. H and W must be multiples of 8 (the model
image 64x112 is). Weight files are safetensors with kind "judge" and the config in the metadata, like every other
network of the package.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from .weights import read_tagged, save_tagged

KIND = "judge"


@dataclass
class JudgeConfig:
    num_classes: int = 17  # the world's classes (worldsplat.world.classes)
    width: int = 24  # channels of the first level; the levels have w, 2w, 3w, 4w
    height_px: int = 64  # the image the judge was trained at (the models' image)
    width_px: int = 112


def _conv(cin: int, cout: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)]


def _block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(*_conv(cin, cout, stride), *_conv(cout, cout))


class Judge(nn.Module):
    # per-channel mean and std of world images (RGB in [0, 1]); a fixed normalisation, not learned
    MEAN = (0.45, 0.47, 0.48)
    STD = (0.25, 0.25, 0.27)

    def __init__(self, cfg: JudgeConfig | None = None):
        super().__init__()
        self.cfg = cfg or JudgeConfig()
        w = self.cfg.width
        chans = (w, 2 * w, 3 * w, 4 * w)
        self.stem = nn.Sequential(*_conv(3, chans[0]))
        self.down = nn.ModuleList([_block(chans[i], chans[i + 1], stride=2) for i in range(3)])
        self.reduce = nn.ModuleList([nn.Conv2d(chans[i + 1], chans[i], 1) for i in reversed(range(3))])
        self.up = nn.ModuleList([nn.Sequential(*_conv(chans[i], chans[i])) for i in reversed(range(3))])
        self.head = nn.Conv2d(chans[0], self.cfg.num_classes, 1)
        self.register_buffer("mean", torch.tensor(self.MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(self.STD).view(1, 3, 1, 1), persistent=False)

    def _encode(self, x: torch.Tensor) -> list[torch.Tensor]:
        h = self.stem((x - self.mean) / self.std)
        levels = [h]
        for d in self.down:
            h = d(h)
            levels.append(h)
        return levels

    def _decode(self, levels: list[torch.Tensor]) -> torch.Tensor:
        h = levels[-1]
        for reduce, up, skip in zip(self.reduce, self.up, reversed(levels[:-1])):
            h = F.interpolate(reduce(h), size=skip.shape[-2:], mode="bilinear", align_corners=False)
            h = up(h + skip)
        return self.head(h)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3, H, W) RGB in [0, 1] -> class logits (N, classes, H, W)."""
        return self._decode(self._encode(x))

    def head_probs(self, levels: list[torch.Tensor]) -> torch.Tensor:
        """Class probabilities (N, classes, H, W) from the encoder's levels (`_encode`), for heads that read both."""
        return self._decode(levels).softmax(1)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3, H, W) -> the deepest level averaged over the image (N, 4w): the Fréchet distances' features."""
        return self._encode(x)[-1].mean(dim=(2, 3))


def num_params(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def to_input(images: np.ndarray) -> torch.Tensor:
    """(..., H, W, 3) uint8 -> (N, 3, H, W) float in [0, 1]."""
    H, W = images.shape[-3:-1]
    x = torch.from_numpy(np.ascontiguousarray(images)).reshape(-1, H, W, 3)
    return x.permute(0, 3, 1, 2).float() / 255.0


def _resize_to(x: torch.Tensor, cfg: JudgeConfig) -> torch.Tensor:
    if tuple(x.shape[-2:]) == (cfg.height_px, cfg.width_px):
        return x
    return F.interpolate(x, size=(cfg.height_px, cfg.width_px), mode="area")


@torch.no_grad()
def segment(model: Judge, images: np.ndarray, batch: int = 64) -> np.ndarray:
    """Classes per pixel (..., H, W) uint8 of uint8 images (..., H, W, 3); other sizes are judged at the judge's
    image and the labels taken back to the input's size (nearest)."""
    lead, (H, W) = images.shape[:-3], images.shape[-3:-1]
    x = to_input(images)
    out = []
    for i in range(0, len(x), batch):
        logits = model(_resize_to(x[i : i + batch], model.cfg))
        if tuple(logits.shape[-2:]) != (H, W):
            logits = F.interpolate(logits, size=(H, W), mode="bilinear", align_corners=False)
        out.append(logits.argmax(1).to(torch.uint8))
    return torch.cat(out).reshape(*lead, H, W).numpy()


@torch.no_grad()
def features(model: Judge, images: np.ndarray, batch: int = 64) -> np.ndarray:
    """The penultimate features (N, 4w) float64 of uint8 images (..., H, W, 3), one row per image."""
    x = to_input(images)
    return (
        torch.cat([model.features(_resize_to(x[i : i + batch], model.cfg)) for i in range(0, len(x), batch)])
        .to(torch.float64)
        .numpy()
    )


def save_judge(model: Judge, path: str | Path, meta: dict | None = None) -> Path:
    """Atomic write: the weights (float32) with {kind: judge, config, **meta} in the metadata."""
    return save_tagged(model, path, KIND, meta)


def load_judge(path: str | Path) -> Judge:
    """A judge weight file -> the model in eval mode, its metadata in `.meta`."""
    tensors, meta = read_tagged(path, KIND, "train them with `worldsplat judge train`")
    fields = {f.name for f in dataclasses.fields(JudgeConfig)}
    model = Judge(JudgeConfig(**{k: v for k, v in meta["config"].items() if k in fields}))
    model.load_state_dict({k: v.float() for k, v in tensors.items()})
    model.meta = meta
    return model.eval()
