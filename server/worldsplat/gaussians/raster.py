"""Stage 3 of the reference rasterizer (compositing) and the single entry point `rasterize`.

`rasterize(g, camera)` -> {"rgb" (H,W,3), "depth" (H,W), "alpha" (H,W), "extras" (H,W,K)}, differentiable with
autograd, on the device of the Gaussians. Two paths share `composite`: "tiled" (default; per-tile depth-sorted lists,
Gaussians processed in chunks of CHUNK so memory is bounded by TILE_SIZE^2 * CHUNK per tensor) and "brute"
(every pixel against every projected Gaussian; for tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from worldsplat.core.camera import Camera
from worldsplat.gaussians import constants as C
from worldsplat.gaussians.project import Projected, depth_order, project, tile_intersect
from worldsplat.gaussians.types import Gaussians


def composite(
    pixels: torch.Tensor, ids: torch.Tensor, proj: Projected, chunk: int = C.CHUNK
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Front-to-back compositing of the depth-sorted Gaussians `ids` at pixel centres `pixels` (P,2).

    Returns features (P,F), expected depth (P,) and alpha (P,). `Tv` is the transmittance of the pixel as if every
    touching Gaussian were added; because it never increases, "stop before a Gaussian whose T' < T_MIN" is exactly
    "include a Gaussian only while Tv' >= T_MIN", which lets a whole chunk be composited with one cumprod.
    Chunks grow geometrically up to `chunk` and finished pixels leave the active set, so dense scenes stop early.
    """
    P = pixels.shape[0]
    dt, dev = proj.uv.dtype, proj.uv.device
    feats = torch.zeros(P, proj.features.shape[1], dtype=dt, device=dev)
    depth = torch.zeros(P, dtype=dt, device=dev)
    weight_sum = torch.zeros(P, dtype=dt, device=dev)
    Tv = torch.ones(P, dtype=dt, device=dev)
    active = torch.arange(P, device=dev)
    support = C.EXTENT_SIGMA**2
    s, step = 0, min(256, chunk)
    while s < ids.shape[0] and active.numel() > 0:
        k = ids[s : s + step]
        s, step = s + step, min(chunk, 2 * step)
        px, T0 = pixels[active], Tv[active]
        uv, con, r = proj.uv[k], proj.conic[k], proj.radius[k]
        dx = px[:, None, 0] - uv[None, :, 0]
        dy = px[:, None, 1] - uv[None, :, 1]
        d = (con[None, :, 0] * dx + (2 * con[None, :, 1]) * dy) * dx + con[None, :, 2] * dy * dy
        with torch.no_grad():
            touch = d <= support
            if bool((r >= C.RADIUS_MAX).any()):  # the square test only bites for capped radii
                rf = r.to(dt)
                touch &= (dx.abs() <= rf) & (dy.abs() <= rf)
        alpha = torch.clamp_max(proj.opacity[k][None, :] * torch.exp(-0.5 * d), C.ALPHA_MAX)
        alpha = alpha * (touch & (alpha >= C.ALPHA_MIN))
        T_after = T0[:, None] * torch.cumprod(1 - alpha, dim=1)
        T_before = torch.cat([T0[:, None], T_after[:, :-1]], dim=1)
        with torch.no_grad():
            included = T_after >= C.T_MIN
        w = torch.where(included, alpha * T_before, torch.zeros_like(alpha))
        feats = feats.index_add(0, active, w @ proj.features[k])
        depth = depth.index_add(0, active, w @ proj.depth[k])
        weight_sum = weight_sum.index_add(0, active, w.sum(1))
        Tv = Tv.index_copy(0, active, T_after[:, -1])
        with torch.no_grad():
            active = active[T_after[:, -1] >= C.T_MIN]
    return feats, depth, weight_sum  # alpha = 1 - T = sum of weights (telescoping)


def _support_boxes(proj: Projected, width: int, height: int):
    """Each projected Gaussian's candidate pixels for the pairs paths, in `proj`'s order: a pixel is a candidate
    when its centre i + 0.5 lies in [u - ex, u + ex] (the support's box, `Projected.extent`), clamped to the image.
    Returns x0, x1, y0, y1 (inclusive; empty when x1 < x0), no gradient."""
    dt = proj.uv.dtype
    uv, e = proj.uv.detach(), proj.extent.to(dt)
    x0 = torch.ceil(uv[:, 0] - e[:, 0] - 0.5).clamp(0, width).to(torch.int64)
    x1 = torch.floor(uv[:, 0] + e[:, 0] - 0.5).clamp(-1, width - 1).to(torch.int64)
    y0 = torch.ceil(uv[:, 1] - e[:, 1] - 0.5).clamp(0, height).to(torch.int64)
    y1 = torch.floor(uv[:, 1] + e[:, 1] - 0.5).clamp(-1, height - 1).to(torch.int64)
    return x0, x1, y0, y1


def _pair_alpha(proj: Projected, k: torch.Tensor, px: torch.Tensor, py: torch.Tensor):
    """The pairs paths' alpha of Gaussians `k` (rows of `proj`) at pixels (px, py) (integer tensors broadcasting
    with `k`): the Mahalanobis distance d of the pixel centre, alpha = min(ALPHA_MAX, o exp(-d/2)) (differentiable)
    and `hit` (no gradient): the pair counts when d is inside the support and alpha >= ALPHA_MIN."""
    dt = proj.uv.dtype
    # one gather of the Gaussian's row for all its fields: `index_select` (not `x[k]`, which takes torch's slower
    # general indexing path on CPU: about half of `pair_weights`' time went there)
    fields = torch.cat([proj.uv, proj.conic, proj.opacity[:, None]], 1)
    row = fields[k] if isinstance(k, slice) else torch.index_select(fields, 0, k.reshape(-1)).reshape(*k.shape, 6)
    dx = (px.to(dt) + 0.5) - row[..., 0]
    dy = (py.to(dt) + 0.5) - row[..., 1]
    d = (row[..., 2] * dx + 2 * row[..., 3] * dy) * dx + row[..., 4] * dy * dy
    alpha = torch.clamp_max(row[..., 5] * torch.exp(-0.5 * d), C.ALPHA_MAX)
    with torch.no_grad():
        hit = (d <= C.EXTENT_SIGMA**2) & (alpha >= C.ALPHA_MIN)
    return d, alpha, hit


def _stop_weights(a: torch.Tensor, T_before: torch.Tensor) -> torch.Tensor:
    """Compositing weight a x T_before of a pair, zero from the first pair that would push the pixel's
    transmittance below T_MIN (T never rises, so this is "stop before it")."""
    return torch.where(T_before * (1 - a) >= C.T_MIN, a * T_before, torch.zeros_like(a))


def _pair_boxes(proj: Projected, width: int, height: int):
    """Depth order of `proj` and, in that order, each Gaussian's box of candidate pixels (a pixel is a candidate
    when its centre i + 0.5 lies in [u - ex, u + ex], the support's box): x0, y0, nx, count and the cumulative
    counts (no gradient)."""
    order = depth_order(proj)
    x0, x1, y0, y1 = (b[order] for b in _support_boxes(proj, width, height))
    nx, ny = (x1 - x0 + 1).clamp_min(0), (y1 - y0 + 1).clamp_min(0)
    counts = nx * ny
    return order, x0, y0, nx, counts, torch.cumsum(counts, 0)


def _batch_pairs(start: int, stop: int, base: int, x0, y0, nx, counts, ends):
    """The (rank in depth order, pixel x, pixel y) pairs of the Gaussians start..stop-1 of `_pair_boxes`."""
    dev = x0.device
    c = counts[start:stop]
    rank = torch.repeat_interleave(torch.arange(start, stop, device=dev), c)
    local = torch.arange(int(c.sum()), device=dev) - torch.repeat_interleave(ends[start:stop] - c - base, c)
    box = torch.index_select(torch.stack([x0, y0, nx], 1), 0, rank)
    return rank, box[:, 0] + local % box[:, 2], box[:, 1] + local // box[:, 2]


def composite_pairs(
    proj: Projected, width: int, height: int, pair_budget: int = 1 << 22
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sparse compositing over (pixel, Gaussian) pairs: each Gaussian meets only the pixel centres inside its
    support's bounding box. Gaussians are taken in depth order in batches of <= `pair_budget` pairs (memory bound); within a batch
    pairs are grouped by pixel and composited with a segmented (float64 log-space) scan, carrying each pixel's
    transmittance `Tv` between batches exactly like `composite` carries it between chunks."""
    dt, dev = proj.uv.dtype, proj.uv.device
    P, nf = width * height, proj.features.shape[1]
    feats = torch.zeros(P, nf, dtype=dt, device=dev)
    depth = torch.zeros(P, dtype=dt, device=dev)
    wsum = torch.zeros(P, dtype=dt, device=dev)
    Tv = torch.ones(P, dtype=dt, device=dev)
    if len(proj) == 0:
        return feats, depth, wsum
    with torch.no_grad():
        order, x0, y0, nx, counts, ends = _pair_boxes(proj, width, height)
    start = 0
    while start < len(order):
        with torch.no_grad():
            base = 0 if start == 0 else int(ends[start - 1])
            stop = int(torch.searchsorted(ends, base + pair_budget, right=True))
            stop = max(stop, start + 1)
            rank, px, py = _batch_pairs(start, stop, base, x0, y0, nx, counts, ends)
            pix = py * width + px
            live = Tv.detach()[pix] >= C.T_MIN
            rank, pix, px, py = rank[live], pix[live], px[live], py[live]
        start = stop
        if rank.numel() == 0:
            continue
        k = order[rank]
        _, alpha, hit = _pair_alpha(proj, k, px, py)
        with torch.no_grad():
            hit = hit.nonzero().squeeze(1)
            pix_h = pix[hit]
            grouped = torch.sort(pix_h, stable=True).indices  # by pixel, depth order kept inside
            idx = hit[grouped]
            pix_s = pix_h[grouped]
            first = torch.ones_like(pix_s, dtype=torch.bool)
            first[1:] = pix_s[1:] != pix_s[:-1]
            seg_start = torch.cummax(torch.where(first, torch.arange(len(pix_s), device=dev), 0), 0).values
        a = alpha[idx]
        la = torch.log1p(-a.to(torch.float64))
        cs = torch.cumsum(la, 0)
        excl = cs - la - (cs - la)[seg_start]  # sum of log(1 - alpha) before this pair, within its pixel
        T_before = Tv[pix_s] * torch.exp(excl).to(dt)
        w = _stop_weights(a, T_before)
        kk = k[idx]
        feats = feats.index_add(0, pix_s, w[:, None] * proj.features[kk])
        depth = depth.index_add(0, pix_s, w * proj.depth[kk])
        wsum = wsum.index_add(0, pix_s, w)
        Tv = Tv * torch.exp(torch.zeros(P, dtype=torch.float64, device=dev).index_add(0, pix_s, la)).to(dt)
    return feats, depth, wsum


def pair_weights(
    g: Gaussians, camera: Camera, pair_budget: int = 1 << 22
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The compositing weights of `render_view` at `camera` as sparse triples (pixel = y * W + x, input row of `g`,
    weight): the render's colour at a pixel is the sum of weight x colour over its triples (the "pairs" path's
    alpha x transmittance, the same tests and stops), so the render is linear in the colours with this matrix
    (`gaussians.lift.fit_colours`). float64 weights, no gradient."""
    width, height = camera.width, camera.height
    with torch.no_grad():
        proj = project(g, camera)
        dev = proj.uv.device
        empty = torch.zeros(0, dtype=torch.int64, device=dev)
        if len(proj) == 0:
            return empty, empty, torch.zeros(0, dtype=torch.float64, device=dev)
        order, x0, y0, nx, counts, ends = _pair_boxes(proj, width, height)
        Tv = torch.ones(width * height, dtype=torch.float64, device=dev)
        out_p, out_r, out_w = [], [], []
        start = 0
        while start < len(order):
            base = 0 if start == 0 else int(ends[start - 1])
            stop = max(int(torch.searchsorted(ends, base + pair_budget, right=True)), start + 1)
            rank, px, py = _batch_pairs(start, stop, base, x0, y0, nx, counts, ends)
            start = stop
            # gathers by `index_select` and each mask turned into indices once (torch's general `x[i]` / `x[mask]`
            # is several times slower on CPU at these sizes)
            take = torch.index_select
            pix = py * width + px
            live = (take(Tv, 0, pix) >= C.T_MIN).nonzero().squeeze(1)
            if live.numel() == 0:
                continue
            if live.numel() < pix.numel():
                rank, pix, px, py = (take(x, 0, live) for x in (rank, pix, px, py))
            k = take(order, 0, rank)
            _, alpha, hit = _pair_alpha(proj, k, px, py)
            hit = hit.nonzero().squeeze(1)
            pix_s, grouped = torch.sort(take(pix, 0, hit), stable=True)  # by pixel, depth order kept inside
            idx = take(hit, 0, grouped)
            first = torch.ones_like(pix_s, dtype=torch.bool)
            first[1:] = pix_s[1:] != pix_s[:-1]
            seg_start = torch.cummax(torch.where(first, torch.arange(len(pix_s), device=dev), 0), 0).values
            a = take(alpha, 0, idx).to(torch.float64)
            la = torch.log1p(-a)
            before = torch.cumsum(la, 0) - la  # sum of log(1 - alpha) over the pairs before, from the batch's start
            T_before = take(Tv, 0, pix_s) * torch.exp(before - take(before, 0, seg_start))
            w = _stop_weights(a, T_before)
            out_p.append(pix_s)
            out_r.append(take(proj.index, 0, take(k, 0, idx)))
            out_w.append(w)
            Tv = Tv * torch.exp(torch.zeros_like(Tv).index_add(0, pix_s, la))
        if not out_p:
            return empty, empty, torch.zeros(0, dtype=torch.float64, device=dev)
        return torch.cat(out_p), torch.cat(out_r), torch.cat(out_w)


# aligned_weights: the farthest pixel (in rows or columns) a pixel-aligned Gaussian's support box may reach from its
# own pixel for the stencil; a set reaching farther (stretched splats) takes `pair_weights`
STENCIL_REACH_MAX = 6


def aligned_weights(
    g: Gaussians, camera: Camera, reach_max: int = STENCIL_REACH_MAX
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """`pair_weights` of a pixel-aligned set (a lifted view at its own lifting camera: at most one projected Gaussian
    per pixel, its centre inside that pixel, every support box within `reach_max` pixels of it) computed on a
    stencil: each pixel meets only the Gaussians of the pixels around it, one stencil offset at a time on the whole
    image (the offset's pairs are the image's Gaussians shifted by it; offsets no pair hits are left out), ordered
    by depth rank per pixel, with the pairs path's own box, alpha and transmittance rules (`_support_boxes`,
    `_pair_alpha`, `_stop_weights`). The same weights as `pair_weights` (float64; zero weights left out), in pixel
    order; a set that is not pixel-aligned gets `pair_weights` itself. No gradient."""
    width, height = camera.width, camera.height
    with torch.no_grad():
        proj = project(g, camera)
        dev = proj.uv.device
        M = len(proj)
        if M == 0:
            return pair_weights(g, camera)
        cell = torch.floor(proj.uv.detach()).to(torch.int64)
        cx, cy = cell[:, 0], cell[:, 1]
        if not bool(((cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)).all()):
            return pair_weights(g, camera)
        P = width * height
        at = torch.full((P,), -1, dtype=torch.int64, device=dev)  # the projected Gaussian in each pixel
        at[cy * width + cx] = torch.arange(M, device=dev)
        occupied = at >= 0
        if int(occupied.sum()) != M:  # two Gaussians in one pixel
            return pair_weights(g, camera)
        x0, x1, y0, y1 = _support_boxes(proj, width, height)
        some = (x1 >= x0) & (y1 >= y0)
        reach = torch.stack([cx - x0, x1 - cx, cy - y0, y1 - cy], 1)[some]
        R = max(int(reach.max()) if reach.numel() else 0, 0)
        if R > reach_max:
            return pair_weights(g, camera)
        j = at.clamp_min(0)
        none = proj.index[:0]
        # the projected Gaussians laid out on the image (what `_pair_alpha` reads: uv, conic, opacity)
        grid = Projected(none, proj.uv[j], proj.conic[j], none, none, none, proj.opacity[j], proj.features[:0])
        rank = torch.empty(M, dtype=torch.int64, device=dev)
        order = depth_order(proj)
        rank[order] = torch.arange(M, device=dev)
        # an offset o is inside no support when (|o| - the farthest centre from its pixel's centre)^2 / the largest
        # covariance eigenvalue exceeds the support's d (d >= |pixel - uv|^2 x the conic's smallest eigenvalue)
        A, B, Cc = (t.to(torch.float64) for t in proj.conic.unbind(1))
        lam_min = max(float((0.5 * (A + Cc) - torch.sqrt(0.25 * (A - Cc) ** 2 + B * B)).min()), 0.0)
        dev_max = float((proj.uv.detach() - (cell + 0.5)).abs().max()) * 2**0.5 + 1e-3
        offsets = [
            (ox, oy)
            for oy in range(-R, R + 1)
            for ox in range(-R, R + 1)
            if max((ox * ox + oy * oy) ** 0.5 - dev_max, 0.0) ** 2 * lam_min <= C.EXTENT_SIGMA**2 + 1e-3
        ]
        ox = torch.tensor([o[0] for o in offsets], device=dev)[:, None]
        oy = torch.tensor([o[1] for o in offsets], device=dev)[:, None]
        gx = torch.arange(width, device=dev).repeat(height)
        gy = torch.arange(height, device=dev).repeat_interleave(width)
        px, py = gx + ox, gy + oy  # (offsets, P): the pixel each Gaussian meets at each offset
        _, alpha, hit = _pair_alpha(grid, slice(None), px, py)
        hit &= occupied & (px >= x0[j]) & (px <= x1[j]) & (py >= y0[j]) & (py <= y1[j])
        a_src = torch.where(hit, alpha.to(torch.float64), 0.0).reshape(-1, height, width)
        k_src = torch.where(hit, torch.where(occupied, rank[j], M).to(torch.int32), M).reshape(-1, height, width)
        S = len(offsets)
        a_at = torch.zeros(height, width, S, dtype=torch.float64, device=dev)  # per receiving pixel, per offset
        k_at = torch.full((height, width, S), M, dtype=torch.int32, device=dev)
        for s_, (ox_, oy_) in enumerate(offsets):
            src = (slice(max(-oy_, 0), height - max(oy_, 0)), slice(max(-ox_, 0), width - max(ox_, 0)))
            dst = (slice(max(oy_, 0), height + min(oy_, 0)), slice(max(ox_, 0), width + min(ox_, 0)))
            a_at[dst + (s_,)] = a_src[s_][src]
            k_at[dst + (s_,)] = k_src[s_][src]
        keys_s, perm = torch.sort(k_at.reshape(P, S), dim=1)  # per pixel in depth order, misses last (alpha 0)
        a = a_at.reshape(P, S).gather(1, perm)
        T_before = torch.cumprod(torch.cat([torch.ones_like(a[:, :1]), 1 - a[:, :-1]], 1), 1)
        w = _stop_weights(a, T_before)
        keep = (keys_s < M) & (w > 0)
        pix = torch.repeat_interleave(torch.arange(P, device=dev), keep.sum(1))
        rows = proj.index[order][keys_s.masked_select(keep).to(torch.int64)]
        return pix, rows, w.masked_select(keep)


def pixel_centres(x0: int, x1: int, y0: int, y1: int, dtype, device) -> torch.Tensor:
    ys, xs = torch.meshgrid(
        torch.arange(y0, y1, device=device, dtype=dtype),
        torch.arange(x0, x1, device=device, dtype=dtype),
        indexing="ij",
    )
    return torch.stack([xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5], -1)


METHODS = ("tiled", "pairs", "brute")


def rasterize(
    g: Gaussians, camera: Camera, *, method: str = "tiled", tile_size: int = C.TILE_SIZE, chunk: int = C.CHUNK
) -> dict[str, torch.Tensor]:
    """Render Gaussians at a camera per web/docs/splatting-math.md (black background).

    Returns rgb (H,W,3), depth (H,W) expected camera z (not normalized), alpha (H,W), extras (H,W,K) (K may be 0)
    and visible (int: Gaussians that survived projection). Never returns NaN/Inf. Safe inside an autocast region:
    the math runs with autocast off (bf16 compositing moves depths by metres and breaks index_add's dtypes).
    """
    with torch.autocast(device_type=g.means.device.type, enabled=False):
        return _rasterize(g, camera, method=method, tile_size=tile_size, chunk=chunk)


def _rasterize(g: Gaussians, camera: Camera, *, method: str, tile_size: int, chunk: int) -> dict[str, torch.Tensor]:
    if method not in METHODS:
        raise ValueError(f"rasterize: method must be one of {', '.join(METHODS)}, got {method!r}")
    W, H = camera.width, camera.height
    proj = project(g, camera)
    dt, dev = proj.uv.dtype, proj.uv.device
    nf = proj.features.shape[1]
    if method == "pairs":
        feats, depth, alpha = composite_pairs(proj, W, H)
        feats, depth, alpha = feats.reshape(H, W, nf), depth.reshape(H, W), alpha.reshape(H, W)
    elif method == "brute":
        order = depth_order(proj)
        pix = pixel_centres(0, W, 0, H, dt, dev)
        parts = [composite(pix[s : s + 4096], order, proj, chunk) for s in range(0, pix.shape[0], 4096)]
        feats = torch.cat([p[0] for p in parts]).reshape(H, W, nf)
        depth = torch.cat([p[1] for p in parts]).reshape(H, W)
        alpha = torch.cat([p[2] for p in parts]).reshape(H, W)
    else:
        tl = tile_intersect(proj, W, H, tile_size)
        rows_f, rows_d, rows_a = [], [], []
        offsets = tl.offsets.tolist()
        for ty in range(tl.tiles_y):
            y0, y1 = ty * tile_size, min(H, (ty + 1) * tile_size)
            tf, td, ta = [], [], []
            for tx in range(tl.tiles_x):
                x0, x1 = tx * tile_size, min(W, (tx + 1) * tile_size)
                k = ty * tl.tiles_x + tx
                pix = pixel_centres(x0, x1, y0, y1, dt, dev)
                f, d, a = composite(pix, tl.ids[offsets[k] : offsets[k + 1]], proj, chunk)
                tf.append(f.reshape(y1 - y0, x1 - x0, nf))
                td.append(d.reshape(y1 - y0, x1 - x0))
                ta.append(a.reshape(y1 - y0, x1 - x0))
            rows_f.append(torch.cat(tf, 1))
            rows_d.append(torch.cat(td, 1))
            rows_a.append(torch.cat(ta, 1))
        feats, depth, alpha = torch.cat(rows_f, 0), torch.cat(rows_d, 0), torch.cat(rows_a, 0)
    return {"rgb": feats[..., :3], "depth": depth, "alpha": alpha, "extras": feats[..., 3:], "visible": len(proj)}


@dataclass
class View:
    """One rendered image: rgb (H,W,3) uint8 = round(255 clamp(c, 0, 1)) (the shared-vector convention), alpha
    (H,W) float32 accumulated opacity (1 - alpha marks the holes) and depth (H,W) float32 expected camera z
    normalised by alpha, inf where alpha < 0.5."""

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray


def render_view(g: Gaussians, camera: Camera) -> View:
    """The one way to render Gaussians to an 8-bit image (tracks, videos, refinement, evaluation, bench): the
    reference rasterizer's sparse "pairs" path, no gradient, no culling beyond the spec's own (exact) tests."""
    with torch.no_grad():
        out = rasterize(g, camera, method="pairs")
    rgb = torch.round(out["rgb"].clamp(0, 1) * 255).to(torch.uint8).cpu().numpy()
    alpha = out["alpha"].float().cpu().numpy().astype(np.float32)
    depth = (out["depth"] / out["alpha"].clamp_min(1e-6)).float().cpu().numpy()
    depth = np.where(alpha >= 0.5, depth, np.inf).astype(np.float32)
    return View(rgb, alpha, depth)
