"""Enhanced Diffusion Model (paper §3.4, Appendix A): refines renders of novel (shifted) tracks in latent space.

The backbone is the 4D-aware DiT of dit.py, unchanged (cross-view spatial, temporal and condition cross-attention
blocks, adaLN-zero, ControlNet branch with zero-initialised projections); only its channels differ:
- input / output: the normalised image latent of the VAE (c channels); the regression target is E(I), the latent
  of the TRUE view of the shifted track (the world renders it exactly), learned with the rectified flow of rflow.py;
- ControlNet input: [render latent E(R') | sketch latent E(S') | render coverage], 2c + 1 channels. The coverage is
  the render's accumulated alpha pooled to the latent grid: where it is low the render has a hole (a disocclusion
  or unobserved sky) and the model must inpaint; it is zero whenever the render condition is absent;
- cross-attention: boxes B', trajectory T' and caption, exactly as in the generator (conditions.py).
Conditions C' = {R', S', B', T', caption} (§3.5). Mixed conditioning: training pairs are degraded renders (oracle or
decoder Gaussians seen from shifted tracks) mixed with clean ones (the true view's own render) with probability
`clean_prob`; `render_drop` zeroes the render condition alone so the same model also runs on reprojected
conditions only (ablation version A).

Source of the flow (`EnhancerConfig.source`): "noise" (the paper's: the sampler starts from seeded Gaussian noise,
the render enters only as a condition) or "render" (a latent bridge as in InDI / I2SB): the flow runs from the
render's own latent, lightly noised (`source_noise`), to the true view's latent, so where the render is already
right the velocity is near zero and the output keeps it, and the model's work goes into holes, ghosts and blur.
With few Euler steps the bridge is close to the MMSE restoration, which is what PSNR rewards; it needs the render
(no version A) and has no SDEdit start.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from safetensors import safe_open

from . import rflow
from .configs import SIZES, DataConfig, DiTConfig, VAEConfig, from_dict
from .dit import DiT4D
from .pixel_mix import PixelMix, PixelMixConfig, mix
from .vae import MultiModalVAE
from .weights import write_safetensors

SOURCES = ("noise", "render")


@dataclass
class EnhancerConfig:
    data: DataConfig = field(default_factory=DataConfig)
    dit: DiTConfig = field(
        default_factory=lambda: DiTConfig(
            in_channels=4, control_channels=9, out_channels=4, dim=96, depth=4, control_depth=2, cond_drop=0.1
        )
    )
    latent_channels: int = 4  # per image; must equal the VAE's latent_channels
    mixed: bool = True  # mixed conditioning (paper: "Mixed Aug"); False = degraded renders only
    clean_prob: float = 0.3  # share of clean pairs in a mixed batch
    render_drop: float = 0.1  # probability of zeroing the render condition (keeps S', B', T', caption)
    num_classes: int = 17
    source: str = "noise"  # where the flow starts: "noise" (paper) or "render" (latent bridge; module doc)
    source_noise: float = 0.0  # std of the noise added to the render latent at the bridge's source, in training
    # ... and when sampling: 0 starts from the render latent itself (the mean of the training sources), measured
    # +0.13 / +0.07 dB over a 0.1-noised start at 2 / 4 m and equal to averaging four noised starts
    sample_noise: float = 0.0
    # the pixel mix of the output with the render (pixel_mix.py), fitted after the enhancer to its outputs; None
    # for files without one (their default blend is "holes")
    pixel_mix: PixelMixConfig | None = None

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"EnhancerConfig.source must be one of {SOURCES}, got {self.source!r}")
        if self.source == "render" and self.render_drop:
            raise ValueError("EnhancerConfig: a render-bridge enhancer always has the render (render_drop must be 0)")
        if not (self.source_noise >= 0 and self.sample_noise >= 0):
            raise ValueError(
                f"EnhancerConfig.source_noise / sample_noise must be >= 0, got {self.source_noise} / {self.sample_noise}"
            )
        c = self.latent_channels
        if (self.dit.in_channels, self.dit.out_channels, self.dit.control_channels) != (c, c, 2 * c + 1):
            raise ValueError(
                f"EnhancerConfig: DiT channels must be in={c}, out={c}, control={2 * c + 1} for "
                f"latent_channels={c}, got in={self.dit.in_channels}, out={self.dit.out_channels}, "
                f"control={self.dit.control_channels}"
            )


def enhancer_config(size: str = "small") -> EnhancerConfig:
    """tiny (tests), small (the shipped weights, 2 CPU cores), paper (the generator's STDiT3-XL widths)."""

    def dit(c: int, **kw) -> DiTConfig:
        return DiTConfig(in_channels=c, control_channels=2 * c + 1, out_channels=c, **kw)

    if size == "tiny":
        return EnhancerConfig(
            data=DataConfig(height=32, width=48, views=2, frames=2, max_boxes=4),
            dit=dit(2, dim=32, depth=2, heads=2, control_depth=1, cond_dim=32, max_views=2, max_frames=2),
            latent_channels=2,
        )
    if size == "small":
        # the shipped VAE's 8-channel latents at 1/4 resolution (16x28), a bridge from the render's latent
        # (module doc). The generator's block design at 3/4 width and 2/3 depth, patch 2 (112 tokens per image):
        # 0.7 s per training step on one contended core (patch 4: 0.16 s, but a token then draws 4x4 latents).
        return EnhancerConfig(
            dit=dit(
                8, patch=2, dim=96, depth=4, heads=4, control_depth=2, cond_drop=0.1, sampler_steps=1, sampler_shift=1.0
            ),
            latent_channels=8,
            render_drop=0.0,
            source="render",
            source_noise=0.1,
        )
    if size == "paper":
        return EnhancerConfig(
            data=DataConfig(height=424, width=800, views=6, frames=17, max_boxes=64),
            dit=dit(4, dim=1152, depth=28, heads=16, control_depth=13, cond_dim=512, max_frames=32),
        )
    raise ValueError(f"unknown enhancer size {size!r}; expected one of {', '.join(SIZES)}")


def config_to_dict(cfg: EnhancerConfig) -> dict:
    return dataclasses.asdict(cfg)


def config_from_dict(d: dict) -> EnhancerConfig:
    d = dict(d)
    data = from_dict(DataConfig, d.pop("data"))
    dit = from_dict(DiTConfig, d.pop("dit"))
    mix_cfg = d.pop("pixel_mix", None)
    if mix_cfg is not None:
        mix_cfg = PixelMixConfig(**{**mix_cfg, "dilations": tuple(mix_cfg.get("dilations", ()))})
    names = {f.name for f in dataclasses.fields(EnhancerConfig)}
    unknown = set(d) - names
    if unknown:
        raise ValueError(f"EnhancerConfig: unknown field(s) {sorted(unknown)}")
    return EnhancerConfig(data=data, dit=dit, pixel_mix=mix_cfg, **d)


# --- VAE I/O: images <-> normalised image latents -------------------------------------------------------------------


def _stats(vae, c: int) -> tuple[torch.Tensor, torch.Tensor]:
    return vae.latent_mean[:c].view(1, -1, 1, 1), vae.latent_std[:c].view(1, -1, 1, 1)


@torch.no_grad()
def encode_images(vae, images: torch.Tensor | np.ndarray, batch: int = 48) -> torch.Tensor:
    """(N,H,W,3) uint8 (or float in [0,1]) -> (N,c,H/8,W/8) latents normalised with the VAE's RGB statistics
    (the same normalisation the generator uses for its sketch latents)."""
    x = torch.as_tensor(np.asarray(images))
    x = x.float() / 255.0 if x.dtype == torch.uint8 else x.float()
    if x.dim() != 4 or x.shape[-1] != 3:
        raise ValueError(f"encode_images: expected (N,H,W,3) images, got {tuple(x.shape)}")
    c = vae.cfg.latent_channels
    mean, std = _stats(vae, c)
    out = [(vae.encode(x[i : i + batch].permute(0, 3, 1, 2) * 2 - 1) - mean) / std for i in range(0, len(x), batch)]
    return torch.cat(out)


@torch.no_grad()
def decode_latents(vae, z: torch.Tensor, batch: int = 48) -> np.ndarray:
    """(N,c,h,w) normalised latents -> (N,8h,8w,3) uint8."""
    c = vae.cfg.latent_channels
    mean, std = _stats(vae, c)
    out = []
    for i in range(0, len(z), batch):
        x = vae.decode(z[i : i + batch].float() * std + mean).clamp(-1, 1)
        out.append(torch.round((x + 1) * 127.5).to(torch.uint8).permute(0, 2, 3, 1))
    return torch.cat(out).numpy()


def coverage(alpha: torch.Tensor | np.ndarray, factor: int = 8) -> torch.Tensor:
    """(N,H,W) accumulated render alpha -> (N,1,H/f,W/f) mean coverage in [0,1] on the latent grid."""
    a = torch.as_tensor(np.asarray(alpha, np.float32)).clamp(0, 1)
    return F.avg_pool2d(a[:, None], factor)


# --- the model ------------------------------------------------------------------------------------------------------


class Enhancer(nn.Module):
    """DiT4D with the enhancer's channels; `control(...)` assembles the ControlNet input."""

    def __init__(self, cfg: EnhancerConfig):
        super().__init__()
        self.cfg = cfg
        self.dit = DiT4D(cfg.dit, cfg.num_classes)
        self.mix = PixelMix(cfg.pixel_mix) if cfg.pixel_mix is not None else None

    def attach_mix(self, net: PixelMix) -> None:
        """Bundle a pixel mix fitted to this enhancer's outputs (saved with it; the default blend becomes "mix")."""
        self.cfg = dataclasses.replace(self.cfg, pixel_mix=net.cfg)
        self.mix = net

    @staticmethod
    def control(
        render_lat: torch.Tensor, sketch_lat: torch.Tensor, cover: torch.Tensor, use_render: torch.Tensor | bool = True
    ) -> torch.Tensor:
        """(B,T,V,c,h,w) render latent, (B,T,V,c,h,w) sketch latent, (B,T,V,1,h,w) coverage -> control latent.
        `use_render` (bool or (B,) bool) False zeroes the render latent and its coverage (S', B', T' only)."""
        if not isinstance(use_render, torch.Tensor):
            use_render = torch.full((render_lat.shape[0],), bool(use_render))
        keep = use_render.to(render_lat.dtype).view(-1, 1, 1, 1, 1, 1)
        return torch.cat([render_lat * keep, sketch_lat, cover * keep], dim=3)

    def forward(self, z: torch.Tensor, s: torch.Tensor, cond: dict) -> torch.Tensor:
        return self.dit(z, s, cond)

    def source(
        self, render_lat: torch.Tensor | None, shape, generator: torch.Generator | None, sampling: bool = False
    ) -> torch.Tensor:
        """The flow's s = 0 end: seeded noise, or (bridge) the render latent plus `source_noise` (training) or
        `sample_noise` (sampling) of it."""
        noise = torch.randn(tuple(shape), generator=generator)
        if self.cfg.source == "noise":
            return noise
        if render_lat is None or tuple(render_lat.shape) != tuple(shape):
            raise ValueError(f"a render-bridge enhancer needs the render latent of shape {tuple(shape)}")
        std = self.cfg.sample_noise if sampling else self.cfg.source_noise
        return render_lat.float() + std * noise

    def loss(
        self,
        target: torch.Tensor,
        cond: dict,
        generator: torch.Generator | None = None,
        render_lat: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Rectified-flow loss with the DiT's timestep shift; cond["drop"] (CFG dropout) is set by the caller.
        `render_lat` (B,T,V,c,h,w) is the bridge's source (needed when cfg.source == "render")."""
        eps = self.source(render_lat, target.shape, generator)
        s = rflow.sample_near_source_s(target.shape[0], generator) if self.cfg.source == "render" else None
        return rflow.training_loss(
            self, target, cond, shift=self.cfg.dit.sampler_shift, generator=generator, eps=eps, s=s
        )

    @torch.no_grad()
    def sample(
        self,
        cond: dict,
        shape: tuple[int, ...],
        steps: int | None = None,
        seed: int = 0,
        callback=None,
        init: torch.Tensor | None = None,
        start: float = 0.0,
    ) -> torch.Tensor:
        """Euler sampling from seeded noise -> refined latents of `shape` (B,T,V,c,h,w).

        `start` > 0 (with `init`, e.g. the render latent) begins at flow time s0 = start from
        z(s0) = (1 - s0) eps + s0 init instead of pure noise (SDEdit-style): the model then only finishes the
        trajectory. Implemented by re-timing, s' = s0 + (1 - s0) s, so rflow.sample is reused as is.
        A render-bridge enhancer (cfg.source == "render") starts from `init`, the render latent, instead."""
        if not 0.0 <= start < 1.0:
            raise ValueError(f"start must be in [0, 1), got {start}")
        gen = torch.Generator().manual_seed(seed)
        steps = steps or self.cfg.dit.sampler_steps
        if self.cfg.source == "render":
            if start:
                raise ValueError("a render-bridge enhancer already starts from the render (no SDEdit start)")
            z0 = self.source(init, shape, gen, sampling=True)
            return rflow.sample(self, z0, cond, steps=steps, shift=self.cfg.dit.sampler_shift, callback=callback)
        noise = torch.randn(shape, generator=gen)
        if start == 0.0:
            return rflow.sample(self, noise, cond, steps=steps, shift=self.cfg.dit.sampler_shift, callback=callback)
        if init is None or tuple(init.shape) != tuple(shape):
            raise ValueError("sampling from start > 0 needs `init` of the latent shape")
        z0 = rflow.interpolate(init.float(), noise, torch.full((shape[0],), start))
        retimed = lambda z, s, c: (1.0 - start) * self(z, start + (1.0 - start) * s, c)  # noqa: E731
        return rflow.sample(retimed, z0, cond, steps=steps, shift=self.cfg.dit.sampler_shift, callback=callback)


# --- weights ---------------------------------------------------------------------------------------------------------


def save_enhancer(model: Enhancer, vae, path, meta: dict | None = None):
    """fp32 safetensors holding the enhancer AND the frozen VAE it was trained against (tensors prefixed "vae."),
    so the pair cannot drift apart; configs and provenance in the metadata."""

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().float().contiguous().clone() for k, v in model.state_dict().items()}
    state.update({f"vae.{k}": v.detach().float().contiguous().clone() for k, v in vae.state_dict().items()})
    md = {
        "kind": "enhancer",
        "config": json.dumps(config_to_dict(model.cfg)),
        "vae_config": json.dumps(dataclasses.asdict(vae.cfg)),
    }
    md.update({k: json.dumps(v) for k, v in (meta or {}).items()})
    return write_safetensors(state, path, md)


def load_enhancer(path) -> tuple[Enhancer, nn.Module]:
    """-> (enhancer, its VAE), both in eval mode; `enhancer.meta` holds the file's metadata."""

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"enhancer weights {path} not found")
    with safe_open(str(path), framework="pt") as f:
        md = dict(f.metadata() or {})
        if md.get("kind") != "enhancer" or "vae_config" not in md:
            raise ValueError(f"{path}: not an enhancer weight file (kind={md.get('kind')!r})")
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    model = Enhancer(config_from_dict(json.loads(md["config"])))
    vae = MultiModalVAE(from_dict(VAEConfig, json.loads(md["vae_config"])))
    vae.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("vae.")})
    model.load_state_dict({k: v for k, v in tensors.items() if not k.startswith("vae.")})
    if vae.cfg.latent_channels != model.cfg.latent_channels:
        raise ValueError(
            f"{path}: VAE has {vae.cfg.latent_channels} latent channels, the enhancer expects "
            f"{model.cfg.latent_channels}"
        )
    model.meta = {k: (v if k == "kind" else json.loads(v)) for k, v in md.items()}
    return model.eval(), vae.eval()


# --- inference ------------------------------------------------------------------------------------------------------

BLENDS = ("none", "holes", "mix")


def _resize(x: torch.Tensor, size: tuple[int, int], mode: str) -> torch.Tensor:
    """(N,C,H,W) -> (N,C,*size); `max` keeps 1-pixel sketch lines when shrinking."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    if mode == "max":
        return F.adaptive_max_pool2d(x, size) if x.shape[-2] >= size[0] else F.interpolate(x, size, mode="nearest")
    return F.interpolate(x, size, mode="bilinear", align_corners=False, antialias=True)


def windows(T: int, n: int) -> list[tuple[int, int]]:
    """Frame windows of length n covering 0..T-1 (the last one shifted back to stay full when T >= n)."""
    if T <= n:
        return [(0, T)]
    starts = list(range(0, T - n + 1, n))
    if starts[-1] + n < T:
        starts.append(T - n)
    return [(s, s + n) for s in starts]


@torch.no_grad()
def enhance(
    model: Enhancer,
    vae,
    render: np.ndarray,
    alpha: np.ndarray,
    sketch: np.ndarray,
    boxes: dict,
    traj: np.ndarray,
    caption_emb: torch.Tensor,
    steps: int | None = None,
    seed: int = 0,
    use_render: bool = True,
    blend: str = "none",
    callback=None,
    timings: dict | None = None,
    start: float = 0.0,
) -> np.ndarray:
    """Refine a novel-track render. render (T,V,H,W,3) uint8, alpha (T,V,H,W), sketch (T,V,H,W,3) in {0,1},
    boxes {box_corners (T,N,8,3), box_cls, box_moving, box_mask (T,N)} in the shifted ego frames, traj (T,4,4)
    relative to frame 0, caption_emb (384,) -> refined (T,V,H,W,3) uint8.

    Images are resized to the model's resolution and back; frames run in windows of the model's clip length
    (trajectory re-based on each window's first frame). blend "none" returns the model's output (the paper);
    "holes" keeps the render where its alpha covers the pixel and takes the model's output in the holes; "mix" the
    file's pixel mix (pixel_mix.py; `default_blend`). `start` > 0 starts the sampler from the noised render latent instead of pure noise (see Enhancer.sample).
    `timings` (a dict) receives seconds per stage: encode, denoise, decode."""
    if blend not in BLENDS:
        raise ValueError(f"blend must be one of {BLENDS}, got {blend!r}")
    cfg = model.cfg
    if cfg.source == "render" and not use_render:
        raise ValueError("a render-bridge enhancer refines a render: use_render=False (version A) needs a noise one")
    T, V, H, W = render.shape[:4]
    if V != cfg.data.views:
        raise ValueError(f"enhancer: trained on {cfg.data.views} views, got {V}")
    if alpha.shape != (T, V, H, W) or sketch.shape[:2] != (T, V):
        raise ValueError(f"enhancer: render {render.shape}, alpha {alpha.shape} and sketch {sketch.shape} disagree")
    h, w = cfg.data.height, cfg.data.width
    f = vae.cfg.downsample
    N = cfg.data.max_boxes
    tm = {"encode": 0.0, "denoise": 0.0, "decode": 0.0}
    out = np.zeros((T, V, h, w, 3), np.uint8)
    img = lambda a: torch.as_tensor(np.asarray(a)).float().reshape(-1, H, W, a.shape[-1]).permute(0, 3, 1, 2)  # noqa
    r_small = _resize(img(render) / 255.0, (h, w), "area")
    Hs, Ws = sketch.shape[2:4]
    s_small = _resize(
        torch.as_tensor(np.asarray(sketch, np.float32)).reshape(-1, Hs, Ws, 3).permute(0, 3, 1, 2), (h, w), "max"
    )
    a_small = _resize(torch.as_tensor(np.asarray(alpha, np.float32)).reshape(-1, 1, H, W), (h, w), "area")
    wins = windows(T, cfg.data.frames)
    for wi, (t0, t1) in enumerate(wins):
        n = t1 - t0
        sl = slice(t0 * V, t1 * V)
        c0 = time.perf_counter()
        r_lat = encode_images(vae, r_small[sl].permute(0, 2, 3, 1))
        s_lat = encode_images(vae, s_small[sl].permute(0, 2, 3, 1))
        cov = F.avg_pool2d(a_small[sl].clamp(0, 1), f)
        lat = lambda z: z.reshape(1, n, V, *z.shape[1:])  # noqa: E731
        rel = np.linalg.inv(traj[t0].astype(np.float64)) @ traj[t0:t1].astype(np.float64)
        cond = {
            "box_corners": torch.as_tensor(boxes["box_corners"][t0:t1, :N])[None].float(),
            "box_cls": torch.as_tensor(boxes["box_cls"][t0:t1, :N])[None].long(),
            "box_moving": torch.as_tensor(boxes["box_moving"][t0:t1, :N])[None].bool(),
            "box_mask": torch.as_tensor(boxes["box_mask"][t0:t1, :N])[None].bool(),
            "traj": torch.as_tensor(rel, dtype=torch.float32)[None],
            "caption": torch.as_tensor(caption_emb).float().reshape(1, -1),
            "control": Enhancer.control(lat(r_lat), lat(s_lat), lat(cov), use_render),
        }
        c1 = time.perf_counter()
        cb = None if callback is None else (lambda k, K, wi=wi: callback((wi + k / K) / len(wins)))
        z = model.sample(
            cond,
            (1, n, V, cfg.latent_channels, h // f, w // f),
            steps,
            seed + t0,
            cb,
            init=lat(r_lat) if start > 0 or cfg.source == "render" else None,
            start=start,
        )
        c2 = time.perf_counter()
        out[t0:t1] = decode_latents(vae, z.reshape(n * V, *z.shape[3:])).reshape(n, V, h, w, 3)
        c3 = time.perf_counter()
        tm["encode"] += c1 - c0
        tm["denoise"] += c2 - c1
        tm["decode"] += c3 - c2
    c0 = time.perf_counter()
    low = None
    if blend == "mix" and (h, w) != (H, W):  # the mix's gate is read at the model image
        r_low = (r_small * 255).round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()
        low = (r_low.reshape(T, V, h, w, 3), a_small.reshape(T, V, h, w).numpy())
    out = finish(out, render, alpha, blend, model.mix, low)
    tm["decode"] += time.perf_counter() - c0
    if timings is not None:
        timings.update(tm)
    return out


def default_blend(model: Enhancer) -> str:
    """ "mix" when the file bundles a pixel mix, else "holes"."""
    return "mix" if model.mix is not None else "holes"


def finish(
    refined: np.ndarray,
    render: np.ndarray,
    alpha: np.ndarray,
    blend: str = "none",
    mix_net: PixelMix | None = None,
    low: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Model-resolution output (T,V,h,w,3) -> the render's size (bilinear), then the blend: "none" keeps the model's
    output, "holes" keeps the render where its alpha covers a pixel (alpha-weighted), "mix" the pixel mix
    (`mix_net`, pixel_mix.py) whose gate is read at the model image from `low` = (render, alpha), the render as the
    model read it (default: `render`, area-resized to (h, w) when larger)."""
    if blend not in BLENDS:
        raise ValueError(f"blend must be one of {BLENDS}, got {blend!r}")
    T, V, h, w, _ = refined.shape
    H, W = render.shape[2:4]
    out = refined
    if (h, w) != (H, W):
        up = _resize(torch.from_numpy(refined).float().reshape(-1, h, w, 3).permute(0, 3, 1, 2), (H, W), "bilinear")
        out = up.permute(0, 2, 3, 1).round().clamp(0, 255).to(torch.uint8).numpy().reshape(T, V, H, W, 3)
    if blend == "holes":
        a = np.clip(np.asarray(alpha, np.float32), 0, 1)[..., None]
        out = np.round(a * render + (1 - a) * out).astype(np.uint8)
    elif blend == "mix":
        if mix_net is None:
            raise ValueError('blend "mix" needs an enhancer file with a pixel mix (this one has none)')
        r_low, a_low = low if low is not None else (render, alpha)
        if r_low.shape[2:4] != (h, w):  # area-resized to the model image, as `enhance` reads the render
            Hl, Wl = r_low.shape[2:4]
            r = _resize(
                torch.from_numpy(np.ascontiguousarray(r_low)).float().reshape(-1, Hl, Wl, 3).permute(0, 3, 1, 2),
                (h, w),
                "area",
            )
            a = _resize(torch.from_numpy(np.asarray(a_low, np.float32)).reshape(-1, 1, Hl, Wl), (h, w), "area")
            r_low = r.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy().reshape(T, V, h, w, 3)
            a_low = a.numpy().reshape(T, V, h, w)
        out = mix(mix_net, refined, r_low, a_low, render, alpha)
    return out
