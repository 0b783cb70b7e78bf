"""Inference glue of the networks, used by `worldsplat.pipeline.scene` (modes "reconstruct" and "generate").

Contract
--------
    models = load_models(weights_dir=None)           # worldsplat_models.weights.weights_dir() by default; cached
    available_modes(weights_dir=None) -> ["reconstruct", "generate"] subset whose weights exist
    dec = reconstruct(clip, models=None, gaussians=None)  # clip: worldsplat.world.simulate(...) output (rgb,
                                                      #   depth, dynamic, rig, ego_to_world, frame_times, caption)
    dec = generate(conditions, steps=8, seed=0, models=None, rig=None, frame_times=None, progress=None,
                   gaussians=None)
                                                      # conditions: world.conditions() (sketch, boxes, ego_traj,
                                                      #   caption); rig: list[RigCamera] (default: default_rig)
    scene = to_scene4d(dec, meta=None)                # paper eq. 3 as served, window by window (aggregate_windows)
Weights: `<role>_small.safetensors` for role in vae | decoder | dit | prior, and optionally decoder_reconstruct (a
per-pixel Gaussian decoder serving reconstruct mode only; without it reconstruct uses `decoder`).
`dec` is a DecodedFrames: gaussians[t][v] (worldsplat.gaussians.Gaussians, world metres, extras[:, 0] = dynamic
probability) and dynamic_logits[t][v] (N,), plus frame_times, rig, ego_to_world and the normalised latent L.
`gaussians` says how L becomes Gaussians (None: the mode's served source, GAUSSIANS): "decoder": the latent Gaussian
decoder's grid; "decoder2x" / "decoder4x": that grid refined (`gs_decoder.refine_fields`); "pixels": the VAE's
decoding of L lifted one opaque Gaussian per pixel of the rig's image (`pipeline.pixels`; served in both modes);
"pixels_decoder_depth": the same at the latent decoder's depth.

The models run at their trained geometry (DataConfig: 64x112 per view, 6 views, 4-frame windows): inputs of other
sizes are resampled to it (the Gaussians live in world metres, so they render at any resolution), except that
reconstruct's lifted pixels run the convolutional VAE at the clip's own image (`reconstruct_size`), and longer clips
are processed in consecutive 4-frame windows (the last one padded by repeating its final frame). The rig must have
the 6 default cameras in order. Deterministic for a given seed; float32 on CPU; `torch.no_grad` throughout.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.core.camera import CAMERA_NAMES, default_rig
from worldsplat.gaussians import Gaussians, Scene4D
from worldsplat.gaussians.aggregate import AggregateStats, Economy, aggregate_windows
from worldsplat.gaussians.colour_fit import JointFit, fit_scene_static, fit_window
from worldsplat.pipeline import backdrop, pixels
from worldsplat.pipeline.conditions import pack_boxes, rig_tensors, sketch_rgb
from worldsplat.pipeline.onnx import ensure_exported, requested_backend, serving_backend, use_onnx
from worldsplat.pipeline.snaps import (
    LAYOUT_SNAP_LOG_TOL,
    narrow_before_agent_edges,
    snap_agents_to_layout,
    snap_to_layout,
    snap_to_map,
)
from worldsplat.world.layout_maps import layout_regions, take_layout
from worldsplat_models import rflow
from worldsplat_models.conditions import encode_captions
from worldsplat_models.configs import DataConfig, get_config
from worldsplat_models.dit import dropped
from worldsplat_models.gs_decoder import refine_fields
from worldsplat_models.vae import normalize_depth
from worldsplat_models.weights import load_weights, read_metadata
from worldsplat_models.weights import weights_dir as default_weights_dir

SIZE = "small"
# How latents become Gaussians, per mode: "pixels" lifts the VAE's decoded colour, depth and mask per pixel of the
# rig's image (as many Gaussians per served pixel as the oracle, tiling at any display size); "decoder" is the latent
# Gaussian decoder's grid (one translucent Gaussian per model pixel on the 2x latents), "decoder2x" / "decoder4x" its
# grid refined (`DECODER_REFINE`). Both modes serve pixels: the 2x VAE's decoding keeps what the page draws (generate
# on the page's scenes 1.63 Gaussians per served px, 17.77 dB / SSIM 0.560, 37 of 38 agents seen; web/docs/models.md
# "Served Gaussians per mode"). Generate served the grid while it drew 4x latents, whose decoding was blotched
# (CHANGELOG.md).
GAUSSIANS = {"reconstruct": "pixels", "generate": "pixels"}
# The lifting's per-view colour fit (`gaussians.lift.fit_colours`, FISTA steps) where a mode does not take the
# lifting's own (`pipeline.pixels.FIT_ITERS`). Generate's window fit
# (JOINT_FIT) starts from the lifted colours and leaves nothing for it: on the 2x stack
# (web/docs/downstream.md "A generator of the 2x latents") the judge read the same with and without it (0.63 of the
# ground truth at the rig, test clips 0-7) at 2.5-3 s less a default scene.
# Reconstruct's joint fit keeps a ridge towards the lifting's fitted colours (measured with them).
VIEW_FIT = {"generate": 0}
# Per learned mode, its joint colour fit (`gaussians.colour_fit.JointFit`; in the served scene, `pipeline.scene`,
# and in `aggregate_decoded`): its static Gaussians fitted to the images its views were lifted from at the keyframe
# cameras, so the nearer frames' copies of a surface no longer blend frame t's view away (web/docs/models.md, "What
# bounds reconstruct at 0 m"); a mode not named is not fitted. Only lifted sources carry the images
# (`DecodedFrames.images`). Reconstruct fits each window (its ridge chosen on its page scenes, `evaluation.scene_quality`,
# 2x canvas, static PSNR / luma SSIM, a 4x VAE: unfitted 22.87 / 0.710, ridge 0 22.83 / 0.697, 0.3 23.22 /
# 0.716, 1 23.27 / 0.718, 3 23.23 / 0.717; the served 2x VAE: unfitted 24.52 / 0.742, ridge 1 24.83 /
# 0.751; the whole scene at the end 24.73 / 0.748). Generate fits the whole scene: its first window is frame 0 alone
# and holds 60 % of the statics, which a window's fit would fix to frame 0 (the judge, `evaluation.generate_gap`,
# test clips 0-7 at the rig, / the ground truth, the 2x stack: per window 0.61-0.63, whole scene 0.72-0.75;
# web/docs/downstream.md "A generator of the 2x latents"), stopped after 10 FISTA steps (the page's scenes,
# test:0-2 + the default preset, 5 / 10 / 20 steps: 17.55 / 17.50 / 17.43 dB, luma SSIM 0.528 / 0.512 / 0.489, the
# judge at the rig 0.69 / 0.70 / 0.70 of the ground truth; the fit reads the sampled images' noise as colour the
# longer it runs), about 1 s less a default scene than 20.
JOINT_FIT = {"reconstruct": JointFit("window", 1.0), "generate": JointFit("scene", 0.0, 10)}


@dataclass(frozen=True)
class RegionTemperature:
    """The sampler's scale of a prior-residual DiT's sample per layout region (L = mu + residual_scale * t * sample;
    `world.layout_maps.layout_regions`); `other` is every cell outside the three, None the weights'
    `residual_temperature`. Where the conditions fix what a surface looks like (the world's road is plain asphalt
    with the painted lines the maps carry; the open sky a plain gradient), the prior's mean is all there is to draw:
    a sample adds texture the world does not have, which the judge reads as cars on the road. Agents keep the DiT's
    trained scale (their contrast with the street is what makes them seen). Measured on the page's scenes and the
    judge (web/docs/models.md, "Where the sampler draws"): 0.8 everywhere 17.50 dB / SSIM 0.512, 36 of 38 agents, the
    judge 0.70 / 0.56 of the ground truth at 0 / +2 m; road and sky at 0, agents at 1: 17.59 / 0.532, 35 of 38, 0.75 /
    0.60."""

    road: float | None = 0.0
    sky: float | None = 0.0
    agents: float | None = 1.0
    other: float | None = None

    @classmethod
    def parse(cls, text: str) -> RegionTemperature:
        """ "road=0,sky=0,agents=1,other=0.5" (a region left out or "none": the weights' temperature there); "flat":
        the weights' temperature everywhere."""
        if text.strip() == "flat":
            return cls(None, None, None, None)
        names = [f.name for f in dataclasses.fields(cls)]
        values: dict[str, float | None] = dict.fromkeys(names)
        for part in filter(None, (p.strip() for p in text.split(","))):
            name, _, value = part.partition("=")
            if name not in names or not value:
                raise ValueError(f"temperature {part!r}: expected region=value, region one of {', '.join(names)}")
            try:
                values[name] = None if value == "none" else float(value)
            except ValueError:
                raise ValueError(f"temperature {part!r}: {value!r} is not a number or none") from None
        return cls(**values)

    def field(self, layout: torch.Tensor, hw: tuple[int, int], base: float) -> torch.Tensor:
        """(..., 1, h, w) temperatures on the latent grid `hw` from layout maps (..., C, H, W): `other` (or `base`)
        everywhere, the road's and sky's share of each cell blended towards theirs, a cell any agent touches the
        agents'."""
        lead = layout.shape[:-3]
        regions = layout_regions(layout.reshape(-1, *layout.shape[-3:]).float())
        t = torch.full((regions["road"].shape[0], 1, *hw), float(base if self.other is None else self.other))
        for name, pool in (
            ("road", F.adaptive_avg_pool2d),
            ("sky", F.adaptive_avg_pool2d),
            ("agents", F.adaptive_max_pool2d),
        ):
            value = getattr(self, name)
            if value is not None:
                share = pool(regions[name], hw)
                t = t + (value - t) * share
        return t.reshape(*lead, 1, *hw)


# The served sampler's temperatures (`sample_latents` reads it at each call; the evaluation commands' --temperature).
REGION_TEMPERATURE = RegionTemperature()
GAUSSIAN_SOURCES = ("pixels", "decoder", "decoder2x", "decoder4x", "pixels_decoder_depth")
# The latent decoder's grid refined r x (`GaussianDecoder.forward(refine=r)`): its raw maps up-sampled bilinearly, the
# pixel guide read at the finer grid, each cell r x r Gaussians of 1/r the footprint on the decoder's surface.
DECODER_REFINE = {"decoder": 1, "decoder2x": 2, "decoder4x": 4}
# The sources lifted one opaque Gaussian per served pixel; "pixels_decoder_depth" lifts the VAE's colour at the
# latent decoder's depth (its grid refined 2x: the model image), which the frames of a window agree on better.
LIFTED = ("pixels", "pixels_decoder_depth")


@dataclass
class Models:
    vae: torch.nn.Module | None
    decoder: torch.nn.Module | None
    dit: torch.nn.Module | None
    data: DataConfig
    version: str  # short hash of the weight files (for cache keys), "-onnx" appended where onnxruntime serves
    weights_dir: Path
    prior: torch.nn.Module | None = None  # the layout prior, for a DiT that generates its residual
    # A finer decoder for reconstruct mode only (one Gaussian per model pixel): its latents come from the VAE
    # encoder, so it may read the pixel guide closely; on generated latents it would read their noise as geometry.
    decoder_reconstruct: torch.nn.Module | None = None

    @property
    def modes(self) -> list[str]:
        out = []
        if self.vae is not None and self.decoder is not None:
            out.append("reconstruct")
            if self.dit is not None and (self.prior is not None or not needs_prior(self.dit)):
                out.append("generate")
        return out

    def decoder_for(self, mode: str) -> torch.nn.Module:
        """The Gaussian decoder that serves `mode` ("reconstruct" | "generate")."""
        if mode == "reconstruct" and self.decoder_reconstruct is not None:
            return self.decoder_reconstruct
        return self.decoder


def needs_prior(dit) -> bool:
    return getattr(dit.cfg, "target", "latent") == "prior_residual"


@dataclass
class DecodedFrames:
    gaussians: list[list]  # [t][v] Gaussians
    dynamic_logits: list[list]  # [t][v] (N,) tensors
    frame_times: np.ndarray
    rig: list
    ego_to_world: np.ndarray
    latents: torch.Tensor  # (T, V, C, h, w) normalised L
    meta: dict = field(default_factory=dict)
    model_width: int | None = None  # the models' image width (the decoded economy's unit); None: the rig's
    windows: list[list[int]] | None = None  # the frame windows decoded together (None: one window of every frame)
    source: str = "decoder"  # how the Gaussians were made: GAUSSIAN_SOURCES (lifted per rig pixel, or a grid)
    # lifted sources: per frame t, the images (V, H, W, 3) float in [0, 1] its views were lifted from (the targets
    # of the scene's joint colour fit, `pipeline.scene`); None for a grid
    images: dict[int, np.ndarray] | None = None
    # generate: [t][v] static Gaussians of what stands behind the agents (`pipeline.backdrop`), which the agents'
    # claims leave alone; None where not drawn
    backdrop: list[list] | None = None

    def frame(self, t: int):
        return Gaussians.cat(self.gaussians[t])


_CACHE: dict[str, Models] = {}


# role -> the model kind its file holds; `<role>_<SIZE>.safetensors` in the weights folder
ROLES = {
    "vae": "vae",
    "decoder": "decoder",
    "dit": "dit",
    "prior": "prior",
    "decoder_reconstruct": "decoder",
}


def weight_paths(weights_dir: str | Path | None = None) -> dict[str, Path]:
    d = Path(weights_dir) if weights_dir is not None else default_weights_dir()
    return {role: d / f"{role}_{SIZE}.safetensors" for role in ROLES}


def available_modes(weights_dir: str | Path | None = None) -> list[str]:
    p = weight_paths(weights_dir)
    out = []
    if p["vae"].exists() and p["decoder"].exists():
        out.append("reconstruct")
        if p["dit"].exists() and (
            p["prior"].exists() or read_metadata(p["dit"])["config"].get("target") != "prior_residual"
        ):
            out.append("generate")
    return out


def load_models(weights_dir: str | Path | None = None, backend: str | None = None) -> Models:
    """Load whichever of vae / decoder / dit / prior exist (missing ones are None; `Models.modes` says what works).
    Cached per folder, backend and state of its weight files (a re-shipped or removed file loads anew).
    backend (None: $WORLDSPLAT_BACKEND, else "auto"; `worldsplat serve --backend` sets it):
      "onnx"  the VAE, the DiT step, the Gaussian decoders and the layout prior run in onnxruntime from
              <weights_dir>/onnx (exported here when missing or stale; same outputs within the documented 1e-3
              parity tolerance; shapes a graph was not exported at run in torch: `pipeline.onnx.use_onnx`);
      "torch" torch eager (the reference the models were trained and tested in);
      "auto"  onnx where the graphs are usable (`pipeline.onnx.serving_backend`: current, or stale and
              re-exportable), else torch with one log line saying why. onnxruntime serves the default preset's
              generate scene about 1.2x and its reconstruct scene 1.35x faster (web/docs/models.md, "ONNX serving")."""
    backend = requested_backend(backend)
    paths = weight_paths(weights_dir)
    folder = paths["vae"].parent
    stamp = [(p.name, p.stat().st_mtime_ns, p.stat().st_size) for p in paths.values() if p.exists()]
    if backend == "auto":  # the graphs' stamp too: `worldsplat export-onnx` run later serves them on the next load
        onnx_stamp = folder / "onnx" / "VERSION"
        stamp.append(onnx_stamp.read_text().strip() if onnx_stamp.exists() else None)
    key = f"{folder.resolve()}:{backend}:{stamp}"
    if key in _CACHE:
        return _CACHE[key]
    h = hashlib.sha256()
    loaded = {}
    for k, p in paths.items():
        if p.exists():
            loaded[k] = load_weights(p, ROLES[k])
            h.update(p.read_bytes())
        else:
            loaded[k] = None
    m = Models(
        loaded["vae"],
        loaded["decoder"],
        loaded["dit"],
        get_config(SIZE).data,
        h.hexdigest()[:12],
        folder,
        loaded["prior"],
        loaded["decoder_reconstruct"],
    )
    if backend == "auto":
        backend = serving_backend(m)
    if backend == "onnx":
        ensure_exported(m)  # derived from the weights, exported here when set-up has not done it
        use_onnx(m, folder / "onnx")
    _CACHE[key] = m
    return m


def _require(models: Models | None, mode: str) -> Models:
    models = models or load_models()
    if mode not in models.modes:
        raise FileNotFoundError(
            f"{mode} mode needs weights that are missing in {models.weights_dir} (have modes: {models.modes or 'none'})"
        )
    return models


# --- geometry helpers ----------------------------------------------------------------------------------------------


def _resize(x: torch.Tensor, hw: tuple[int, int], mode: str) -> torch.Tensor:
    """(N, C, H, W) -> (N, C, h, w). mode: area | nearest | max (thin sketch lines survive down-sampling)."""
    if tuple(x.shape[-2:]) == tuple(hw):
        return x
    if mode == "max" and x.shape[-2] >= hw[0]:
        return F.adaptive_max_pool2d(x, hw)
    if mode == "area" and x.shape[-2] >= hw[0]:
        return F.adaptive_avg_pool2d(x, hw)
    return F.interpolate(x, size=hw, mode="nearest" if mode in ("nearest", "max") else "bilinear", align_corners=False)


def _windows(T: int, F_: int, pad: bool = True) -> list[list[int]]:
    """Consecutive windows of F_ frame indices covering 0..T-1; the last is padded with its final frame (`pad`), or
    left short (the networks take any T <= their max_frames; a short window then costs its own frames only)."""
    out = []
    for s in range(0, T, F_):
        idx = list(range(s, min(T, s + F_)))
        out.append(idx + [idx[-1]] * (F_ - len(idx)) if pad else idx)
    return out


def _check_rig(rig, V: int) -> None:
    names = tuple(rc.name for rc in rig)
    if len(rig) != V or names != CAMERA_NAMES[:V]:
        raise ValueError(f"the models were trained on the default {V}-camera rig {CAMERA_NAMES}; got {names}")


def pixel_guide(models: Models, L: torch.Tensor) -> torch.Tensor:
    """The decoder's pixel guide: the VAE's own decoding of L (T,V,C,h,w) -> (T,V,5,H,W) = rgb [-1,1],
    normalised depth, mask probability."""
    T, V = L.shape[:2]
    rgb, dn, m = models.vae.decode_joint(L.reshape(T * V, *L.shape[2:]).float())
    g = torch.cat([rgb, dn, m], 1)
    return g.reshape(T, V, *g.shape[1:])


def layout_size(models: Models) -> tuple[int, int] | None:
    """(W, H) of the layout maps a layout-control DiT or the layout prior reads, or None when the DiT reads the sketch
    latent."""
    if models.prior is None and (models.dit is None or not models.dit.cfg.control_hint):
        return None
    return (models.data.width, models.data.height)


# The decoders were supervised at the model image only, so nothing finer than its pixel was ever seen: each decoded
# Gaussian's std is widened by this many model pixels (in quadrature, as Mip-Splatting's 3D filter bounds a Gaussian
# by its training sampling rate), so a display larger than the model image shows no gaps between them. The decoder's
# grid on the 4x latents was every second model pixel: at 0.3 its Gaussians showed as a square grid over facades and
# sky at 4x the served image; wider, the road before an agent spills over it. Generate on the 4x latents, test:0-2 +
# the default preset, frame 0 at 2x (web/docs/models.md, "Scale floor of the decoder's grid"), floor 0.3 / 0.6 / 0.8
# / 1.0: luma SSIM 0.466 /
# 0.481 / 0.486 / 0.488, agents seen 30 / 31 / 29 / 22 of 38, silhouette IoU 0.834 / 0.814 / 0.783 / 0.736.
DECODED_SCALE_FLOOR_MODEL_PX = 0.6


# The same floor for the decoder's grid refined r x (`DECODER_REFINE`), in model pixels. 2x on the default preset
# (web/docs/models.md, "generate: the decoder's grid refined 2x"), floor 0.3 / 0.6 / 0.8: static PSNR 15.09 / 15.08 /
# 15.12 dB, luma SSIM 0.511 / 0.541 / 0.551; at 4x the served image a dot lattice / fine vertical lines / faint ones.
# Over test:0-2 + the default preset (frame 0) 0.8 / 0.6: 16.86 / 16.91 dB, SSIM 0.482 / 0.481, agents seen 34 / 35
# of 38: four Gaussians per coarse cell as wide as it, at its opacity, stack into a haze over the agents beside a
# nearer surface (test:1's parked car 9 covered 0.70 at 0.8); the rest of that haze: `snaps.narrow_before_agent_edges`.
REFINED_SCALE_FLOOR_MODEL_PX = {1: DECODED_SCALE_FLOOR_MODEL_PX, 2: 0.6, 4: 0.6}


def scale_floor(
    scales: torch.Tensor, depth: torch.Tensor, fx_model: float, floor_px: float = DECODED_SCALE_FLOOR_MODEL_PX
) -> torch.Tensor:
    """scales (N,3) of Gaussians at camera depth (N,) -> widened by `floor_px` model pixels (fx_model: the camera's
    focal length in model-image pixels, so one model pixel spans depth / fx_model metres)."""
    floor = floor_px * depth / fx_model
    return torch.sqrt(scales**2 + floor[:, None] ** 2)


def gaussian_source(gaussians: str | None, mode: str = "generate") -> str:
    """`gaussians` checked (one of GAUSSIAN_SOURCES; None: the source `mode` serves, GAUSSIANS)."""
    g = GAUSSIANS[mode] if gaussians is None else gaussians
    if g not in GAUSSIAN_SOURCES:
        raise ValueError(f"gaussians must be one of {', '.join(GAUSSIAN_SOURCES)}, got {gaussians!r}")
    return g


def decode_gaussians(
    models: Models,
    L: torch.Tensor,
    rig,
    ego_to_world: np.ndarray,
    frame_times,
    meta: dict,
    pad: bool = True,
    decoder: torch.nn.Module | None = None,
    gaussians: str | None = None,
    agents: np.ndarray | None = None,
) -> DecodedFrames:
    """L (T,V,C,h,w) normalised -> DecodedFrames (window by window; `pad`: see `_windows`). `gaussians`: "pixels"
    (`_lift_pixels`) or "decoder" (None: the one meta["mode"] serves, GAUSSIANS); `decoder`: which Gaussian decoder
    (default: the one for meta["mode"], `Models.decoder_for`); `agents`: lifted pixels' observed agent pixels (T, V,
    H, W) at the rig's image (`pipeline.pixels.lift_views`)."""
    d = models.data
    T = L.shape[0]
    wins = _windows(T, d.frames, pad)
    mode = meta.get("mode", "generate")
    source = "decoder" if decoder is not None else gaussian_source(gaussians, mode)
    images = None
    if source in LIFTED:
        dd = models.decoder_for(mode) if source == "pixels_decoder_depth" else None
        gs, logits, images = _lift_pixels(models, L, rig, ego_to_world, wins, dd, agents, VIEW_FIT.get(mode))
    else:
        refine = DECODER_REFINE[source]
        gs, logits = _decode_grid(models, L, rig, ego_to_world, wins, decoder or models.decoder_for(mode), refine)
    return DecodedFrames(
        gs,
        logits,
        np.asarray(frame_times, np.float64),
        list(rig),
        np.asarray(ego_to_world, np.float64),
        L,
        meta,
        model_width=L.shape[-1] * models.vae.cfg.downsample,
        windows=[sorted(set(w)) for w in wins],
        source=source,
        images=images,
    )


def _decode_grid(models: Models, L, rig, ego_to_world, wins, decoder, refine: int = 1) -> tuple[list[list], list[list]]:
    """The latent Gaussian decoder's Gaussians [t][v] and dynamic logits of L, window by window (`refine`: its grid
    r x finer, `GaussianDecoder.forward`; the scale floor shrinks with the cell)."""
    d = models.data
    intr, c2w = rig_tensors(rig, ego_to_world, (d.height, d.width))
    gs, logits = [[None] * len(rig) for _ in range(L.shape[0])], [[None] * len(rig) for _ in range(L.shape[0])]
    for win in wins:
        guide = pixel_guide(models, L[win])[None] if decoder.cfg.guide_channels else None
        args = (L[win][None], intr[win][None], c2w[win][None], (d.height, d.width))
        out = decoder(*args) if guide is None else decoder(*args, guide=guide)
        out = refine_fields(decoder.cfg, out, *args[1:], refine, guide)
        for i, t in enumerate(win):
            for v in range(len(rig)):
                f = {
                    k: x[0, i, v].reshape(-1, x.shape[-1]) if x.dim() == 6 else x[0, i, v].reshape(-1)
                    for k, x in out.items()
                }
                p = torch.sigmoid(f["dynamic_logit"])
                scales = scale_floor(
                    f["scales"], f["depth"], float(intr[t, v, 0]), REFINED_SCALE_FLOOR_MODEL_PX[refine]
                )
                gs[t][v] = Gaussians(f["means"], f["quats"], scales, f["opacities"], f["colors"], p[:, None])
                logits[t][v] = f["dynamic_logit"]
    return gs, logits


def _lift_pixels(
    models: Models, L, rig, ego_to_world, wins, depth_decoder=None, agents=None, fit_iters: int | None = None
) -> tuple[list[list], list[list], dict[int, np.ndarray]]:
    """The VAE's decoding of L, up-sampled to the rig's image, its ground onto the plane (`pixels.snap_to_ground`)
    and lifted per pixel (`pipeline.pixels`): Gaussians [t][v] (H*W each, row-major), dynamic logits (+-15 from
    the lifted mask) and per frame the images lifted (V, H, W, 3), window by window. `agents`: (T, V, H, W) bool,
    the observed agents' pixels (`lift_views`); `fit_iters`: the lifting's per-view colour fit (None: the lifting's own)."""
    d, V = models.data, len(rig)
    size = (rig[0].height, rig[0].width)
    gs, logits = [[None] * V for _ in range(L.shape[0])], [[None] * V for _ in range(L.shape[0])]
    images = {}
    for win in wins:
        frames = sorted(set(win))
        guide = pixel_guide(models, L[frames])
        rgb, depth, dyn = pixels.served_maps(guide.reshape(-1, *guide.shape[2:]), size, d.depth_near, d.depth_far)
        if depth_decoder is not None:
            depth = _decoder_depth(models, L, rig, ego_to_world, frames, depth_decoder, guide, size)
        cams = [rig[v].at(ego_to_world[t]) for t in frames for v in range(V)]
        depth = pixels.snap_to_ground(depth, dyn, cams)
        views = pixels.lift_views(
            rgb, depth, dyn, cams, None if agents is None else agents[frames].reshape(depth.shape), fit_iters
        )
        for i, t in enumerate(frames):
            images[t] = rgb[i * V : (i + 1) * V]
            for v in range(V):
                g = views[i * V + v]
                gs[t][v], logits[t][v] = g, (g.extras[:, 0] * 30.0 - 15.0)
    return gs, logits, images


def _decoder_depth(models: Models, L, rig, ego_to_world, frames, decoder, guide, size) -> np.ndarray:
    """The latent decoder's depth (grid refined 2x, camera z) of `frames`' views at the served grid (N, H, W)."""
    d = models.data
    intr, c2w = rig_tensors(rig, ego_to_world, (d.height, d.width))
    args = (L[frames][None], intr[frames][None], c2w[frames][None], (d.height, d.width))
    out = refine_fields(decoder.cfg, decoder(*args, guide=guide[None]), *args[1:], 2, guide[None])
    z = out["depth"][0]
    return pixels.depth_map(z.reshape(-1, 1, *z.shape[-2:]), size)


# --- modes -----------------------------------------------------------------------------------------------------------


# Reconstruct encodes and decodes its observation at the clip's own image (`reconstruct_size`), not at the model
# image: the VAE is convolutional and a mode that does not sample is not bound to the DiT's token count. The VAE's
# round trip of frame 0 against the world's 200x112 images (test:0, test:1, test:2, the default preset): through the
# 64x112 model image and up-sampled 25.27 / 24.10 / 20.74 / 23.15 dB, at 200x112 28.86 / 28.27 / 22.99 / 24.80 dB;
# the default reconstruct scene 1.8x the CPU time (web/docs/models.md, "reconstruct: the VAE at the clip's own
# image"). The area is capped (a 1600x900 clip would hold ~1 GB per activation of a window); larger clips are encoded
# at the largest size within the cap.
RECONSTRUCT_MAX_PIXELS = 200 * 112


def reconstruct_size(models: Models, hw: tuple[int, int]) -> tuple[int, int]:
    """The image (H, W) reconstruct runs the VAE at for a clip of image `hw`: the clip's own, scaled down to at most
    RECONSTRUCT_MAX_PIXELS, each side a multiple of the VAE's down-sampling (at least one latent)."""
    ds = models.vae.cfg.downsample
    s = min(1.0, (RECONSTRUCT_MAX_PIXELS / (hw[0] * hw[1])) ** 0.5)
    return tuple(max(ds, int(n * s) // ds * ds) for n in hw)


@torch.no_grad()
def encode_clip(models: Models, rgb, depth, dynamic, size: tuple[int, int] | None = None) -> torch.Tensor:
    """(T,V,H,W,3) uint8, (T,V,H,W) metres, (T,V,H,W) bool -> normalised L (T,V,C,h,w), the images resampled to
    `size` (H, W; None: the model image, `DataConfig`) first."""
    d = models.data
    rgb = torch.as_tensor(np.asarray(rgb))
    T, V = rgb.shape[:2]
    hw = (d.height, d.width) if size is None else tuple(size)
    x = _resize(rgb.reshape(T * V, *rgb.shape[2:]).permute(0, 3, 1, 2).float() / 127.5 - 1, hw, "area")
    dn = normalize_depth(torch.as_tensor(np.asarray(depth, np.float32)), d.depth_near, d.depth_far)
    dn = _resize(dn.reshape(T * V, 1, *dn.shape[2:]), hw, "area")
    m = torch.as_tensor(np.asarray(dynamic, bool)).reshape(T * V, 1, *rgb.shape[2:4]).float()
    m = (_resize(m, hw, "area") > 0.5).float()
    L = models.vae.encode_joint(x, dn, m)
    return L.reshape(T, V, *L.shape[1:])


@torch.no_grad()
def reconstruct(clip, models: Models | None = None, gaussians: str | None = None) -> DecodedFrames:
    """Reconstruct mode (paper §3.5): multi-view video + depth + dynamic masks -> VAE encoder -> Gaussians
    (`gaussians`: "pixels" or "decoder", see `decode_gaussians`), bypassing diffusion. The world supplies exact depth
    and masks where the paper used Metric3D and SegFormer. Lifted pixels ("pixels") run the VAE at the clip's own image
    (`reconstruct_size`); the latent decoder's sources at the model image it was trained on."""
    models = _require(models, "reconstruct")
    for k in ("rgb", "depth", "dynamic", "rig", "ego_to_world"):
        if getattr(clip, k, None) is None:
            raise ValueError(f"reconstruct: the clip has no {k!r}")
    _check_rig(clip.rig, models.data.views)
    source = gaussian_source(gaussians, "reconstruct")
    size = reconstruct_size(models, np.shape(clip.rgb)[2:4]) if source == "pixels" else None
    t0 = time.perf_counter()
    L = encode_clip(models, clip.rgb, clip.depth, clip.dynamic, size)
    t1 = time.perf_counter()
    dec = decode_gaussians(
        models,
        L,
        clip.rig,
        clip.ego_to_world,
        clip.frame_times,
        {"mode": "reconstruct", "model_version": models.version, "caption": getattr(clip, "caption", "")},
        gaussians=gaussians,
        agents=pixels.observed_agents(clip),
    )
    dec.meta["timing_s"] = {"vae_encode": t1 - t0, "gs_decoder": time.perf_counter() - t1}
    return dec


def condition_tensors(
    models: Models, conditions: dict, ego_to_world: np.ndarray, caption_emb: torch.Tensor | None = None
) -> dict:
    """world.conditions() -> the DiT's condition dict for all T frames (control = sketch latent)."""
    d = models.data
    for k in ("sketch", "boxes", "caption"):
        if k not in conditions:
            raise ValueError(f"generate: conditions lack {k!r}")
    sk = torch.from_numpy(sketch_rgb(conditions["sketch"]))
    T, V = sk.shape[:2]
    if V != d.views:
        raise ValueError(f"generate: {V} sketch views, the models expect {d.views}")
    if len(conditions["boxes"]) != T:
        raise ValueError(f"generate: boxes for {len(conditions['boxes'])} frames, sketch has {T}")
    if layout_size(models) is not None:
        # layout control: the per-camera layout maps in pixel space, read by the DiT's hint encoder
        if "layout" not in conditions:
            raise ValueError("generate: these models read layout maps; pass world.conditions(layout_size=...)")
        lay = torch.from_numpy(np.asarray(conditions["layout"], np.float32))
        ctl = _resize(lay.reshape(T * V, *lay.shape[2:]).permute(0, 3, 1, 2), (d.height, d.width), "area")
    else:
        sk = _resize(sk.reshape(T * V, *sk.shape[2:]).permute(0, 3, 1, 2), (d.height, d.width), "max") * 2 - 1
        c = models.vae.cfg.latent_channels
        vae = models.vae
        ctl = (vae.encode(sk) - vae.latent_mean[:c].view(1, -1, 1, 1)) / vae.latent_std[:c].view(1, -1, 1, 1)
    corners, cls, moving, mask = pack_boxes(conditions["boxes"], ego_to_world, d.max_boxes)
    if caption_emb is None:
        caption_emb = encode_captions([str(conditions["caption"])])[0]
    traj = np.asarray(conditions.get("ego_traj", ego_to_world), np.float32)
    out = {
        "box_corners": torch.from_numpy(corners),
        "box_cls": torch.from_numpy(cls),
        "box_moving": torch.from_numpy(moving),
        "box_mask": torch.from_numpy(mask),
        "traj": torch.from_numpy(traj),
        "caption": caption_emb.float(),
        "control": ctl.reshape(T, V, *ctl.shape[1:]),
    }
    if "layout_behind" in conditions and layout_size(models) is not None:  # the backdrop's maps (`pipeline.backdrop`)
        lay = torch.from_numpy(np.asarray(conditions["layout_behind"], np.float32))
        behind = _resize(lay.reshape(T * V, *lay.shape[2:]).permute(0, 3, 1, 2), (d.height, d.width), "area")
        out["control_behind"] = behind.reshape(T, V, *behind.shape[1:])
    return out


def window_cond(cond: dict, win: list[int]) -> dict:
    out = {k: v[win][None] for k, v in cond.items() if k not in ("caption", "control_behind")}
    out["caption"] = cond["caption"][None]
    return out


def prior_mean(models: Models, control: torch.Tensor, caption: torch.Tensor) -> torch.Tensor:
    """The layout prior's mu (B,T,V,C,h,w) from layout maps (B,T,V,Cl,H,W) with at least the prior's channels."""
    return models.prior.clip(take_layout(control, models.prior.cfg.in_channels).float(), caption)


@torch.no_grad()
def sample_latents(
    models: Models,
    cond: dict,
    steps: int = 8,
    seed: int = 0,
    cfg_scale: float | None = None,
    shift: float | None = None,
    progress: Callable[[float], None] | None = None,
    pad: bool = True,
    temperature: RegionTemperature | None = None,
) -> torch.Tensor:
    """Rectified-flow sampling of L (T,V,C,h,w), window by window; the noise depends only on (seed, window).
    A DiT that generates the layout prior's residual gives L = mu + residual_scale * t * sample, t per latent cell
    from `temperature` (None: REGION_TEMPERATURE).
    `pad` False: a clip shorter than a window (or its last window) is sampled at its own length (`_windows`)."""
    d, dcfg = models.data, models.dit.cfg
    T = cond["control"].shape[0]
    cfg_scale = dcfg.cfg_scale if cfg_scale is None else cfg_scale
    shift = dcfg.sampler_shift if shift is None else shift
    wins = _windows(T, d.frames, pad)
    ds = models.vae.cfg.downsample
    L = torch.zeros(T, d.views, dcfg.out_channels, d.height // ds, d.width // ds)
    for wi, win in enumerate(wins):
        c = window_cond(cond, win)
        layout = c["control"]
        if dcfg.control_hint:  # a DiT reads the first layout channels it was trained on (take_layout)
            c["control"] = take_layout(layout, dcfg.control_channels)
        g = torch.Generator().manual_seed(int(seed) * 1000 + wi)
        noise = torch.randn(1, len(win), d.views, dcfg.in_channels, *L.shape[-2:], generator=g)
        cb = None if progress is None else (lambda k, n, wi=wi: progress((wi + k / n) / len(wins)))
        z = rflow.sample(
            models.dit, noise, c, steps=steps, shift=shift, cfg_scale=cfg_scale, uncond=dropped(c), callback=cb
        )
        if needs_prior(models.dit):
            t = (temperature or REGION_TEMPERATURE).field(layout, z.shape[-2:], dcfg.residual_temperature)
            z = prior_mean(models, layout, c["caption"]) + dcfg.residual_scale * t * z
        L[win] = z[0]
    return L


def decode_generated(
    models: Models,
    L: torch.Tensor,
    cond: dict,
    rig,
    ego_to_world,
    frame_times,
    meta: dict,
    pad=True,
    snap=True,
    snap_log_tol: float = LAYOUT_SNAP_LOG_TOL,
    snap_agents: bool = True,
    snap_map: bool = True,
    gaussians: str | None = None,
) -> DecodedFrames:
    """Generated latents -> DecodedFrames as generate mode serves them (the evaluation scores exactly this):
    decode, then, where the models read layout maps, `snap_to_layout` (the road onto its plane) and
    `snap_to_map` (facades, trees and poles onto the map layer's surfaces) and `snap_agents_to_layout` (the agents onto
    their boxes, moving with them); snap=False skips all three, snap_map=False / snap_agents=False one of them.
    Lifted pixels snap per pixel against the layout maps up-sampled to the rig's image (`pixels.upsample_layout`)."""
    dec = decode_gaussians(models, L, rig, ego_to_world, frame_times, meta, pad=pad, gaussians=gaussians)
    if snap and layout_size(models) is not None:
        control = cond["control"][: L.shape[0]]
        size = _grid_size(dec, control.shape[-2:])
        if size is not None:
            control = pixels.upsample_layout(control.reshape(-1, *control.shape[2:]), size)
            control = control.reshape(L.shape[0], len(rig), *control.shape[1:])
        dec.meta["layout_snap_fraction"] = snap_to_layout(dec, control, snap_log_tol)
        if snap_map:
            dec.meta["map_snap_fraction"] = snap_to_map(dec, control)
        if snap_agents:
            boxes = {k: cond[k][: L.shape[0]] for k in ("box_corners", "box_moving", "box_mask")}
            dec.meta.update(snap_agents_to_layout(dec, control, boxes))
            r = DECODER_REFINE.get(dec.source, 1)
            if r > 1:  # the refined grid's floor stacks into a haze before an agent's edge
                dec.meta["agent_edge_fraction"] = narrow_before_agent_edges(
                    dec, control, REFINED_SCALE_FLOOR_MODEL_PX[r], (models.data.height, models.data.width)
                )
        if dec.source in LIFTED:
            for t, row in enumerate(dec.gaussians):
                row[:] = [pixels.settle_sky(g, dec.rig[v].at(dec.ego_to_world[t])) for v, g in enumerate(row)]
            if snap_agents and BACKDROP and "control_behind" in cond:
                dec.backdrop = draw_backdrop(cond, control, dec)
    return dec


# Generate draws what stands behind its agents (`pipeline.backdrop`).
BACKDROP = True


@torch.no_grad()
def draw_backdrop(cond: dict, control: torch.Tensor, dec: DecodedFrames) -> list[list]:
    """[t][v] static Gaussians of what stands behind the agents of `dec`'s lifted views (`pipeline.backdrop`): at
    the box pixels of `control` (the maps up-sampled to the rig's image), the surface the maps without the boxes
    (cond["control_behind"]) put there, coloured as the same view shows it elsewhere."""
    T, V = control.shape[:2]
    size = tuple(control.shape[-2:])
    flat = control.reshape(T * V, *control.shape[2:])
    boxes = backdrop.box_pixels(flat)
    out = [[Gaussians.empty() for _ in range(V)] for _ in range(T)]
    pick = [i for i in range(T * V) if bool(boxes[i].any())]
    if not pick or dec.images is None:
        return out
    behind = cond["control_behind"][:T]
    behind = pixels.upsample_layout(behind.reshape(T * V, *behind.shape[2:])[pick].float(), size)
    images = np.stack([dec.images[i // V][i % V] for i in pick])
    rgb = backdrop.fill_behind(images, flat[pick].float(), behind, boxes[pick])
    cams = [dec.rig[i % V].at(dec.ego_to_world[i // V]) for i in pick]
    for i, g in zip(pick, backdrop.lift_behind(rgb, behind, boxes[pick], cams), strict=True):
        out[i // V][i % V] = g
    return out


def _grid_size(dec: DecodedFrames, layout_hw) -> tuple[int, int] | None:
    """The grid (H, W) the snaps read the layout maps at, where finer than the maps' `layout_hw`: the rig's image for
    lifted pixels, a refined decoder's grid (None: the maps as they are)."""
    if dec.source in LIFTED:
        return (dec.rig[0].height, dec.rig[0].width)
    n = len(dec.gaussians[0][0])
    h, w = int(layout_hw[0]), int(layout_hw[1])
    if n <= h * w:
        return None
    r = round((n / (h * w)) ** 0.5)
    return (h * r, w * r)


@torch.no_grad()
def generate(
    conditions: dict,
    steps: int = 8,
    seed: int = 0,
    models: Models | None = None,
    rig=None,
    frame_times=None,
    cfg_scale: float | None = None,
    progress: Callable[[float], None] | None = None,
    caption_embedding: torch.Tensor | None = None,
    pad: bool = True,
    snap: bool = True,
    gaussians: str | None = None,
) -> DecodedFrames:
    """Generate mode: conditions -> DiT (rectified flow, `steps` Euler steps) -> Gaussians (`gaussians`: "pixels" or
    "decoder", `decode_gaussians`) -> snapped onto the layout (`snap`, `decode_generated`). `pad` False: a clip
    shorter than the models' window is sampled and decoded at its own length (the streamed first window)."""
    models = _require(models, "generate")
    if not isinstance(steps, int) or not 1 <= steps <= 256:
        raise ValueError(f"generate: steps must be an integer in 1..256, got {steps!r}")
    d = models.data
    ego = np.asarray(conditions.get("ego_traj"), np.float64) if conditions.get("ego_traj") is not None else None
    T = np.asarray(conditions["sketch"]).shape[0]
    if ego is None:
        raise ValueError("generate: conditions lack 'ego_traj'")
    if rig is None:
        h, w = np.asarray(conditions["sketch"]).shape[2:4]
        rig = default_rig(w, h)
    _check_rig(rig, d.views)
    t0 = time.perf_counter()
    cond = condition_tensors(models, conditions, ego, caption_embedding)
    t1 = time.perf_counter()
    L = sample_latents(models, cond, steps, seed, cfg_scale, progress=progress, pad=pad)
    t2 = time.perf_counter()
    ft = np.arange(T, dtype=np.float64) if frame_times is None else frame_times
    meta = {
        "mode": "generate",
        "steps": steps,
        "seed": seed,
        "model_version": models.version,
        "caption": str(conditions["caption"]),
    }
    dec = decode_generated(models, L, cond, rig, ego, ft, meta, pad=pad, snap=snap, gaussians=gaussians)
    # stage times for the benchmark's efficiency table (conditions incl. caption encoding, diffusion, decoder)
    dec.meta["timing_s"] = {"conditions": t1 - t0, "diffusion": t2 - t1, "gs_decoder": time.perf_counter() - t2}
    return dec


def gaussian_grid(models: Models, mode: str = "generate") -> tuple[int, int]:
    """(gh, gw): the Gaussians per view (one per grid cell) of `mode`'s decoder at the model resolution."""
    cfg, ds = models.decoder_for(mode).cfg, models.vae.cfg.downsample
    return tuple(n // ds // cfg.patch * cfg.upsample for n in (models.data.height, models.data.width))


def decoded_economy(
    model_width: int, image_width: int, gaussians: str | None = None, mode: str = "generate"
) -> Economy:
    """The economy of decoded Gaussians on an image_width image of scenes decoded at the models' model_width:
    lifted pixels ("pixels") `Economy.for_lifted_decoding`, the decoder's grid `Economy.for_decoded` (None: the
    source `mode` serves)."""
    source = gaussian_source(gaussians, mode)
    if source in LIFTED:
        return Economy.for_lifted_decoding()
    return Economy.for_decoded(image_width / model_width / DECODER_REFINE[source])


def aggregate_decoded(dec: DecodedFrames, economy: Economy | None = None) -> tuple[Scene4D, AggregateStats]:
    """Paper eq. 3 on decoded Gaussians, window by window as the playground serves them (`aggregate_windows` over the
    windows they were decoded in: static = each window's Gaussians with p_dynamic <= 0.5, dynamic[t] = frame t's
    others, then the economy; the static colours fitted jointly as the mode serves them, JOINT_FIT). No
    agent objects: `pipeline.scene` builds those."""
    H, W = dec.rig[0].height, dec.rig[0].width
    fit, joint = None, JOINT_FIT.get(dec.meta.get("mode", "generate"))
    images = dec.images if joint is not None else None
    if images is not None and joint.scope == "window":

        def fit(frames, static, held, dynamic):
            targets = {t: images[t] for t in frames if t in images}
            return (
                fit_window(static, held, dec.rig, dec.ego_to_world, targets, dynamic, joint.ridge, joint.iters)
                if targets
                else static
            )

    scene, stats = aggregate_windows(
        dec.gaussians,
        dec.frame_times,
        dec.rig,
        dec.ego_to_world,
        dec.windows or [list(range(len(dec.gaussians)))],
        economy=decoded_economy(dec.model_width or W, W, dec.source) if economy is None else economy,
        meta=dict(dec.meta),
        image_size=(H, W),
        fit=fit,
    )
    if images is not None and joint.scope == "scene":
        scene = fit_scene_static(scene, dict(images), iters=joint.iters, ridge=joint.ridge)
    return scene, stats


def to_scene4d(dec: DecodedFrames, meta: dict | None = None, economy: Economy | None = None) -> Scene4D:
    """The served scene of decoded frames (`aggregate_decoded`), with `meta` merged into its meta."""
    scene, stats = aggregate_decoded(dec, economy)
    scene.meta.update({"aggregate": stats.as_dict(), **(meta or {})})
    return scene
