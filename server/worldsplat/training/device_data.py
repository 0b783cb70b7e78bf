"""Training data generated once and held on the training device as tensors (`worldsplat train-stack`): the world's
clips as images, depth, masks and layout maps; the frozen VAE's latents and the conditions of every clip; and the
caption table that serves `encode_captions` where the sentence encoder is not installed (a lent machine).

    Images   every image of a set of clips: rgb uint8 (M,3,H,W), metric depth (M,H,W), dynamic (M,H,W)
    Cache    per clip: L (N,T,V,C,h,w) fp16, R = (L - mu) / scale once a layout prior exists, layout maps, conditions
"""

from __future__ import annotations

import contextlib
import io
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.io import atomic_write_bytes
from worldsplat.training.data import sample_from_shard
from worldsplat.training.loop import COND_KEYS
from worldsplat.world import build_world
from worldsplat.world.dataset import clip_scenario
from worldsplat.world.layout_maps import take_layout
from worldsplat_models import conditions as caption_module
from worldsplat_models.configs import DataConfig
from worldsplat_models.vae import normalize_depth

DCFG = DataConfig()


def device_generator(device: torch.device, seed: int) -> torch.Generator:
    return torch.Generator(device=device).manual_seed(seed)


# --- caption embeddings (made where the sentence encoder is installed, read where it is not) ----------------------


def caption_table(path: Path, train: int, test: int, pairs: int = 0, val: int = 0, workers: int = 1) -> Path:
    """The captions of train clips 0..train-1, test clips 0..test-1 and the enhancer's pair clips (train seeds
    0..pairs-1 and val seeds 0..val-1 of `pairs.split_seeds`), each from its scenario's world layout without
    rendering, and their sentence embeddings, one file."""
    from worldsplat.training.pairs import sample_scenario, split_seeds  # noqa: PLC0415

    jobs = [clip_scenario("train", i) for i in range(train)] + [clip_scenario("test", i) for i in range(test)]
    jobs += [sample_scenario(s) for s in split_seeds("train", pairs) + split_seeds("val", val)]
    with ThreadPoolExecutor(max(1, workers)) as pool:
        caps = list(pool.map(lambda sc: build_world(sc).caption, jobs))
    uniq = list(dict.fromkeys(caps))
    emb = caption_module.encode_captions(uniq)
    buf = io.BytesIO()
    torch.save({"captions": uniq, "emb": emb.half(), "train": train, "test": test}, buf)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())
    return path


class CaptionTable:
    """`encode_captions` from a precomputed table (float16 -> float32, as the encoder's unit vectors)."""

    def __init__(self, path: Path):
        d = torch.load(path, weights_only=False)
        self.index = {c: i for i, c in enumerate(d["captions"])}
        self.emb = d["emb"].float()
        self.train, self.test = int(d["train"]), int(d["test"])

    def __call__(self, captions: list[str]) -> torch.Tensor:
        missing = [c for c in captions if c not in self.index]
        if missing:
            raise KeyError(
                f"{len(missing)} caption(s) not in the caption table (made for other clips or another world version;"
                f" write it again with `worldsplat train-stack --write-captions`): {missing[0][:80]!r}"
            )
        return torch.stack([self.emb[self.index[c]] for c in captions])


@contextlib.contextmanager
def caption_table_installed(path: Path | None):
    """Serve `worldsplat_models.conditions.encode_captions` from the table while inside (restored after); None:
    the installed sentence encoder serves."""
    if path is None:
        yield None
        return
    table = CaptionTable(path)
    before = caption_module.caption_encoder
    caption_module.caption_encoder = lambda: table
    try:
        yield table
    finally:
        caption_module.caption_encoder = before


# --- clips -> device tensors ------------------------------------------------------------------------------------------


def _load(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        zz = {k: z[k] for k in z.files if k not in ("semantic", "bev") and not k.endswith("_shifted")}
    s = sample_from_shard(zz, DCFG.max_boxes)
    s.pop("sketch")
    s["layout"] = zz["layout"]
    return s


def load_clips(files: list[Path], threads: int) -> list[dict]:
    """Shards read in threads (zlib releases the GIL)."""
    with ThreadPoolExecutor(max(1, threads)) as pool:
        return list(pool.map(_load, files))


@dataclass
class Images:
    """Every image of a set of clips on the device: rgb uint8 (M,3,H,W), metric depth (M,H,W), dynamic (M,H,W)."""

    rgb: torch.Tensor
    depth: torch.Tensor
    dynamic: torch.Tensor

    @classmethod
    def of(cls, clips: list[dict], device) -> Images:
        def stack(k):
            return torch.from_numpy(np.stack([c[k].reshape(-1, *c[k].shape[2:]) for c in clips])).flatten(0, 1)

        return cls(
            stack("rgb").permute(0, 3, 1, 2).contiguous().to(device),
            stack("depth").to(device),
            stack("dynamic").to(device),
        )

    def __len__(self) -> int:
        return self.rgb.shape[0]

    def vae_inputs(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """As `data.vae_inputs`: rgb [-1,1] (B,3,H,W), normalised depth (B,1,H,W), mask {0,1} (B,1,H,W)."""
        rgb = self.rgb[idx].float().div(127.5).sub(1.0)
        depth = normalize_depth(self.depth[idx], DCFG.depth_near, DCFG.depth_far)[:, None]
        return rgb, depth, self.dynamic[idx].float()[:, None]

    def modalities(self, idx: torch.Tensor) -> torch.Tensor:
        """The VAE's training input: (rgb, depth, mask) of each image interleaved, each 3 channels in [-1, 1]."""
        rgb, depth, mask = self.vae_inputs(idx)
        x = torch.stack([rgb, depth.expand(-1, 3, -1, -1), (mask * 2 - 1).expand(-1, 3, -1, -1)], 1)
        return x.flatten(0, 1)

    def clip(self, c: int, frames: int, views: int) -> dict:
        """Clip c's fields as `loop.decoder_losses` reads them (views of the device tensors)."""
        sl = slice(c * frames * views, (c + 1) * frames * views)
        H, W = self.rgb.shape[-2:]
        return {
            "rgb": self.rgb[sl].reshape(frames, views, 3, H, W).permute(0, 1, 3, 4, 2),
            "depth": self.depth[sl].reshape(frames, views, H, W),
            "dynamic": self.dynamic[sl].reshape(frames, views, H, W),
        }


@torch.no_grad()
def fit_stats(vae, imgs: Images, n: int = 288, chunk: int = 96) -> None:
    """`loop.fit_latent_stats` on the device: per-channel mean/std of L over the first n images."""
    vae.latent_mean.zero_()
    vae.latent_std.fill_(1.0)
    Ls = []
    for a in range(0, min(n, len(imgs)), chunk):
        idx = torch.arange(a, min(a + chunk, n, len(imgs)), device=imgs.rgb.device)
        Ls.append(vae.encode_joint(*imgs.vae_inputs(idx)).float())
    L = torch.cat(Ls)
    vae.latent_mean.copy_(L.mean(dim=(0, 2, 3)))
    vae.latent_std.copy_(L.std(dim=(0, 2, 3)).clamp_min(1e-3))


@dataclass
class Cache:
    """Frozen-VAE latents of every clip and its conditions, on the device: L (N,T,V,C,h,w) fp16, layout maps
    (N,T,V,K,H,W), the condition arrays and caption embeddings; R (as L) once a layout prior exists;
    `intrinsics` / `cam_to_world` stay numpy (the decoder's cameras)."""

    L: torch.Tensor
    control: torch.Tensor
    cond: dict
    intrinsics: list
    cam_to_world: list
    R: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.L.shape[0]

    def batch(self, idx: torch.Tensor, channels: int) -> tuple[torch.Tensor, dict]:
        """As `campaign.dit_batch`: the flow's data (R when set, else L) and the DiT's conditions."""
        idx = idx.to(self.L.device)
        cond = {k: v[idx] for k, v in self.cond.items()}
        cond["control"] = take_layout(self.control[idx], channels).float()
        return (self.L if self.R is None else self.R)[idx].float(), cond

    def images(self, idx: torch.Tensor, channels: int) -> tuple[torch.Tensor, ...]:
        """As `campaign.prior_batch` for flat (clip * T * V) image indices: layout, caption, view, L."""
        N, T, V = self.L.shape[:3]
        idx = idx.to(self.L.device)
        c, v = idx // (T * V), idx % V
        t = (idx // V) % T
        lay = take_layout(self.control[c, t, v], channels).float()
        return lay, self.cond["caption"][c], v, self.L[c, t, v].float()


@torch.no_grad()
def build_cache(vae, clips: list[dict], imgs: Images, chunk: int = 8) -> Cache:
    T, V = clips[0]["rgb"].shape[:2]
    dev = imgs.rgb.device
    Ls = []
    for a in range(0, len(clips), chunk):
        b = min(a + chunk, len(clips))
        L = vae.encode_joint(*imgs.vae_inputs(torch.arange(a * T * V, b * T * V, device=dev)))
        Ls.append(L.reshape(b - a, T, V, *L.shape[1:]).half())
    control = torch.from_numpy(np.stack([np.ascontiguousarray(c["layout"].transpose(0, 1, 4, 2, 3)) for c in clips]))
    cond = {k: torch.from_numpy(np.stack([np.asarray(c[k]) for c in clips])).to(dev) for k in COND_KEYS}
    cond["caption"] = caption_module.encode_captions([c["caption"] for c in clips]).float().to(dev)
    return Cache(
        torch.cat(Ls), control.to(dev), cond, [c["intrinsics"] for c in clips], [c["cam_to_world"] for c in clips]
    )


@torch.no_grad()
def attach_residuals(prior, caches: list[Cache], channels: int, scale: float | None = None) -> float:
    """R = (L - mu) / scale on each cache (fp16); scale = the residual's RMS over the first cache when not given
    (as `campaign.attach_residuals`, on the device)."""
    mus = []
    for cache in caches:
        mus.append(
            torch.cat(
                [
                    prior.clip(
                        take_layout(cache.control[i : i + 1], channels).float(), cache.cond["caption"][i : i + 1]
                    )
                    for i in range(len(cache))
                ]
            )
        )
    if scale is None:
        scale = float(torch.sqrt(((caches[0].L.float() - mus[0]) ** 2).mean()))
    for cache, mu in zip(caches, mus):
        cache.R = ((cache.L.float() - mu) / scale).half()
    return scale
