"""4D aggregation (paper eq. 3) and the economy that makes a scene carry only what it needs.

Eq. 3: the per-frame, per-view Gaussians (already in the world frame, or moved there by the ego poses) split by
their dynamic mask into a static union over all frames and views, plus each frame's own dynamic set:

    G(t) = U_{t', v} G_static(t', v)  +  U_v G_dynamic(t, v)

The naive union repeats every surface once per frame and view that sees it. The economy then
1. drops Gaussians that cannot show (transparent: opacity < `min_opacity`; out of range: farther than `max_range`
   from every camera position, except the sky shell flagged in extras[:, SKY_CHANNEL]; non-finite);
2. merges repeats with one resolution per place: a voxel hash whose cell is `cell_factor` x the pixel footprint
   seen from the nearest camera of the track (distance / focal), rounded to a power of two. Every observation of a
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

from worldsplat.core.camera import RigCamera
from worldsplat.gaussians import constants as C
from worldsplat.gaussians.lift import SKY_CHANNEL
from worldsplat.gaussians.types import Gaussians, Scene4D

DYNAMIC_THRESHOLD = 0.5  # extras[:, 0] (dynamic probability / mask) above this -> dynamic
SKY_COVER = 0.5  # a merged sky Gaussian's std is at least this fraction of its cell
DYNAMIC_CELL_FACTOR = 1.0  # cell of the per-frame dynamic sets, in pixel footprints (static: Economy.cell_factor)
DYNAMIC_COVER = 0.0  # > 0: merged dynamic std = this x the patch width (see merged_variance; 0.7 = FOOTPRINT)


@dataclass
class Economy:
    """Thresholds of the economy (defaults measured in web/docs/gaussians.md)."""

    enabled: bool = True
    min_opacity: float = 0.02  # "transparent": below this a Gaussian barely shows
    max_range: float = 150.0  # m from the nearest camera position ("out of range")
    cell_factor: float = 3.0  # voxel cell = cell_factor x the pixel footprint seen from the nearest camera
    sky_cell_factor: float = 3.0  # the same for the sky shell (far and smooth: may be coarser)
    # A frame's dynamic set is seen only from that frame's cameras, at the distance it was observed (a static
    # place is mostly seen from farther than its nearest camera), so its cells are one footprint. `dynamic_cover`
    # > 0 lets coarser dynamic cells stay closed (merged std = cover x the patch width; see merged_variance): a
    # cheaper, softer setting measured in gaussians.md.
    dynamic_cell_factor: float = DYNAMIC_CELL_FACTOR
    dynamic_cover: float = DYNAMIC_COVER
    opacity_merge: str = "mean"  # merged opacity: "mean" of the members or "union" 1 - prod(1 - o)
    static_budget: int | None = None  # cap on static Gaussians (most important kept)
    dynamic_budget: int | None = None  # cap per frame


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


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """3x3 rotation -> wxyz unit quaternion."""
    m = np.asarray(R, dtype=np.float64)
    t = np.trace(m)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k]) * 2
        q = [0.0] * 4
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def transform(g: Gaussians, m: np.ndarray) -> Gaussians:
    """Apply a rigid 4x4 transform (e.g. ego_to_world[t]) to Gaussians: means and rotations."""
    R = torch.as_tensor(np.asarray(m)[:3, :3], dtype=g.means.dtype)
    t = torch.as_tensor(np.asarray(m)[:3, 3], dtype=g.means.dtype)
    qr = torch.as_tensor(quat_from_matrix(np.asarray(m)[:3, :3]), dtype=g.quats.dtype).expand_as(g.quats)
    return Gaussians(g.means @ R.T + t, quat_mul(qr, g.quats), g.scales, g.opacities, g.colors, g.extras)


def split_dynamic(g: Gaussians, threshold: float = DYNAMIC_THRESHOLD) -> tuple[Gaussians, Gaussians]:
    if g.extras is None or g.extras.shape[1] == 0:
        return g, g.subset(torch.zeros(len(g), dtype=torch.bool))
    dyn = g.extras[:, 0] > threshold
    return g.subset(~dyn), g.subset(dyn)


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


def nearest_distance(p: np.ndarray, centres: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    out = np.full(len(p), np.inf)
    for s in range(0, len(p), chunk):
        q = p[s : s + chunk]
        for c in centres:
            out[s : s + chunk] = np.minimum(out[s : s + chunk], np.sqrt(((q - c) ** 2).sum(1)))
    return out


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


def economize(
    g: Gaussians,
    eco: Economy,
    camera_centres: np.ndarray,
    focal: float,
    stats: AggregateStats | None = None,
    budget: int | None = None,
    cell_factor: float | None = None,
    cover: float = 0.0,
) -> Gaussians:
    """Drop, merge, order by importance, cap (see the module docstring). Works on detached numpy copies; the
    result is a new Gaussians (isotropic inputs stay isotropic; a merged cell takes the rotation of its most
    opaque member). `cell_factor` overrides `eco.cell_factor` (the dynamic sets use `eco.dynamic_cell_factor`).
    `cover` > 0: a merged Gaussian stands for the surface patch its members tile, not for their centres
    (see `merged_variance`)."""
    stats = stats or AggregateStats()
    a = {k: v.astype(np.float64) for k, v in g.numpy().items()}
    if len(a["means"]) == 0:
        return g.detach()
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
    dist, sky = dist[~far], sky[~far]
    n = len(a["means"])
    if n == 0:
        return Gaussians.empty(0 if g.extras is None else g.extras.shape[1])
    s = np.clip(a["scales"], C.SCALE_MIN, C.SCALE_MAX)
    # One resolution per place: the pixel footprint from the nearest camera, times cell_factor, rounded to a
    # power of two. Every observation of a surface (any frame, any view, any depth) lands in the same cell.
    cf = eco.cell_factor if cell_factor is None else cell_factor
    cell = np.where(sky, eco.sky_cell_factor, cf) * np.maximum(dist, 0.1) / focal
    level = np.round(np.log2(cell)).astype(np.int64)
    keys = _cell_keys(a["means"], level, sky)
    uniq, inv, counts = np.unique(keys, return_inverse=True, return_counts=True)
    m = len(uniq)
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
    importance = opac * np.exp(2 * np.log(scales).mean(1)) * (1 + np.log(counts))
    idx = np.argsort(-importance, kind="stable")
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
    return Gaussians.from_numpy(**out, dtype=torch.float64 if g.means.dtype == torch.float64 else torch.float32)


def importance_order(g: Gaussians) -> Gaussians:
    s = g.scales.detach().double().clamp(C.SCALE_MIN, C.SCALE_MAX)
    imp = g.opacities.detach().double().clamp(0, 1) * torch.exp(2 * s.log().mean(1))
    return g.subset(torch.argsort(-imp, stable=True))


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
    Returns the Scene4D (static in importance order) and the statistics of the economy."""
    economy = economy or Economy()
    ego_to_world = np.asarray(ego_to_world, dtype=np.float64)
    T = len(per_view)
    if T != len(ego_to_world) or T != len(frame_times):
        raise ValueError(
            f"aggregate: {T} frames of Gaussians, {len(ego_to_world)} ego poses, {len(frame_times)} frame times"
        )
    stats = AggregateStats()
    if image_size is not None:
        stats.naive = T * len(rig) * image_size[0] * image_size[1]
    statics, dynamics = [], []
    for t, views in enumerate(per_view):
        dyn_t = []
        for g in views:
            stats.lifted += len(g)
            if in_ego_frame:
                g = transform(g, ego_to_world[t])
            st, dy = split_dynamic(g)
            statics.append(st)
            dyn_t.append(dy)
        dynamics.append(Gaussians.cat(dyn_t) if dyn_t else Gaussians.empty())
    static = Gaussians.cat(statics) if statics else Gaussians.empty()
    stats.static_union = len(static)
    stats.dynamic_union = sum(len(d) for d in dynamics)
    centres = np.array([[rc.at(e).position for rc in rig] for e in ego_to_world])  # (T,V,3)
    focal = float(np.median([np.sqrt(rc.fx * rc.fy) for rc in rig])) if rig else 1.0
    if economy.enabled:
        static = economize(static, economy, centres.reshape(-1, 3), focal, stats, economy.static_budget)
        dynamics = [
            economize(
                d,
                economy,
                centres[t],
                focal,
                stats,
                economy.dynamic_budget,
                cell_factor=economy.dynamic_cell_factor,
                cover=economy.dynamic_cover,
            )
            if len(d)
            else d.detach()
            for t, d in enumerate(dynamics)
        ]
    else:
        static = importance_order(static.detach())
        dynamics = [d.detach() for d in dynamics]
    stats.static_kept = len(static)
    if static.extras is not None and static.extras.shape[1] > SKY_CHANNEL:
        stats.sky_kept = int((static.extras[:, SKY_CHANNEL] > 0.5).sum())
    stats.dynamic_kept = sum(len(d) for d in dynamics)
    return Scene4D(
        static, dynamics, np.asarray(frame_times, dtype=np.float64), list(rig), ego_to_world, dict(meta or {})
    ), stats
