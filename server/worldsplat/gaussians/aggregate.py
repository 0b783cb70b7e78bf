"""4D aggregation (paper eq. 3) and the economy that makes a scene carry only what it needs.

Eq. 3: the per-frame, per-view Gaussians (already in the world frame, or moved there by the ego poses) split by
their dynamic mask into a static union over all frames and views, plus each frame's own dynamic set:

    G(t) = U_{t', v} G_static(t', v)  +  U_v G_dynamic(t, v)

The naive union repeats every surface once per frame and view that sees it. The economy then
1. drops Gaussians that cannot show (transparent: opacity < `min_opacity`; out of range: farther than `max_range`
   from every camera position, except the sky shell flagged in extras[:, SKY_CHANNEL]; non-finite);
2. keeps one observation per place. Static surfaces (`Economy.static_rule` "finest", the default): the finest
   observation of each point, unmerged (`finest_observations`: an observation is dropped where another frame-view
   sees its point with a smaller pixel footprint), so the surface keeps one sharp pixel grid. "merge" (decoded
   grids, `Economy.for_decoded`; the sky shell always) merges repeats: a voxel hash whose cell is `cell_factor` x
   the pixel footprint seen from the nearest camera of the track (distance / focal), rounded to a power of two.
   Every observation of a
   surface (any frame, view or depth) lands in the same cell; the members of a cell become one Gaussian (mean and
   colour averaged with finer observations weighing more, scale grown to cover the members' spread). The sky shell
   merges in its own cells (`sky_cell_factor` x its footprint), never with a surface, into Gaussians that cover
   their cell (std >= SKY_COVER x cell). Each frame's dynamic set is economized with that frame's cameras in
   cells of `dynamic_cell_factor` (1) footprints: it is seen from those cameras only, at the distance it was
   observed, so a coarser cell is a visible down-sampling (with the static factor 3 near vehicles became dot
   grids, alpha 0.6-0.8 on their pixels; gaussians.md, "Dynamic objects stay solid");
3. orders by importance (opacity x scale^2 x (1 + log merged count): big, solid, often-seen first, so any prefix of
   the stream is a coarser whole scene) and caps by a budget.
`python -m worldsplat.gaussians.economy` measures kept Gaussians and PSNR change against exact ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from worldsplat.core.camera import Camera, RigCamera
from worldsplat.gaussians import constants as C
from worldsplat.gaussians.lift import MAX_DEPTH, SKY_CHANNEL
from worldsplat.gaussians.types import Gaussians, Scene4D, transform

DYNAMIC_THRESHOLD = 0.5  # extras[:, 0] (dynamic probability / mask) above this -> dynamic
# A merged sky Gaussian's std is at least this fraction of its cell. At 0.5 neighbouring cells' Gaussians cover
# only 0.85 of the sky between their centres (alpha), and the backdrop behind them showed through as a dark cell
# grid over an open sky on a canvas 2x the served image (test:2, the highway; web/docs/gaussians.md "Sky shell").
SKY_COVER = 0.8
DYNAMIC_CELL_FACTOR = 1.0  # cell of the per-frame dynamic sets, in pixel footprints (static: Economy.cell_factor)
DYNAMIC_COVER = 0.0  # > 0: merged dynamic std = this x the patch width (see merged_variance; 0.7 = FOOTPRINT)
# Static cells of *decoded* Gaussians (reconstruct / generate), in pixels of the models' image (64x112): the decoder
# puts one Gaussian per grid cell (1 or 2x2 model pixels) with learned scales, so the economy should merge repeats of
# a place seen in several frames and not its neighbours. Cells of 3 *display*-pixel footprints (the oracle's) were
# 1.5 grid pitches of the 2x2 decoder at 64x112 and averaged neighbours into blobs: reconstruct 0 m 19.32 dB vs
# 21.51 at one model pixel; measured best for both strides (gaussians.md, "decoded cells").
DECODED_CELL_MODEL_PX = 1.0
# Decoded depths are coarse far away: a window's static Gaussian seen at distance d that a later frame of the track
# will see from d / DEFER_NEARER or nearer is left to that frame (`Economy.defer_nearer`). Kept, the far windows'
# Gaussians at the wrong depth became a fog the ego drove into (a 200-frame generate clip: grey from frame ~60 on;
# within 5 m of frame 100's front camera lay 9k of them). Places nearer than DEFER_MIN_M, and places no later
# camera sees in its image, stay. Later frames are sampled each DEFER_SAMPLE_M of ego travel.
DEFER_MIN_M = 8.0
DEFER_SAMPLE_M = 2.0
FINEST_DEPTH_TOL = 0.02  # relative depth agreement of "the same surface point" (finest rule, exact depths)
# The same for depths the VAE decodes per frame (reconstruct's lifted pixels): a window's frames put the same surface
# a few per cent apart, and under 0.02 the finest rule kept several frames' copies side by side (a blotched road;
# default preset 3.40 Gaussians per served px, 20.63 dB). Measured 0.02 / 0.06 / 0.12 / 0.25 in web/docs/models.md.
LIFTED_DECODED_DEPTH_TOL = 0.12


@dataclass
class Economy:
    """Thresholds of the economy (defaults measured in web/docs/gaussians.md)."""

    enabled: bool = True
    min_opacity: float = 0.02  # "transparent": below this a Gaussian barely shows
    max_range: float = MAX_DEPTH  # m from the nearest camera position ("out of range"; farther pixels are sky)
    cell_factor: float = 3.0  # voxel cell = cell_factor x the pixel footprint seen from the nearest camera
    # The same for the sky shell. 3 (cells of 2.7 footprints after the power-of-two rounding, at the shell's fixed
    # distance) blurred the clouds and the far horizon the shell holds; 1.5 (1.3 footprints) keeps them at about the
    # surfaces' resolution, and with one shell per stretch of track (`lift.sky_centre`) costs no more Gaussians.
    sky_cell_factor: float = 1.5
    # A frame's dynamic set is seen only from that frame's cameras, at the distance it was observed (a static
    # place is mostly seen from farther than its nearest camera), so its cells are one footprint. `dynamic_cover`
    # > 0 lets coarser dynamic cells stay closed (merged std = cover x the patch width; see merged_variance): a
    # cheaper, softer setting measured in gaussians.md.
    dynamic_cell_factor: float = DYNAMIC_CELL_FACTOR
    dynamic_cover: float = DYNAMIC_COVER
    opacity_merge: str = "mean"  # merged opacity: "mean" of the members or "union" 1 - prod(1 - o)
    static_budget: int | None = None  # cap on static Gaussians (most important kept)
    # Static surfaces: "finest" keeps, for each surface place, the observations of the one frame-view that sees it
    # finest, unmerged (`finest_observations`); "merge" averages every observation in its cell (the sky shell
    # always merges in its cells). Decoded Gaussians (learned modes) merge: see `for_decoded`.
    static_rule: str = "finest"
    # Relative depth within which two observations are "the same surface point" (finest rule): exact depths agree
    # to FINEST_DEPTH_TOL; depths decoded per frame disagree by a few per cent (`for_lifted_decoding`).
    finest_depth_tol: float = FINEST_DEPTH_TOL
    # Decoded depths: an observation in front of what an earlier window's view showed is a copy the frames disagree
    # on (that view saw through it), not a surface the earlier window could not see (`finest_observations`).
    carve: bool = False
    # > 1: a static observation a later frame's camera will see this many times nearer is left to it (see
    # DEFER_MIN_M); None keeps every observation (exact depths: the oracle).
    defer_nearer: float | None = None
    dynamic_budget: int | None = None  # cap per frame

    @staticmethod
    def for_decoded(model_px: float) -> Economy:
        """The served economy of the learned modes' Gaussians: static cells of `DECODED_CELL_MODEL_PX` model-image
        pixels, `model_px` = image pixels per model-image pixel (image width / model width). Lifted pixels (oracle)
        keep the default cells."""
        if not (math.isfinite(model_px) and model_px > 0):
            raise ValueError(f"Economy.for_decoded: model_px must be a finite number > 0, got {model_px}")
        return Economy(cell_factor=DECODED_CELL_MODEL_PX * model_px, static_rule="merge", defer_nearer=1.5)

    @staticmethod
    def for_lifted_decoding() -> Economy:
        """The served economy of decoded colour and depth lifted per pixel (`pipeline.pixels`): the oracle's, with
        the decoded depths' agreement (`LIFTED_DECODED_DEPTH_TOL`) and earlier windows carving what they saw
        through (`carve`)."""
        return Economy(finest_depth_tol=LIFTED_DECODED_DEPTH_TOL, carve=True)


@dataclass
class AggregateStats:
    naive: int = 0  # V * T * H * W (every pixel of every view and frame)
    lifted: int = 0  # Gaussians handed to aggregate (oracle: every pixel, the sky on its shell)
    static_union: int = 0
    dynamic_union: int = 0
    static_kept: int = 0
    dynamic_kept: int = 0
    dropped_transparent: int = 0
    dropped_range: int = 0
    sky_kept: int = 0  # static Gaussians of the sky shell (part of static_kept)
    merged_away: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def kept(self) -> int:
        return self.static_kept + self.dynamic_kept

    def as_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "extra"}
        d["kept"] = self.kept
        d["kept_fraction_of_naive"] = self.kept / max(1, self.naive)
        d.update(self.extra)
        return d


def split_dynamic(g: Gaussians, threshold: float = DYNAMIC_THRESHOLD) -> tuple[Gaussians, Gaussians]:
    static = torch.as_tensor(_static_rows(g, threshold))
    return g.subset(static), g.subset(~static)


# ---------------------------------------------------------------------------------------------- economy
def _finite_rows(a: dict[str, np.ndarray]) -> np.ndarray:
    keep = np.ones(len(a["means"]), dtype=bool)
    for v in a.values():
        keep &= np.isfinite(v if v.ndim == 2 else v[:, None]).all(1)
    return keep


def _cell_keys(p: np.ndarray, level: np.ndarray, sky: np.ndarray) -> np.ndarray:
    """Hash (sky flag, level, voxel of size 2^level m) to int64: 16 bits sky + level, 16 bits per axis (voxel
    indices wrap;
    a collision needs the same level 65536 cells apart and is harmless: it only merges two far Gaussians' counts
    into one cell... so the wrap distance is kept far beyond any scene extent at the levels used)."""
    ijk = np.floor(p / np.exp2(level.astype(np.float64))[:, None]).astype(np.int64) & 0xFFFF
    lv = ((level.astype(np.int64) + 64) & 0x7FFF) | (sky.astype(np.int64) << 15)
    return (lv << 48) | (ijk[:, 0] << 32) | (ijk[:, 1] << 16) | ijk[:, 2]


def nearest_distance(p: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Distance from each (finite) point to the nearest of `centres`, exact: a k-d tree over the centres (a 200-frame
    clip has 1,200 camera positions; a loop over them was 29 s of 300k points against the tree's 2.7 s)."""
    from scipy.spatial import cKDTree  # noqa: PLC0415 - heavy (0.7 s), needed by the aggregation only

    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    if not len(centres):
        return np.full(len(p), np.inf)
    return cKDTree(centres).query(np.asarray(p, np.float64).reshape(-1, 3), workers=1)[0]


def merged_variance(total_var: np.ndarray, cover: float = 0.0) -> np.ndarray:
    """The variance a merged Gaussian adds to its members' mean variance, from the members' centre spread
    `total_var` (sum over the 3 axes of the weighted variance about the merged mean).

    cover = 0: moment matching of the centres, total_var / 3 per axis. That is right for a cloud of repeats of one
    place, but it under-covers a patch the members tile: n x n lifted splats at pitch p (std F p, F = FOOTPRINT)
    have per-axis centre variance p^2 (n^2 - 1) / 12 on the patch's two axes, so the merged std is
    sqrt(F^2 + (n^2 - 1) / 18) p (0.97 p for n = 3) while the next merged Gaussian sits n p away: a dot grid
    (measured: alpha 0.6-0.8 on near vehicles with the static cells).
    cover = c > 0: the members sample a surface patch (two in-plane axes: per-axis variance total_var / 2) of
    width w (w^2 = 12 x that variance for a uniform patch); the merged Gaussian gets std c w, the lifting's own
    closure rule (std F x pitch) one level up: F^2 p^2 + 12 c^2 p^2 (n^2 - 1) / 12 = (c n p)^2 for c = F,
    exactly, for any n."""
    if cover <= 0:
        return total_var / 3.0
    return 12.0 * cover**2 * (total_var / 2.0)


def _kept_rows(g: Gaussians, eco: Economy, camera_centres: np.ndarray, stats: AggregateStats, single: np.ndarray):
    """The rows `economize` works on, as float64 numpy: finite, opaque enough and (sky aside) within range of a
    camera; with each row's distance to the nearest camera, its sky flag and its `single` flag (kept unmerged).
    Counts what it drops in `stats`."""
    a = {k: v.astype(np.float64) for k, v in g.numpy().items()}
    a["single"] = np.asarray(single, np.float64)
    keep = _finite_rows(a)
    a["opacities"] = np.clip(np.nan_to_num(a["opacities"]), 0, 1)
    transparent = keep & (a["opacities"] < max(eco.min_opacity, C.ALPHA_MIN))
    stats.dropped_transparent += int(transparent.sum())
    keep &= ~transparent
    a = {k: v[keep] for k, v in a.items()}
    sky = (
        a["extras"][:, SKY_CHANNEL] > 0.5
        if "extras" in a and a["extras"].shape[1] > SKY_CHANNEL
        else np.zeros(len(a["means"]), dtype=bool)
    )
    dist = nearest_distance(a["means"], camera_centres)
    far = (dist > eco.max_range) & ~sky
    stats.dropped_range += int(far.sum())
    a = {k: v[~far] for k, v in a.items()}
    return a, dist[~far], sky[~far], a.pop("single") > 0.5


def economize(
    g: Gaussians,
    eco: Economy,
    camera_centres: np.ndarray,
    focal: float,
    stats: AggregateStats | None = None,
    budget: int | None = None,
    cell_factor: float | None = None,
    cover: float = 0.0,
    emitted: CellTable | None = None,
    single: np.ndarray | None = None,
) -> Gaussians:
    """Drop, merge, order by importance, cap (see the module docstring). Works on detached numpy copies; the
    result is a new Gaussians (isotropic inputs stay isotropic; a merged cell takes the rotation of its most
    opaque member). `cell_factor` overrides `eco.cell_factor` (the dynamic sets use `eco.dynamic_cell_factor`).
    `cover` > 0: a merged Gaussian stands for the surface patch its members tile, not for their centres
    (see `merged_variance`). `emitted`: the cells earlier windows emitted (`WindowAggregator`); a cell found there
    is emitted again only when this window sees it at least `FINER` times finer, else its members count as merged
    away; the cells this call emits are added to it. `single` (bool per row): rows kept as they are, each its own
    cell, never in `emitted` (the finest observations, `finest_observations`)."""
    stats = stats or AggregateStats()
    if len(g) == 0:
        return g.detach()
    single = np.zeros(len(g), dtype=bool) if single is None else np.asarray(single, dtype=bool)
    a, dist, sky, single = _kept_rows(g, eco, camera_centres, stats, single)
    n = len(a["means"])
    if n == 0:
        return Gaussians.empty(0 if g.extras is None else g.extras.shape[1])
    s = np.clip(a["scales"], C.SCALE_MIN, C.SCALE_MAX)
    # One resolution per place: the pixel footprint from the nearest camera, times cell_factor, rounded to a
    # power of two. Every observation of a surface (any frame, any view, any depth) lands in the same cell.
    cf = eco.cell_factor if cell_factor is None else cell_factor
    cell = np.where(sky, eco.sky_cell_factor, cf) * np.maximum(dist, 0.1) / focal
    level = np.round(np.log2(cell)).astype(np.int64)
    keys = _cell_keys(a["means"][~single], level[~single], sky[~single])
    uniq, inv_cells, counts = np.unique(keys, return_inverse=True, return_counts=True)
    inv = np.empty(n, dtype=np.int64)
    inv[~single] = inv_cells.reshape(-1)
    inv[single] = len(uniq) + np.arange(int(single.sum()))  # each single row its own cell, after the cells
    counts = np.concatenate([counts, np.ones(int(single.sum()), dtype=counts.dtype)])
    m = len(counts)
    stats.merged_away += n - m
    w = a["opacities"] / np.exp(2 * np.log(s).mean(1))  # finer observations weigh more
    wsum = np.bincount(inv, weights=w, minlength=m)

    def wmean(x):
        if x.ndim == 1:
            return np.bincount(inv, weights=x * w, minlength=m) / wsum
        return (
            np.stack([np.bincount(inv, weights=x[:, j] * w, minlength=m) for j in range(x.shape[1])], 1) / wsum[:, None]
        )

    means = wmean(a["means"])
    spread = merged_variance(wmean(((a["means"] - means[inv]) ** 2).sum(1)), cover)
    scales = np.sqrt(np.exp(2 * wmean(np.log(s))) + spread[:, None])
    # A sky cell's Gaussian covers its cell (sigma >= cell / 2): the shell is one smooth backdrop behind everything,
    # and member spread alone (a few footprints in a cell of many) leaves see-through gaps between cells.
    cell_sky = np.bincount(inv, weights=sky.astype(np.float64), minlength=m) > 0
    cell_size = np.exp2(np.bincount(inv, weights=level.astype(np.float64), minlength=m) / counts)
    scales = np.where(cell_sky[:, None], np.maximum(scales, SKY_COVER * cell_size[:, None]), scales)
    colors = wmean(a["colors"])
    if eco.opacity_merge == "union":
        opac = np.clip(
            1 - np.exp(np.bincount(inv, weights=np.log1p(-np.minimum(a["opacities"], 0.999)), minlength=m)), 0, 1
        )
    elif eco.opacity_merge == "mean":
        opac = np.bincount(inv, weights=a["opacities"], minlength=m) / counts
    else:
        raise ValueError(f"Economy.opacity_merge must be 'mean' or 'union', got {eco.opacity_merge!r}")
    order = np.lexsort((-a["opacities"], inv))
    first = order[np.r_[0, np.flatnonzero(np.diff(inv[order])) + 1]]
    quats = a["quats"][first]
    extras = wmean(a["extras"]) if "extras" in a else None
    log_scale = np.log(scales).mean(1)
    importance = opac * np.exp(2 * log_scale) * (1 + np.log(counts))
    idx = np.argsort(-importance, kind="stable")
    if emitted is not None and len(emitted.keys):
        cellular = idx < len(uniq)
        again = np.ones(len(idx), dtype=bool)
        again[cellular] = emitted.emit(uniq[idx[cellular]], log_scale[idx[cellular]])
        stats.merged_away += int((~again).sum())  # their members merged into the cell's earlier Gaussian
        idx = idx[again]
    if budget is not None:
        idx = idx[:budget]
    out = {
        "means": means[idx],
        "quats": quats[idx],
        "scales": scales[idx],
        "opacities": opac[idx],
        "colors": colors[idx],
    }
    if extras is not None:
        out["extras"] = extras[idx]
    if emitted is not None:
        cellular = idx[idx < len(uniq)]
        emitted.add(uniq[cellular], log_scale[cellular])
    dtype = torch.float64 if g.means.dtype == torch.float64 else torch.float32
    return Gaussians.from_numpy(**out, dtype=dtype)


# ------------------------------------------------------------------------------------------- finest observation
# A static surface observation is superseded where another frame-view sees the same surface point finer (smaller
# pixel footprint depth / focal): the surface keeps one pixel grid, the sharpest, instead of every frame's copy
# re-sampled at its own pose and averaged (gaussians.md, "Finest observation"). Where no finer view sees the point
# (occluded there, outside its image), the observation stays: the window's other frames fill what one cannot see.
FINEST_SMOOTH = 1.5  # a 2x2 pixel neighbourhood whose depths span less than this ratio is one continuous surface


class SurfaceView:
    """One frame-view's camera and the nearest static-surface depth at each of its pixels (a z-buffer of its own
    observations' centres; +inf where it has none: sky, a moving agent, a hole)."""

    def __init__(self, camera: Camera, points: np.ndarray):
        self.camera = camera
        self.focal = math.sqrt(camera.fx * camera.fy)
        H, W = camera.height, camera.width
        self.depth = np.full((H, W), np.inf)
        uv, z = camera.project(points)
        with np.errstate(invalid="ignore"):
            ok = (z > C.NEAR) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        np.minimum.at(self.depth, (uv[ok, 1].astype(np.int64), uv[ok, 0].astype(np.int64)), z[ok])
        self.footprint = np.where(ok, z, np.inf) / self.focal  # of `points`, as this view observed them

    def looks(self, points: np.ndarray, tol: float = FINEST_DEPTH_TOL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each of `points`: whether this view observes it (its surface depth there agrees within `tol`: within
        the depth range of the 2x2 pixel centres around it on a continuous surface, else at the nearest pixel), the
        pixel footprint it sees it at, and whether it lies in the free space this view saw through (more than `tol`
        in front of the surface at all four pixel centres, all four a surface: a silhouette or sky never carves)."""
        H, W = self.depth.shape
        uv, z = self.camera.project(points)
        with np.errstate(invalid="ignore"):
            ok = (z > C.NEAR) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        seen, past = np.zeros(len(points), dtype=bool), np.zeros(len(points), dtype=bool)
        at = np.flatnonzero(ok)  # the tests on the points in view only (most of a view's pairs face apart)
        u, v, zk = uv[at, 0], uv[at, 1], z[at]
        x0 = np.clip(np.floor(u - 0.5).astype(np.int64), 0, max(W - 2, 0))
        y0 = np.clip(np.floor(v - 0.5).astype(np.int64), 0, max(H - 2, 0))
        x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
        d = np.stack([self.depth[y0, x0], self.depth[y0, x1], self.depth[y1, x0], self.depth[y1, x1]], 1)
        lo, hi = d.min(1), d.max(1)
        near = self.depth[np.minimum(v.astype(np.int64), H - 1), np.minimum(u.astype(np.int64), W - 1)]
        with np.errstate(invalid="ignore"):
            smooth = np.isfinite(hi) & (hi < FINEST_SMOOTH * lo)
            on_smooth = smooth & (zk >= lo * (1 - tol)) & (zk <= hi * (1 + tol))
            at_edge = ~smooth & (np.abs(near - zk) <= tol * zk)
            seen[at] = on_smooth | at_edge
            past[at] = np.isfinite(hi) & (zk < lo * (1 - tol))
        return seen, np.where(ok, z, np.inf) / self.focal, past


def finest_observations(
    points: list[np.ndarray],
    cameras: list[Camera],
    earlier: list[SurfaceView],
    finer: float = math.inf,
    tol: float = FINEST_DEPTH_TOL,
    carve: bool = False,
) -> tuple[list[np.ndarray], list[SurfaceView]]:
    """`points[i]`: the static surface observations (centres) of frame-view i of a window, seen by `cameras[i]`.
    Returns which of each to keep and the window's `SurfaceView`s. An observation is dropped where another view of
    the window sees its point finer (equal footprints: the earlier view wins), or where a view of an earlier window
    (`earlier`, whose Gaussians are sent) sees it at less than `finer` x its own footprint (inf: at all). `tol`: the
    relative depth agreement of the same point (`SurfaceView.looks`). `carve`: also drop an observation in the free
    space an earlier window's view saw through (`SurfaceView.looks`: in front of what that view shows)."""
    views = [SurfaceView(c, p) for c, p in zip(cameras, points, strict=True)]
    keep = []
    for i, (p, own) in enumerate(zip(points, views)):
        k = np.ones(len(p), dtype=bool)
        for j, other in enumerate(views + earlier):
            if j == i or not k.any():
                continue
            rows = np.flatnonzero(k)
            seen, fp, past = other.looks(p[rows], tol)
            mine = own.footprint[rows]
            if j >= len(views):
                drop = seen & (fp < finer * mine)
                if carve:
                    drop |= past
            else:
                drop = seen & ((fp < mine) | ((fp == mine) & (j < i)))
            k[rows[drop]] = False
        keep.append(k)
    return keep, views


def _static_rows(g: Gaussians, threshold: float = DYNAMIC_THRESHOLD) -> np.ndarray:
    """The rows `split_dynamic` calls static."""
    if g.extras is None or g.extras.shape[1] == 0:
        return np.ones(len(g), dtype=bool)
    return ~(g.extras[:, 0] > threshold).detach().cpu().numpy()


def sky_rows(g: Gaussians) -> np.ndarray:
    """The rows of the sky shell (extras[:, SKY_CHANNEL], `lift`)."""
    if g.extras is None or g.extras.shape[1] <= SKY_CHANNEL:
        return np.zeros(len(g), dtype=bool)
    return (g.extras[:, SKY_CHANNEL] > 0.5).cpu().numpy()


def importance_order(g: Gaussians) -> Gaussians:
    s = g.scales.detach().double().clamp(C.SCALE_MIN, C.SCALE_MAX)
    imp = g.opacities.detach().double().clamp(0, 1) * torch.exp(2 * s.log().mean(1))
    return g.subset(torch.argsort(-imp, stable=True))


class CellTable:
    """The static cells a streamed scene has emitted so far (sorted int64 keys of `_cell_keys`) and the log of the
    geometric-mean scale of the Gaussian each got. A later window emits a cell again only when it sees it at least
    `finer` times finer (the ego drives towards what it first saw far away); else that window's members of the cell
    are merged away into the Gaussian already sent."""

    def __init__(self, finer: float):
        self.keys, self.log_scale = np.zeros(0, np.int64), np.zeros(0)
        self.log_finer = math.log(finer) if 0 < finer < math.inf else (math.inf if finer > 0 else -math.inf)

    def emit(self, keys: np.ndarray, log_scale: np.ndarray) -> np.ndarray:
        if not len(self.keys):
            return np.ones(len(keys), dtype=bool)
        i = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        hit = self.keys[i] == keys
        return ~hit | (log_scale < self.log_scale[i] - self.log_finer)

    def add(self, keys: np.ndarray, log_scale: np.ndarray) -> None:
        """Each key once, with the smallest log scale it was given. The new keys are sorted and inserted into the
        sorted table (a long clip's table holds a million keys: re-sorting it every window cost 2.6 s of a
        200-frame clip with the grid refined 2x)."""
        keys, log_scale = np.asarray(keys, np.int64), np.asarray(log_scale, np.float64)
        order = np.lexsort((log_scale, keys))
        k, ls = keys[order], log_scale[order]
        first = np.r_[True, k[1:] != k[:-1]] if len(k) else np.zeros(0, dtype=bool)
        k, ls = k[first], ls[first]
        i = np.searchsorted(self.keys, k)
        hit = self.keys[np.minimum(i, len(self.keys) - 1)] == k if len(self.keys) else np.zeros(len(k), dtype=bool)
        self.log_scale[i[hit]] = np.minimum(self.log_scale[i[hit]], ls[hit])
        self.keys = np.insert(self.keys, i[~hit], k[~hit])
        self.log_scale = np.insert(self.log_scale, i[~hit], ls[~hit])

    def holds(self, keys: np.ndarray) -> np.ndarray:
        """Per key: is it in the table."""
        if not len(self.keys):
            return np.zeros(len(keys), dtype=bool)
        return self.keys[np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)] == keys


# A later window re-emits a static cell it sees at least this many times finer. Measured (gaussians.md, "Window by
# window"): never re-emitting keeps exactly the cells of one union over all frames and rendered as well; 2 and 1.5
# added 1-4% Gaussians for no gain. Under the finest rule, re-emitting points seen 2x finer: +0.06 dB for +9 %.
WINDOW_FINER = math.inf


class WindowAggregator:
    """Paper eq. 3 + economy over a clip that arrives window by window (the models' 4-frame windows), so a scene can
    be streamed while it is generated: `add(frames, per_view)` returns that window's static Gaussians (importance
    order, final: nothing later changes them) and each of its frames' dynamic set (final too).

    The cell of a static place is the same as `aggregate_4d`'s (its footprint from the nearest camera of the whole
    track: the track is known before any frame is generated). What differs from one union over all frames: a cell
    already emitted by an earlier window is not merged with a later window's members (those bytes are sent); a later
    window emits it again only when it sees it `finer` times finer (see `CellTable`). Under the finest rule a later
    window's surface observation is dropped where a view of an earlier window saw its point (at less than `finer` x
    its footprint; `finest_observations`). One window with every frame is exactly `aggregate_4d`."""

    def __init__(
        self,
        frame_times,
        rig: list[RigCamera],
        ego_to_world: np.ndarray,
        *,
        in_ego_frame: bool = False,
        economy: Economy | None = None,
        image_size: tuple[int, int] | None = None,
        finer: float = WINDOW_FINER,
    ):
        self.economy = economy or Economy()
        self.ego_to_world = np.asarray(ego_to_world, dtype=np.float64)
        self.frame_times = np.asarray(frame_times, dtype=np.float64)
        self.rig, self.in_ego_frame = list(rig), in_ego_frame
        T = len(self.ego_to_world)
        if T != len(self.frame_times):
            raise ValueError(f"aggregate: {T} ego poses, {len(self.frame_times)} frame times")
        self.stats = AggregateStats()
        if image_size is not None:
            self.stats.naive = T * len(rig) * image_size[0] * image_size[1]
        self.centres = np.array([[rc.at(e).position for rc in rig] for e in self.ego_to_world]).reshape(T, -1, 3)
        self.focal = float(np.median([np.sqrt(rc.fx * rc.fy) for rc in rig])) if rig else 1.0
        self.cells = CellTable(finer)
        self.finer = finer
        self.views: list[SurfaceView] = []  # every frame-view added so far (`finest_observations`)
        self.seen: set[int] = set()
        if self.economy.static_rule not in ("finest", "merge"):
            raise ValueError(f"Economy.static_rule must be 'finest' or 'merge', got {self.economy.static_rule!r}")

    def add(
        self, frames: list[int], per_view: list[list[Gaussians]], deferred: bool = False
    ) -> tuple[Gaussians, dict[int, Gaussians]]:
        """`per_view[i][v]`: Gaussians of frame `frames[i]`, view v (see `aggregate_4d`). Each frame once.
        `deferred`: `per_view` is already `defer`'s output (the deferral is not run again)."""
        if len(frames) != len(per_view):
            raise ValueError(f"aggregate: {len(per_view)} frames of Gaussians for frames {frames}")
        T = len(self.ego_to_world)
        for t in frames:
            if not 0 <= t < T or t in self.seen:
                raise ValueError(f"aggregate: frame {t} out of range 0..{T - 1} or added twice")
        self.seen.update(frames)
        eco, st = self.economy, self.stats
        statics, dynamics, cameras = [], {}, []
        for t, views in zip(frames, per_view, strict=True):
            dyn_t = []
            for v, g in enumerate(views):
                st.lifted += len(g)
                if self.in_ego_frame:
                    g = transform(g, self.ego_to_world[t])
                s, d = split_dynamic(g)
                statics.append(s)
                cameras.append(self.rig[v].at(self.ego_to_world[t]) if v < len(self.rig) else None)
                dyn_t.append(d)
            dynamics[t] = Gaussians.cat(dyn_t) if dyn_t else Gaussians.empty()
        st.static_union += sum(len(s) for s in statics)
        st.dynamic_union += sum(len(d) for d in dynamics.values())
        if eco.enabled and eco.defer_nearer and not deferred:
            statics = self._defer_to_nearer(frames, statics, cameras, eco.defer_nearer)
        single = None
        if eco.enabled and eco.static_rule == "finest":
            statics, single = self._finest(statics, cameras)
        static = Gaussians.cat(statics) if statics else Gaussians.empty()
        if eco.enabled:
            budget = None if eco.static_budget is None else max(0, eco.static_budget - st.static_kept)
            static = economize(
                static, eco, self.centres.reshape(-1, 3), self.focal, st, budget, emitted=self.cells, single=single
            )
            dynamics = {
                t: economize(
                    d,
                    eco,
                    self.centres[t],
                    self.focal,
                    st,
                    eco.dynamic_budget,
                    cell_factor=eco.dynamic_cell_factor,
                    cover=eco.dynamic_cover,
                )
                if len(d)
                else d.detach()
                for t, d in dynamics.items()
            }
        else:
            static = importance_order(static.detach())
            dynamics = {t: d.detach() for t, d in dynamics.items()}
        st.static_kept += len(static)
        if static.extras is not None and static.extras.shape[1] > SKY_CHANNEL:
            st.sky_kept += int((static.extras[:, SKY_CHANNEL] > 0.5).sum())
        st.dynamic_kept += sum(len(d) for d in dynamics.values())
        return static, dynamics

    def defer(self, frames: list[int], per_view: list[list[Gaussians]]) -> list[list[Gaussians]]:
        """`per_view` less the static Gaussians `add` would leave to another frame (`Economy.defer_nearer`), the
        dynamic ones kept. Each Gaussian is tested on its own, so `defer` then `add(..., deferred=True)` is `add`
        alone; a caller runs it first where later work costs per Gaussian (the object claims: a long clip's first
        window keeps a fraction of its far Gaussians)."""
        eco = self.economy
        if not (eco.enabled and eco.defer_nearer):
            return per_view
        sets, cameras = [], []
        for t, views in zip(frames, per_view, strict=True):
            for v, g in enumerate(views):
                sets.append(transform(g, self.ego_to_world[t]) if self.in_ego_frame else g)
                cameras.append(self.rig[v].at(self.ego_to_world[t]) if v < len(self.rig) else None)
        drops = self._deferred(frames, sets, cameras, eco.defer_nearer)
        gone = sum(int(d.sum()) for d in drops)
        self.stats.lifted += gone  # `add` counts what it is given
        self.stats.static_union += gone
        drops = iter(drops)
        return [[g.subset(torch.as_tensor(~d)) if (d := next(drops)).any() else g for g in views] for views in per_view]

    def drop_emitted(self, frames: list[int], per_view: list[list[Gaussians]]) -> list[list[Gaussians]]:
        """`per_view` less the static rows `add` would merge away into a cell an earlier window emitted (under the
        "merge" rule with `finer` infinite, every such row: `CellTable`), each row's cell found as `economize` finds
        it; the rows it would drop as transparent, out of range or not finite, and the dynamic ones, are kept. A
        caller runs it first where later work costs per Gaussian (the deferral, the object claims: a long clip's
        windows see much of what the window before them emitted); the static Gaussians `add` returns are the same,
        as long as a static row the later work makes dynamic is dropped there too (generate's claims)."""
        eco = self.economy
        merging = eco.enabled and eco.static_rule == "merge" and self.cells.log_finer == math.inf
        if not (merging and len(self.cells.keys)):
            return per_view
        out, centres, gone = [], self.centres.reshape(-1, 3), 0
        for t, views in zip(frames, per_view, strict=True):
            row = []
            for g in views:
                drop = self._emitted_rows(transform(g, self.ego_to_world[t]) if self.in_ego_frame else g, centres)
                if drop.any():
                    gone += int(drop.sum())
                    g = g.subset(torch.as_tensor(~drop))
                row.append(g)
            out.append(row)
        st = self.stats  # counted as `add` counts them: given, static, merged away
        st.lifted += gone
        st.static_union += gone
        st.merged_away += gone
        st.extra["emitted_early"] = st.extra.get("emitted_early", 0) + gone
        return out

    def _emitted_rows(self, g: Gaussians, centres: np.ndarray) -> np.ndarray:
        eco = self.economy
        drop = np.zeros(len(g), dtype=bool)
        if not len(g):
            return drop
        a = {k: v.astype(np.float64) for k, v in g.numpy().items()}
        rows = _static_rows(g) & _finite_rows(a)
        opac = np.clip(np.nan_to_num(a["opacities"]), 0, 1)
        rows &= opac >= max(eco.min_opacity, C.ALPHA_MIN)
        sky = a["extras"][:, SKY_CHANNEL] > 0.5 if "extras" in a and a["extras"].shape[1] > SKY_CHANNEL else None
        sky = np.zeros(len(g), dtype=bool) if sky is None else sky
        at = np.flatnonzero(rows)
        if not len(at):
            return drop
        dist = nearest_distance(a["means"][at], centres)
        near = (dist <= eco.max_range) | sky[at]
        at, dist = at[near], dist[near]
        cell = np.where(sky[at], eco.sky_cell_factor, eco.cell_factor) * np.maximum(dist, 0.1) / self.focal
        level = np.round(np.log2(cell)).astype(np.int64)
        drop[at] = self.cells.holds(_cell_keys(a["means"][at], level, sky[at]))
        return drop

    def _other_cameras(self, frames: list[int]) -> tuple[list[list[Camera]], np.ndarray]:
        """The rig's cameras at the clip's frames outside `frames` (earlier and later), one frame each
        DEFER_SAMPLE_M of ego travel on either side, and those frames' ego positions."""
        own = set(frames)
        picked = []
        for side in ([t for t in range(len(self.ego_to_world)) if t < min(own)][::-1],
                     [t for t in range(len(self.ego_to_world)) if t > max(own)]):  # fmt: skip
            last = None
            for t in side:
                pos = self.ego_to_world[t][:3, 3]
                if last is None or np.linalg.norm(pos - last) >= DEFER_SAMPLE_M:
                    picked.append(t)
                    last = pos
        cams = [[rc.at(self.ego_to_world[t]) for rc in self.rig] for t in picked]
        return cams, np.array([self.ego_to_world[t][:3, 3] for t in picked]).reshape(-1, 3)

    def _defer_to_nearer(
        self, frames: list[int], statics: list[Gaussians], cameras: list[Camera | None], factor: float
    ) -> list[Gaussians]:
        """Each frame-view's static set less what another frame's camera (earlier or later) sees `factor` times
        nearer (`Economy.defer_nearer`; the sky shell stays)."""
        drops = self._deferred(frames, statics, cameras, factor)
        return [s.subset(torch.as_tensor(~d)) if d.any() else s for s, d in zip(statics, drops, strict=True)]

    def _deferred(
        self, frames: list[int], sets: list[Gaussians], cameras: list[Camera | None], factor: float
    ) -> list[np.ndarray]:
        """Per set (scene frame, seen by its camera), the static rows (not sky, DEFER_MIN_M or farther) whose place
        a frame outside `frames` (`_other_cameras`) has in its image `factor` times nearer."""
        drops = [np.zeros(len(s), dtype=bool) for s in sets]
        later, ego = self._other_cameras(frames)
        if not later:
            return drops
        reach = max(float(np.linalg.norm(rc.camera_to_ego[:3, 3])) for rc in self.rig) if self.rig else 0.0
        for s, cam, drop in zip(sets, cameras, drops, strict=True):
            if cam is None or not len(s):
                continue
            p = s.means.detach().double().cpu().numpy()
            near = np.linalg.norm(p - cam.position, axis=1) / factor
            rows = np.flatnonzero(_static_rows(s) & ~sky_rows(s) & (near * factor >= DEFER_MIN_M))
            if len(rows):
                # (point, other frame) pairs whose ego lies within the point's reach, every frame at once (a frame
                # view holds a few thousand points and the clip at most a few hundred sampled frames: a per-point
                # ball query's Python lists cost more than the whole matrix)
                # |p - e|^2 as |p|^2 + |e|^2 - 2 p.e (one matrix product), the reach grown by a millimetre for its
                # rounding: the pairs only choose whom to test, and a camera that sees a point `near` lies within
                # near + reach of its ego
                r = near[rows] + reach + 1e-3
                q = p[rows]
                d2 = (q * q).sum(1)[:, None] + (ego * ego).sum(1)[None, :] - 2.0 * (q @ ego.T)
                within = d2 <= (r * r)[:, None]
                for f in np.flatnonzero(within.any(0)):
                    pts = rows[within[:, f]]
                    for c in later[f]:
                        pts = pts[~drop[pts]]  # a row once dropped stays dropped: not tested again
                        if not len(pts):
                            break
                        uv, z = c.project(p[pts])
                        with np.errstate(invalid="ignore"):
                            seen = (z > C.NEAR) & (uv[:, 0] >= 0) & (uv[:, 0] < c.width) & (uv[:, 1] >= 0)
                            seen &= (uv[:, 1] < c.height) & (np.linalg.norm(p[pts] - c.position, axis=1) <= near[pts])
                        drop[pts[seen]] = True
            self.stats.extra["deferred"] = self.stats.extra.get("deferred", 0) + int(drop.sum())
        return drops

    def _finest(self, statics: list[Gaussians], cameras: list[Camera | None]) -> tuple[list[Gaussians], np.ndarray]:
        """Each frame-view's static set less the surface observations a finer view supersedes
        (`finest_observations`; the sky shell stays, for the cells), and which rows remain as they are."""
        sky = [sky_rows(s) for s in statics]
        known = [i for i, c in enumerate(cameras) if c is not None]
        points = [statics[i].means.detach().double().cpu().numpy()[~sky[i]] for i in known]
        cams = [cameras[i] for i in known]
        eco = self.economy
        keep, views = finest_observations(points, cams, self.views, self.finer, eco.finest_depth_tol, eco.carve)
        self.views += views
        kept, single = [], []
        for i, s in enumerate(statics):
            rows = np.ones(len(s), dtype=bool)
            if i in known:
                rows[np.flatnonzero(~sky[i])[~keep[known.index(i)]]] = False
            kept.append(s.subset(torch.as_tensor(rows)))
            single.append(~sky[i][rows])
        superseded = sum(len(s) for s in statics) - sum(len(s) for s in kept)
        self.stats.extra["superseded"] = self.stats.extra.get("superseded", 0) + superseded
        return kept, np.concatenate(single) if single else np.zeros(0, dtype=bool)

    def scene(self, statics: list[Gaussians], dynamics: dict[int, Gaussians], meta: dict | None = None) -> Scene4D:
        """The Scene4D of the windows added (their static parts in the order sent, every frame's dynamic set)."""
        T = len(self.ego_to_world)
        if set(dynamics) != set(range(T)):
            raise ValueError(f"aggregate: dynamics for frames {sorted(dynamics)}, the clip has {T}")
        static = Gaussians.cat(statics) if len(statics) > 1 else (statics[0] if statics else Gaussians.empty())
        return Scene4D(
            static, [dynamics[t] for t in range(T)], self.frame_times.copy(), self.rig, self.ego_to_world,
            dict(meta or {}),
        )  # fmt: skip


def windows(T: int, size: int) -> list[list[int]]:
    """Consecutive windows of `size` frames covering 0..T-1 (the last may be shorter)."""
    return [list(range(s, min(T, s + size))) for s in range(0, T, size)]


def aggregate_windows(
    per_view: list[list[Gaussians]],
    frame_times,
    rig: list[RigCamera],
    ego_to_world: np.ndarray,
    frame_windows: list[list[int]],
    *,
    in_ego_frame: bool = False,
    economy: Economy | None = None,
    meta: dict | None = None,
    image_size: tuple[int, int] | None = None,
    finer: float = WINDOW_FINER,
    fit=None,
) -> tuple[Scene4D, AggregateStats]:
    """Paper eq. 3 window by window, as the playground builds a scene (`WindowAggregator.add` of each window of
    `frame_windows` in order); `per_view[t][v]` as in `aggregate_4d`, which is one window of every frame.
    `fit(frames, static, earlier statics, dynamic)`: each window's static set as kept (a colour fit,
    `gaussians.colour_fit.fit_window`), before the next window is added."""
    T = len(per_view)
    if T != len(ego_to_world) or T != len(frame_times):
        raise ValueError(
            f"aggregate: {T} frames of Gaussians, {len(ego_to_world)} ego poses, {len(frame_times)} frame times"
        )
    agg = WindowAggregator(
        frame_times, rig, ego_to_world, in_ego_frame=in_ego_frame, economy=economy, image_size=image_size, finer=finer
    )
    statics, dynamics = [], {}
    for frames in frame_windows:
        static, dyn = agg.add(frames, [per_view[t] for t in frames])
        if fit is not None:
            static = fit(frames, static, statics, dyn)
        statics.append(static)
        dynamics.update(dyn)
    return agg.scene(statics, dynamics, meta), agg.stats


def aggregate_4d(
    per_view: list[list[Gaussians]],
    frame_times,
    rig: list[RigCamera],
    ego_to_world: np.ndarray,
    *,
    in_ego_frame: bool = False,
    economy: Economy | None = None,
    meta: dict | None = None,
    image_size: tuple[int, int] | None = None,
) -> tuple[Scene4D, AggregateStats]:
    """Paper eq. 3. `per_view[t][v]`: Gaussians of frame t, view v, with extras[:, 0] = dynamic probability
    (> 0.5 = dynamic); in world coordinates, or in the ego frame of frame t when `in_ego_frame`.
    Returns the Scene4D (static in importance order) and the statistics of the economy. (One window of every
    frame of `aggregate_windows`.)"""
    T = len(per_view)
    return aggregate_windows(
        per_view,
        frame_times,
        rig,
        ego_to_world,
        [list(range(T))],
        in_ego_frame=in_ego_frame,
        economy=economy,
        meta=meta,
        image_size=image_size,
    )
