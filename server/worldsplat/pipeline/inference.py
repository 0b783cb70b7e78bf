"""Inference glue of the networks, used by `worldsplat.pipeline.scene` (modes "reconstruct" and "generate").

Contract
--------
    models = load_models(weights_dir=None)           # worldsplat_models.weights.weights_dir() by default; cached
    available_modes(weights_dir=None) -> ["reconstruct", "generate"] subset whose weights exist
    dec = reconstruct(clip, models=None)              # clip: worldsplat.world.simulate(...) output (rgb, depth,
                                                      #   dynamic, rig, ego_to_world, frame_times, caption)
    dec = generate(conditions, steps=8, seed=0, models=None, rig=None, frame_times=None, progress=None)
                                                      # conditions: world.conditions() (sketch, boxes, ego_traj,
                                                      #   caption); rig: list[RigCamera] (default: default_rig)
    scene = to_scene4d(dec, meta=None)                # paper eq. 3 as served, window by window (aggregate_windows)
Weights: `<role>_small.safetensors` for role in vae | decoder | dit | prior, and optionally decoder_reconstruct (a
per-pixel Gaussian decoder serving reconstruct mode only; without it reconstruct uses `decoder`).
`dec` is a DecodedFrames: gaussians[t][v] (worldsplat.gaussians.Gaussians, world metres, extras[:, 0] = dynamic
probability) and dynamic_logits[t][v] (N,), plus frame_times, rig, ego_to_world and the normalised latent L.

The models run at their trained geometry (DataConfig: 64x112 per view, 6 views, 4-frame windows): inputs of other
sizes are resampled to it (the Gaussians live in world metres, so they render at any resolution), and longer clips
are processed in consecutive 4-frame windows (the last one padded by repeating its final frame). The rig must have
the 6 default cameras in order. Deterministic for a given seed; float32 on CPU; `torch.no_grad` throughout.
"""

from __future__ import annotations

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
from worldsplat.pipeline.conditions import pack_boxes, rig_tensors, sketch_rgb
from worldsplat.pipeline.onnx import ensure_exported, use_onnx
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, layout_depth_m, take_layout
from worldsplat_models import rflow
from worldsplat_models.conditions import encode_captions
from worldsplat_models.configs import DataConfig, get_config
from worldsplat_models.dit import dropped
from worldsplat_models.vae import normalize_depth
from worldsplat_models.weights import load_weights, read_metadata
from worldsplat_models.weights import weights_dir as default_weights_dir

SIZE = "small"


@dataclass
class Models:
    vae: torch.nn.Module | None
    decoder: torch.nn.Module | None
    dit: torch.nn.Module | None
    data: DataConfig
    version: str  # short hash of the weight files (for cache keys)
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

    def frame(self, t: int):
        return Gaussians.cat(self.gaussians[t])


_CACHE: dict[str, Models] = {}


# role -> the model kind its file holds; `<role>_<SIZE>.safetensors` in the weights folder
ROLES = {"vae": "vae", "decoder": "decoder", "dit": "dit", "prior": "prior", "decoder_reconstruct": "decoder"}


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


def load_models(weights_dir: str | Path | None = None, backend: str = "torch") -> Models:
    """Load whichever of vae / decoder / dit / prior exist (missing ones are None; `Models.modes` says what works).
    Cached per folder and per state of its weight files (a re-shipped or removed file loads anew).
    backend "onnx" serves the VAE, the DiT step and the Gaussian decoder with onnxruntime from
    <weights_dir>/onnx (same outputs within the documented 1e-3 parity tolerance)."""
    if backend not in ("torch", "onnx"):
        raise ValueError(f"backend must be 'torch' or 'onnx', got {backend!r}")
    paths = weight_paths(weights_dir)
    stamp = [(p.name, p.stat().st_mtime_ns, p.stat().st_size) for p in paths.values() if p.exists()]
    key = f"{paths['vae'].parent.resolve()}:{backend}:{stamp}"
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
        paths["vae"].parent,
        loaded["prior"],
        loaded["decoder_reconstruct"],
    )
    if backend == "onnx":
        ensure_exported(m)  # derived from the weights, exported here when set-up has not done it
        use_onnx(m, paths["vae"].parent / "onnx")
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
# by its training sampling rate), so a display larger than the model image shows no gaps between them. Measured on
# the default scene, reconstruct at the rig (web/docs/models.md, "Scale floor"): 0 / 0.3 / 0.5 -> 22.22 / 22.16 / 22.00 dB at
# 112x64, 22.11 / 22.15 / 22.05 at 200x112, 22.04 / 22.17 / 22.13 at 400x224; pixels under alpha 0.9 at 400x224
# 25 / 15 / 6 %.
DECODED_SCALE_FLOOR_MODEL_PX = 0.3


def scale_floor(scales: torch.Tensor, depth: torch.Tensor, fx_model: float) -> torch.Tensor:
    """scales (N,3) of Gaussians at camera depth (N,) -> widened by DECODED_SCALE_FLOOR_MODEL_PX model pixels
    (fx_model: the camera's focal length in model-image pixels, so one model pixel spans depth / fx_model metres)."""
    floor = DECODED_SCALE_FLOOR_MODEL_PX * depth / fx_model
    return torch.sqrt(scales**2 + floor[:, None] ** 2)


def decode_gaussians(
    models: Models,
    L: torch.Tensor,
    rig,
    ego_to_world: np.ndarray,
    frame_times,
    meta: dict,
    pad: bool = True,
    decoder: torch.nn.Module | None = None,
) -> DecodedFrames:
    """L (T,V,C,h,w) normalised -> DecodedFrames (window by window; `pad`: see `_windows`). `decoder`: which
    Gaussian decoder (default: the one for meta["mode"], `Models.decoder_for`)."""
    d = models.data
    decoder = decoder or models.decoder_for(meta.get("mode", "generate"))
    T = L.shape[0]
    intr, c2w = rig_tensors(rig, ego_to_world, (d.height, d.width))
    gs, logits = [[None] * len(rig) for _ in range(T)], [[None] * len(rig) for _ in range(T)]
    for win in _windows(T, d.frames, pad):
        guide = pixel_guide(models, L[win])[None] if decoder.cfg.guide_channels else None
        args = (L[win][None], intr[win][None], c2w[win][None], (d.height, d.width))
        out = decoder(*args) if guide is None else decoder(*args, guide=guide)
        for i, t in enumerate(win):
            for v in range(len(rig)):
                f = {
                    k: x[0, i, v].reshape(-1, x.shape[-1]) if x.dim() == 6 else x[0, i, v].reshape(-1)
                    for k, x in out.items()
                }
                p = torch.sigmoid(f["dynamic_logit"])
                scales = scale_floor(f["scales"], f["depth"], float(intr[t, v, 0]))
                gs[t][v] = Gaussians(f["means"], f["quats"], scales, f["opacities"], f["colors"], p[:, None])
                logits[t][v] = f["dynamic_logit"]
    return DecodedFrames(
        gs,
        logits,
        np.asarray(frame_times, np.float64),
        list(rig),
        np.asarray(ego_to_world, np.float64),
        L,
        meta,
        model_width=d.width,
        windows=[sorted(set(w)) for w in _windows(T, d.frames, pad)],
    )


def _grid_pitch(who: str, n: int, H: int, W: int) -> int:
    """The decoder's grid pitch in model pixels (1 or 2) of n Gaussians per view on an H x W layout."""
    f = round((H * W / n) ** 0.5)
    if f < 1 or (H // f) * (W // f) != n:
        raise ValueError(f"{who}: {n} Gaussians per view is not a grid of the {H}x{W} layout")
    return f


def _views(dec: DecodedFrames, control: torch.Tensor, who: str):
    """Each view of each frame: (t, v, its Gaussians, their grid pitch `_grid_pitch`, its layout maps as float)."""
    T, V, _, H, W = control.shape
    for t in range(T):
        for v in range(V):
            g = dec.gaussians[t][v]
            yield t, v, g, _grid_pitch(who, len(g), H, W), control[t, v].float()


def _camera_ray_depth(dec: DecodedFrames, t: int, v: int, means: torch.Tensor):
    """(origin, camera-z depth of each mean) of view v at frame t: a mean moves along its ray as o + (m - o) r."""
    cam = dec.rig[v].at(dec.ego_to_world[t])
    c2w = torch.as_tensor(np.linalg.inv(cam.world_to_camera), dtype=means.dtype)
    o = c2w[:3, 3]
    return o, (means - o) @ c2w[:3, 2]


# Generated ground Gaussians within this log-depth ratio (x/ 1.8) of the plane the layout states are put onto it
# (snap_to_layout). Swept on test clips 0-2 (CHANGELOG.md, the ground snap): 0.15 / 0.3 / 0.6 / 1.0 -> road AbsRel
# 0.122 / 0.078 / 0.028 / 0.022, all-pixel 0.258 / 0.242 / 0.229 / 0.229; beyond 0.6 nothing more is gained and
# more of what stands on the road (trees, walls the layout does not know) would be flattened onto it.
LAYOUT_SNAP_LOG_TOL = 0.6


@torch.no_grad()
def snap_to_layout(dec: DecodedFrames, control: torch.Tensor, log_tol: float = LAYOUT_SNAP_LOG_TOL) -> float:
    """Put generated Gaussians that the layout maps call ground (drivable area or sidewalk, no box) onto the ground
    plane those maps state: the scenario's road is exact geometry, the generator's depth there scatters around it
    (measured in web/docs/models.md). control (T,V,7,H,W): the layout maps at the model resolution. A Gaussian moves
    along its own camera ray (mean and scales by the depth ratio) only where every pixel of its grid cell is ground,
    its dynamic probability is <= 0.5 and its depth is within exp(+-log_tol) of the plane's (so a tree or wall
    the layout does not know about keeps its place). In place; returns the fraction of Gaussians moved."""
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}
    moved = total = 0
    for t, v, g, f, c in _views(dec, control, "snap_to_layout"):
        ground = ((c[ch["drivable"]] + c[ch["sidewalk"]]) > 0.5) & (c[ch["vehicle"]] + c[ch["vulnerable"]] < 0.5)
        ground &= c[ch["depth"]] < 0.999  # the plane is in range
        cell_ground = -F.max_pool2d(-ground[None, None].float(), f)[0, 0] > 0.5
        # a plane's inverse depth is linear in the image: its cell mean is the value at the cell's centre ray
        z_plane = 1.0 / F.avg_pool2d(1.0 / layout_depth_m(c[ch["depth"]])[None, None], f)[0, 0]
        o, z = _camera_ray_depth(dec, t, v, g.means)
        ratio = z_plane.reshape(-1) / z.clamp_min(1e-3)
        ok = cell_ground.reshape(-1) & (ratio.log().abs() < log_tol) & (z > 0)
        if g.extras is not None:
            ok &= g.extras[:, 0] <= 0.5
        r = torch.where(ok, ratio, torch.ones_like(ratio))[:, None]
        g.means = o + (g.means - o) * r
        g.scales = g.scales * r
        moved, total = moved + int(ok.sum()), total + len(g)
    return moved / max(total, 1)


# A generated Gaussian within this distance of a moving agent's box (metres) moves with that agent: the layout's box
# surface, onto which the box cells' Gaussians are put, is exact; the margin takes the cell's footprint.
AGENT_BOX_MARGIN_M = 0.3
AGENT_MIN_OPACITY = 0.95  # box cells' Gaussians at least this opaque (`solid`)


def _cell_surface(mask: torch.Tensor, depth_m: torch.Tensor, f: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(H,W) mask in [0,1] and depth in metres -> per f x f grid cell: the mask's cover and the harmonic mean depth of
    its pixels (exact for a plane seen through the cell, as inverse depth is linear in the image)."""
    cover = F.avg_pool2d(mask[None, None], f)[0, 0]
    inv_z = F.avg_pool2d((mask / depth_m)[None, None], f)[0, 0]
    return cover, cover / inv_z.clamp_min(1e-9)


# Generated Gaussians in cells the map layer covers move onto its surface when within this log-depth ratio of it
# (x/ 3: a facade the generator put at half or twice its distance still lands on it; a wall behind a tree, which the
# generator drew as a tree, farther off, keeps its place). Measured: CHANGELOG.md, the map layer.
MAP_SNAP_LOG_TOL = 1.1
MAP_MIN_OPACITY = 0.95  # building cells' Gaussians at least this opaque (a facade is not see-through)


@torch.no_grad()
def snap_to_map(
    dec: DecodedFrames,
    control: torch.Tensor,
    log_tol: float = MAP_SNAP_LOG_TOL,
    solid: bool = True,
    classes: tuple[str, ...] = ("building", "vegetation", "furniture"),
) -> float:
    """Generated Gaussians where the layout's map layer (buildings, trees, poles; `world/layout_maps.py`) is the
    nearest surface onto that surface: a grid cell mostly covered (> 0.5) by the map layer and no agent box, with
    the Gaussian static (p_dynamic <= 0.5) and within exp(+-log_tol) of the surface's depth, moves along its camera
    ray (mean and scales by the depth ratio) to the harmonic mean of the cell's map depth; with `solid` building cells
    become opaque (opacity >= MAP_MIN_OPACITY). `classes`: the map channels snapped. Maps without the map layer (7 channels) leave the scene unchanged. In place;
    returns the fraction of Gaussians moved."""
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}
    if control.shape[2] < len(LAYOUT_CHANNELS):
        return 0.0
    moved = total = 0
    for t, v, g, f, c in _views(dec, control, "snap_to_map"):
        depth = layout_depth_m(c[ch["map_depth"]])
        structure = sum(c[ch[k]] for k in classes).clamp(0, 1)
        cover, z_map = _cell_surface(structure, depth, f)
        building, _ = _cell_surface(c[ch["building"]], depth, f)
        agent = F.max_pool2d((c[ch["vehicle"]] + c[ch["vulnerable"]])[None, None], f)[0, 0] > 0.5
        o, z = _camera_ray_depth(dec, t, v, g.means)
        ratio = z_map.reshape(-1) / z.clamp_min(1e-3)
        ok = (cover.reshape(-1) > 0.5) & ~agent.reshape(-1) & (ratio.log().abs() < log_tol) & (z > 1e-3)
        if g.extras is not None:
            ok &= g.extras[:, 0] <= 0.5
        r = ratio[:, None]
        g.means = torch.where(ok[:, None], o + (g.means - o) * r, g.means)
        g.scales = torch.where(ok[:, None], g.scales * r, g.scales)
        if solid:
            firm = ok & (building.reshape(-1) > 0.5)
            g.opacities = torch.where(firm, g.opacities.clamp_min(MAP_MIN_OPACITY), g.opacities)
        moved, total = moved + int(ok.sum()), total + len(g)
    return moved / max(total, 1)


# A cell at least this much box that covers more than any neighbour holds an agent smaller than a cell (a pedestrian
# at 40 m is ~1.5 model pixels wide: straddling two cells, neither is half box, and the agent got no Gaussian).
AGENT_MIN_PEAK_COVER = 0.2


def _agent_cells(cover: torch.Tensor, *class_covers: torch.Tensor) -> torch.Tensor:
    """(h,w) box cover per cell -> cells whose Gaussians go onto the box: mostly box (> 0.5), or, in any of
    `class_covers` (the vehicle and the vulnerable channels' own cover, so a pedestrian beside a car is still a peak),
    a local peak of cover >= AGENT_MIN_PEAK_COVER (a sub-cell agent's best cell; a large agent's edge cells are not
    peaks, so its silhouette does not grow)."""
    out = cover > 0.5
    for c in class_covers or (cover,):
        peak = F.max_pool2d(c[None, None], 3, stride=1, padding=1)[0, 0]
        out |= (c >= AGENT_MIN_PEAK_COVER) & (c >= peak)
    return out


def _box_centre_points(dec: DecodedFrames, t: int, v: int, box, cover, z_box, f: int) -> torch.Tensor:
    """(cells, 3) world points at camera depth z_box on the ray through the centroid of each f x f cell's box pixels
    (box (H,W) at the model resolution; the rig camera's intrinsics scaled to it)."""
    H, W = box.shape
    cam = dec.rig[v].at(dec.ego_to_world[t])
    sx, sy = W / cam.width, H / cam.height
    u = (torch.arange(W, dtype=torch.float32) + 0.5)[None].expand(H, W)
    w = (torch.arange(H, dtype=torch.float32) + 0.5)[:, None].expand(H, W)
    pool = lambda x: F.avg_pool2d(x[None, None], f)[0, 0]  # noqa: E731
    cu = pool(box * u) / cover.clamp_min(1e-9)
    cv = pool(box * w) / cover.clamp_min(1e-9)
    ray = torch.stack([(cu - cam.cx * sx) / (cam.fx * sx), (cv - cam.cy * sy) / (cam.fy * sy), torch.ones_like(cu)], -1)
    c2w = torch.as_tensor(np.linalg.inv(cam.world_to_camera), dtype=torch.float32)
    return c2w[:3, 3] + (ray.reshape(-1, 3) * z_box.reshape(-1, 1)) @ c2w[:3, :3].T


def _inside_boxes(points: torch.Tensor, corners: torch.Tensor, margin: float) -> torch.Tensor:
    """(N,3) points, (K,8,3) box corners (`Agent.box_corners` order: bottom face counter-clockwise from rear-right,
    then the top face) in the same frame -> (N,) True where a point lies inside any box grown by `margin` metres."""
    if corners.shape[0] == 0:
        return torch.zeros(points.shape[0], dtype=torch.bool)
    o = corners[:, 0]  # (K,3) rear-right bottom
    axes = torch.stack([corners[:, 1] - o, corners[:, 3] - o, corners[:, 4] - o], 1)  # (K,3,3) length, width, height
    size = axes.norm(dim=-1).clamp_min(1e-6)  # (K,3)
    local = torch.einsum("nkc,kac->nka", points[:, None] - o[None], axes / size[..., None])  # (N,K,3) metres
    inside = (local > -margin) & (local < size[None] + margin)
    return inside.all(-1).any(-1)


@torch.no_grad()
def snap_agents_to_layout(
    dec: DecodedFrames, control: torch.Tensor, cond: dict, margin: float = AGENT_BOX_MARGIN_M, solid: bool = True
):
    """Generated Gaussians where the layout maps state an agent onto that agent's box, and the agents' motion from
    the scenario. The layout's box channels and their depth are exact (a box per agent, `world/layout_maps.py`);
    the generator's latents at 1/4 resolution lose far and small agents (0-51 dynamic Gaussians per frame on imported
    files, web/docs/world.md), so the scene did not hold them where the scenario put them. Two steps, in place:
    1. every Gaussian whose grid cell is mostly box (vehicle or vulnerable channel > 0.5 on average), or is the peak
       cell of an agent smaller than a cell (`_agent_cells`), moves along its camera ray onto the box surface (the harmonic mean of the cell's box-pixel depths; mean and scales by the ratio,
       so the image from its own camera barely changes);
    2. a Gaussian inside a moving agent's box at its frame (`cond` box_corners, box_moving: the conditions' boxes in
       each frame's ego frame) becomes dynamic, one inside a standing agent's box static; elsewhere the decoder's
       dynamic probability is kept.
    Returns {"agent_snap_fraction", "agent_dynamic_fraction"} over all Gaussians."""
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}
    T, V, _, H, W = control.shape
    moved = dynamic = total = 0
    for t in range(T):
        known = cond["box_mask"][t].bool()
        corners = cond["box_corners"][t].double()
        mov, stand = corners[known & cond["box_moving"][t].bool()], corners[known & ~cond["box_moving"][t].bool()]
        w2e = torch.as_tensor(np.linalg.inv(dec.ego_to_world[t]), dtype=torch.float64)
        for v in range(V):
            g = dec.gaussians[t][v]
            n = len(g)
            f = _grid_pitch("snap_agents_to_layout", n, H, W)
            c = control[t, v].float()
            box = (c[ch["vehicle"]] + c[ch["vulnerable"]]).clamp(0, 1)
            cover, z_box = _cell_surface(box, layout_depth_m(c[ch["depth"]]), f)
            o, z = _camera_ray_depth(dec, t, v, g.means)
            by_class = [F.avg_pool2d(c[ch[k]][None, None], f)[0, 0] for k in ("vehicle", "vulnerable")]
            ok = _agent_cells(cover, *by_class).reshape(-1) & (z > 1e-3)
            r = (z_box.reshape(-1) / z.clamp_min(1e-3))[:, None]
            g.means = torch.where(ok[:, None], o + (g.means - o) * r, g.means)
            g.scales = torch.where(ok[:, None], g.scales * r, g.scales)
            # a sub-cell agent's cell: onto the ray through its box pixels' centre (at 40 m the decoder's offset
            # within the cell alone puts the Gaussian half a metre beside a pedestrian)
            small = ok & (cover.reshape(-1) <= 0.5)
            if small.any():
                target = _box_centre_points(dec, t, v, box, cover, z_box, f)
                g.means = torch.where(small[:, None], target.to(g.means.dtype), g.means)
            if solid:  # an agent is solid where the layout states it , whatever colour it got
                g.opacities = torch.where(ok, g.opacities.clamp_min(AGENT_MIN_OPACITY), g.opacities)
            ego = g.means.double() @ w2e[:3, :3].T + w2e[:3, 3]
            in_moving, in_standing = _inside_boxes(ego, mov, margin), _inside_boxes(ego, stand, margin)
            p = g.extras[:, 0] if g.extras is not None else torch.zeros(n)
            p = torch.where(in_moving, torch.ones_like(p), torch.where(in_standing, torch.zeros_like(p), p))
            g.extras = p[:, None] if g.extras is None else torch.cat([p[:, None], g.extras[:, 1:]], 1)
            moved, dynamic, total = moved + int(ok.sum()), dynamic + int(in_moving.sum()), total + n
    return {"agent_snap_fraction": moved / max(total, 1), "agent_dynamic_fraction": dynamic / max(total, 1)}


# --- modes -----------------------------------------------------------------------------------------------------------


@torch.no_grad()
def encode_clip(models: Models, rgb, depth, dynamic) -> torch.Tensor:
    """(T,V,H,W,3) uint8, (T,V,H,W) metres, (T,V,H,W) bool -> normalised L (T,V,C,h,w) at the native size."""
    d = models.data
    rgb = torch.as_tensor(np.asarray(rgb))
    T, V = rgb.shape[:2]
    hw = (d.height, d.width)
    x = _resize(rgb.reshape(T * V, *rgb.shape[2:]).permute(0, 3, 1, 2).float() / 127.5 - 1, hw, "area")
    dn = normalize_depth(torch.as_tensor(np.asarray(depth, np.float32)), d.depth_near, d.depth_far)
    dn = _resize(dn.reshape(T * V, 1, *dn.shape[2:]), hw, "area")
    m = torch.as_tensor(np.asarray(dynamic, bool)).reshape(T * V, 1, *rgb.shape[2:4]).float()
    m = (_resize(m, hw, "area") > 0.5).float()
    L = models.vae.encode_joint(x, dn, m)
    return L.reshape(T, V, *L.shape[1:])


@torch.no_grad()
def reconstruct(clip, models: Models | None = None) -> DecodedFrames:
    """Reconstruct mode (paper §3.5): multi-view video + depth + dynamic masks -> VAE encoder -> Gaussian decoder,
    bypassing diffusion. The world supplies exact depth and masks where the paper used Metric3D and SegFormer."""
    models = _require(models, "reconstruct")
    for k in ("rgb", "depth", "dynamic", "rig", "ego_to_world"):
        if getattr(clip, k, None) is None:
            raise ValueError(f"reconstruct: the clip has no {k!r}")
    _check_rig(clip.rig, models.data.views)
    t0 = time.perf_counter()
    L = encode_clip(models, clip.rgb, clip.depth, clip.dynamic)
    t1 = time.perf_counter()
    dec = decode_gaussians(
        models,
        L,
        clip.rig,
        clip.ego_to_world,
        clip.frame_times,
        {"mode": "reconstruct", "model_version": models.version, "caption": getattr(clip, "caption", "")},
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
    return {
        "box_corners": torch.from_numpy(corners),
        "box_cls": torch.from_numpy(cls),
        "box_moving": torch.from_numpy(moving),
        "box_mask": torch.from_numpy(mask),
        "traj": torch.from_numpy(traj),
        "caption": caption_emb.float(),
        "control": ctl.reshape(T, V, *ctl.shape[1:]),
    }


def window_cond(cond: dict, win: list[int]) -> dict:
    out = {k: v[win][None] for k, v in cond.items() if k != "caption"}
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
) -> torch.Tensor:
    """Rectified-flow sampling of L (T,V,C,h,w), window by window; the noise depends only on (seed, window).
    A DiT that generates the layout prior's residual gives L = mu + residual_scale * sample.
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
            z = prior_mean(models, layout, c["caption"]) + dcfg.residual_scale * z
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
) -> DecodedFrames:
    """Generated latents -> DecodedFrames as generate mode serves them (the evaluation scores exactly this):
    decode, then, where the models read layout maps, `snap_to_layout` (the road onto its plane) and
    `snap_to_map` (facades, trees and poles onto the map layer's surfaces) and `snap_agents_to_layout` (the agents onto
    their boxes, moving with them); snap=False skips all three, snap_map=False / snap_agents=False one of them."""
    dec = decode_gaussians(models, L, rig, ego_to_world, frame_times, meta, pad=pad)
    if snap and layout_size(models) is not None:
        control = cond["control"][: L.shape[0]]
        dec.meta["layout_snap_fraction"] = snap_to_layout(dec, control, snap_log_tol)
        if snap_map:
            dec.meta["map_snap_fraction"] = snap_to_map(dec, control)
        if snap_agents:
            boxes = {k: cond[k][: L.shape[0]] for k in ("box_corners", "box_moving", "box_mask")}
            dec.meta.update(snap_agents_to_layout(dec, control, boxes))
    return dec


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
) -> DecodedFrames:
    """Generate mode: conditions -> DiT (rectified flow, `steps` Euler steps) -> Gaussian decoder -> road Gaussians
    onto the layout's ground plane (`snap`, `snap_to_layout`). `pad` False: a clip shorter than the models' window
    is sampled and decoded at its own length (the streamed first window)."""
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
    dec = decode_generated(models, L, cond, rig, ego, ft, meta, pad=pad, snap=snap)
    # stage times for the benchmark's efficiency table (conditions incl. caption encoding, diffusion, decoder)
    dec.meta["timing_s"] = {"conditions": t1 - t0, "diffusion": t2 - t1, "gs_decoder": time.perf_counter() - t2}
    return dec


def gaussian_grid(models: Models, mode: str = "generate") -> tuple[int, int]:
    """(gh, gw): the Gaussians per view (one per grid cell) of `mode`'s decoder at the model resolution."""
    cfg, ds = models.decoder_for(mode).cfg, models.vae.cfg.downsample
    return tuple(n // ds // cfg.patch * cfg.upsample for n in (models.data.height, models.data.width))


def decoded_economy(model_width: int, image_width: int) -> Economy:
    """The economy of decoded Gaussians (`Economy.for_decoded`) on an image_width image of scenes decoded at the
    models' model_width."""
    return Economy.for_decoded(image_width / model_width)


def aggregate_decoded(dec: DecodedFrames, economy: Economy | None = None) -> tuple[Scene4D, AggregateStats]:
    """Paper eq. 3 on decoded Gaussians, window by window as the playground serves them (`aggregate_windows` over the
    windows they were decoded in: static = each window's Gaussians with p_dynamic <= 0.5, dynamic[t] = frame t's
    others, then the economy)."""
    H, W = dec.rig[0].height, dec.rig[0].width
    return aggregate_windows(
        dec.gaussians,
        dec.frame_times,
        dec.rig,
        dec.ego_to_world,
        dec.windows or [list(range(len(dec.gaussians)))],
        economy=decoded_economy(dec.model_width or W, W) if economy is None else economy,
        meta=dict(dec.meta),
        image_size=(H, W),
    )


def to_scene4d(dec: DecodedFrames, meta: dict | None = None, economy: Economy | None = None) -> Scene4D:
    """The served scene of decoded frames (`aggregate_decoded`), with `meta` merged into its meta."""
    scene, stats = aggregate_decoded(dec, economy)
    scene.meta.update({"aggregate": stats.as_dict(), **(meta or {})})
    return scene
