"""Training the judge (worldsplat_models.judge): per-pixel classes of world images, from the world's exact labels.

Data: the shards of `worldsplat dataset` (their `rgb` and `semantic`, every camera and frame of every clip is one
image), held in memory as uint8. A step draws `batch` images with the step's generator, flips half of them
left-right and jitters brightness and contrast (world images only: the judge never sees a render in training, so
what it scores on renders is the domain gap). With `degrade`, a step also blurs, colour-casts and adds noise to
some of its images (`degrade`): a judge that does not hinge on the world's exact textures, the second yardstick of
web/docs/downstream.md (still world images only). The loss is cross-entropy weighted per class by frequency^-1/2 over the
training labels, so thin classes (poles, signs, lane markings) are not drowned by road, building and sky. The loop
is the package's one training loop (`training.loop.train_loop`: checkpoints with resume, warm-up + cosine, a
wall-time limit); the weights are exported at every checkpoint.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.training.data import shard_files
from worldsplat.training.loop import train_loop
from worldsplat.world.classes import CLASS_NAMES
from worldsplat_models.configs import TrainConfig
from worldsplat_models.judge import Judge, JudgeConfig, num_params, save_judge, to_input

NUM_CLASSES = len(CLASS_NAMES)


def load_images(data: Path, split: str, limit: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every camera and frame of the split's clips: images (N, H, W, 3) uint8 and classes (N, H, W) uint8."""
    images, labels = [], []
    for f in shard_files(data, split, limit):
        with np.load(f, allow_pickle=False) as z:  # only the two arrays (a shard holds a dozen more)
            rgb, semantic = z["rgb"], z["semantic"]
        H, W = rgb.shape[-3:-1]
        images.append(rgb.reshape(-1, H, W, 3))
        labels.append(semantic.reshape(-1, H, W))
    return np.concatenate(images), np.concatenate(labels)


def class_weights(labels: np.ndarray, num_classes: int = NUM_CLASSES) -> np.ndarray:
    """frequency^-1/2 per class, normalised to a pixel-weighted mean of 1; absent classes get the largest weight."""
    freq = np.bincount(labels.ravel(), minlength=num_classes).astype(np.float64)
    freq = freq / freq.sum()
    w = np.where(freq > 0, 1.0 / np.sqrt(np.maximum(freq, 1e-12)), 0.0)
    w[freq == 0] = w.max()
    return (w / (w * freq).sum()).astype(np.float32)


def augment(x: torch.Tensor, y: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Flip half the batch left-right; brightness x[0.8, 1.2] and contrast x[0.8, 1.2] per image."""
    n = x.shape[0]
    flip = torch.rand(n, generator=gen) < 0.5
    x = torch.where(flip.view(n, 1, 1, 1), x.flip(-1), x)
    y = torch.where(flip.view(n, 1, 1), y.flip(-1), y)
    bright = 0.8 + 0.4 * torch.rand(n, 1, 1, 1, generator=gen)
    contrast = 0.8 + 0.4 * torch.rand(n, 1, 1, 1, generator=gen)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = ((x - mean) * contrast + mean) * bright
    return x.clamp(0, 1), y


def _gaussian_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """(C, H, W) blurred by a separable Gaussian of `sigma` pixels (reflected borders)."""
    r = max(1, int(np.ceil(2.5 * sigma)))
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=x.dtype) / sigma) ** 2)
    k = k / k.sum()
    c = x.shape[0]
    y = F.pad(x[None], (r, r, r, r), mode="reflect")
    y = F.conv2d(y, k.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(y, k.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)[0]


def degrade(x: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Photometric degradations of a batch (N, 3, H, W) in [0, 1], each image independently: half are blurred
    (Gaussian, sigma 0.5-1.5 px: a splatted render's softness at the model image), half get a colour cast (gain
    x[0.85, 1.15] per channel) and a gamma in [0.8, 1.25], all get pixel noise of std up to 0.03. The labels are
    unchanged: the classes are where they were."""
    n = x.shape[0]
    blur, cast = torch.rand(n, generator=gen) < 0.5, torch.rand(n, generator=gen) < 0.5
    sigma = 0.5 + torch.rand(n, generator=gen)
    gain = 0.85 + 0.3 * torch.rand(n, 3, 1, 1, generator=gen)
    gamma = torch.exp(torch.empty(n, 1, 1, 1).uniform_(np.log(0.8), np.log(1.25), generator=gen))
    noise = 0.03 * torch.rand(n, 1, 1, 1, generator=gen) * torch.randn(x.shape, generator=gen)
    out = []
    for i in range(n):
        xi = _gaussian_blur(x[i], float(sigma[i])) if blur[i] else x[i]
        out.append((xi * gain[i]).clamp(0, 1) ** gamma[i] if cast[i] else xi)
    return (torch.stack(out) + noise).clamp(0, 1)


def judge_step_fn(images: np.ndarray, labels: np.ndarray, weights: np.ndarray, batch: int, degraded: bool = False):
    """step_fn for `train_loop`: `batch` random images of the in-memory set, augmented (and with `degraded`,
    `degrade`d), weighted cross-entropy."""
    w = torch.from_numpy(weights)

    def step(model, step_i: int, gen: torch.Generator):
        idx = torch.randint(0, len(images), (batch,), generator=gen).numpy()
        x = to_input(images[idx])
        y = torch.from_numpy(labels[idx].astype(np.int64))
        x, y = augment(x, y, gen)
        if degraded:
            x = degrade(x, gen)
        logits = model(x)
        loss = F.cross_entropy(logits, y, weight=w)
        with torch.no_grad():
            acc = float((logits.argmax(1) == y).float().mean())
        return loss, {"pixel_acc": round(acc, 4)}

    return step


def train_judge(
    data: Path,
    out: Path,
    steps: int = 1200,
    batch: int = 12,
    width: int = 24,
    lr: float = 3e-3,
    minutes: float | None = None,
    seed: int = 0,
    threads: int = 2,
    clips: int | None = None,
    progress: bool = True,
    degraded: bool = False,
) -> Path:
    """Train a judge on DATA/train; checkpoints and log in OUT, weights in OUT/judge_small.safetensors (exported at
    every checkpoint; a re-run resumes). With `degraded`, the training images are also `degrade`d. Returns the
    weights' path."""
    images, labels = load_images(data, "train", clips)
    source = {"data": str(data), "train_clips": len(shard_files(data, "train", clips))}
    if degraded:
        source["augmentation"] = "flip, brightness, contrast, degrade (blur, colour cast, gamma, noise)"
    return train_judge_on(
        images, labels, out, source, steps, batch, width, lr, minutes, seed, threads, progress, degraded
    )


def train_judge_on(
    images: np.ndarray,
    labels: np.ndarray,
    out: Path,
    source: dict,
    steps: int = 1200,
    batch: int = 12,
    width: int = 24,
    lr: float = 3e-3,
    minutes: float | None = None,
    seed: int = 0,
    threads: int = 2,
    progress: bool = True,
    degraded: bool = False,
) -> Path:
    """Train a judge on in-memory images (N, H, W, 3) uint8 and their classes (N, H, W); `source` (what the images
    are) goes into the weights' provenance. Checkpoints, log and OUT/judge_small.safetensors as `train_judge`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(threads)
    t0 = time.time()
    weights = class_weights(labels)
    H, W = images.shape[1:3]
    model = Judge(JudgeConfig(num_classes=NUM_CLASSES, width=width, height_px=H, width_px=W))
    tcfg = TrainConfig(
        steps=steps, lr=lr, warmup=min(50, steps // 10), seed=seed, ckpt_every=100, log_every=20, threads=threads
    )
    path = out / "judge_small.safetensors"

    def export(m, done: int) -> None:
        meta = {
            "provenance": {
                **source,
                "train_images": int(len(images)),
                "image": [int(W), int(H)],
                "steps": int(done),
                "batch": batch,
                "lr": lr,
                "seed": seed,
                "params": num_params(m),
                "class_weights": [round(float(v), 4) for v in weights],
                "wall_s": round(time.time() - t0, 1),
            }
        }
        save_judge(m, path, meta)

    history = train_loop(
        "judge",
        model,
        judge_step_fn(images, labels, weights, batch, degraded),
        tcfg,
        out,
        progress=progress,
        on_checkpoint=export,
        minutes=minutes,
    )
    if history:
        (out / "judge_last.json").write_text(json.dumps(history[-1]) + "\n")
    return path
