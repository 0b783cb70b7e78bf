"""Stages 1-2 of the reference rasterizer: sanitize and project (EWA) Gaussians; intersect them with tiles.

Every formula follows web/docs/splatting-math.md. All stages are differentiable w.r.t. the float inputs
(culling decisions are made on detached values and applied by index selection, so a dropped Gaussian, even one
holding NaN, never contributes a NaN to the gradient).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from worldsplat.core.camera import Camera
from worldsplat.gaussians import constants as C
from worldsplat.gaussians.types import Gaussians
from worldsplat_models.geometry import normalize_quaternion, quaternion_to_matrix


@dataclass
class Projected:
    """The M Gaussians that survive sanitizing and projection, in input order."""

    index: torch.Tensor  # (M,) int64 rows of the input
    uv: torch.Tensor  # (M,2) pixel centre
    conic: torch.Tensor  # (M,3) inverse 2D covariance (A, B, C): d = A dx^2 + 2 B dx dy + C dy^2
    depth: torch.Tensor  # (M,) camera z
    radius: torch.Tensor  # (M,) int64 px
    extent: torch.Tensor  # (M,2) px: half-size of the support's bounding box, min(radius, 3 sqrt(cov_xx|yy))
    opacity: torch.Tensor  # (M,)
    features: torch.Tensor  # (M,3+K) colour then extras, composited alike

    def __len__(self) -> int:
        return int(self.index.shape[0])


def compute_dtype(g: Gaussians) -> torch.dtype:
    """fp16/bf16 inputs are upcast to float32; float64 stays (gradcheck)."""
    return torch.float64 if g.means.dtype == torch.float64 else torch.float32


def sanitize(g: Gaussians) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Drop Gaussians with any non-finite mean/quat/scale/opacity/colour or opacity < ALPHA_MIN; normalize
    quaternions (|q| < QUAT_EPS -> identity); clamp scale, opacity and colour. Returns (kept rows, fields)."""
    dt = compute_dtype(g)
    f = {k: getattr(g, k).to(dt) for k in ("means", "quats", "scales", "opacities", "colors")}
    with torch.no_grad():
        finite = torch.ones(len(g), dtype=torch.bool, device=g.means.device)
        for k, t in f.items():
            finite &= torch.isfinite(t[:, None] if t.ndim == 1 else t).all(dim=1)
        keep = finite & (f["opacities"].clamp(0, 1) >= C.ALPHA_MIN)
        index = keep.nonzero().squeeze(1)
    f = {k: t[index] for k, t in f.items()}
    f["quats"] = normalize_quaternion(f["quats"], C.QUAT_EPS)
    f["scales"] = f["scales"].clamp(C.SCALE_MIN, C.SCALE_MAX)
    f["opacities"] = f["opacities"].clamp(0.0, 1.0)
    f["colors"] = f["colors"].clamp(0.0, 1.0)
    if g.extras is not None:
        f["extras"] = torch.nan_to_num(g.extras.to(dt)[index], nan=0.0, posinf=0.0, neginf=0.0)
    return index, f


def camera_tensors(camera: Camera, dtype: torch.dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    m = torch.as_tensor(camera.world_to_camera, dtype=torch.float64)
    return m[:3, :3].to(dtype=dtype, device=device), m[:3, 3].to(dtype=dtype, device=device)


PRECULL_MIN = 50_000


def view_candidates(g: Gaussians, camera: Camera) -> torch.Tensor:
    """Rows that can possibly reach the image: centre beyond NEAR and within a rigorous pixel margin of the image.
    The margin bounds the radius: sqrt(lambda_max) <= sqrt(2) (f / z) s_max sqrt(1 + lim^2) + 1 (each row of the
    clamped Jacobian has norm <= (f / z) sqrt(1 + lim^2), so its Frobenius norm <= sqrt(2) times that; the dilation
    and eigenvalue floor add < 1 px). A cheap exact pre-cull: it only removes
    Gaussians the screen test would drop, so large scenes project only what a view can show."""
    with torch.no_grad():
        R, t = camera_tensors(camera, torch.float32, g.means.device)
        p = g.means.detach().float() @ R.T + t
        z = p[:, 2]
        smax = g.scales.detach().float().clamp(C.SCALE_MIN, C.SCALE_MAX).max(1).values
        lim_x = C.CLAMP * 0.5 * camera.width / camera.fx
        lim_y = C.CLAMP * 0.5 * camera.height / camera.fy
        f = max(camera.fx, camera.fy)
        zs = z.clamp_min(C.NEAR)
        bound = C.EXTENT_SIGMA * ((f / zs) * smax * math.sqrt(2 * (1 + max(lim_x, lim_y) ** 2)) + 1.0) + 2.0
        u = camera.fx * p[:, 0] / zs + camera.cx
        v = camera.fy * p[:, 1] / zs + camera.cy
        ok = (z > C.NEAR) & (u > -bound) & (u < camera.width + bound) & (v > -bound) & (v < camera.height + bound)
        return ok.nonzero().squeeze(1)


def project(g: Gaussians, camera: Camera) -> Projected:
    """Sanitize, near-cull, EWA-project, cull by determinant and screen extent. Differentiable."""
    pre = None
    if len(g) > PRECULL_MIN:  # big scenes: an exact cheap pre-cull first (see view_candidates)
        pre = view_candidates(g, camera)
        g = g.subset(pre)
    index, f = sanitize(g)
    dt, dev = f["means"].dtype, f["means"].device
    R, t = camera_tensors(camera, dt, dev)
    p = f["means"] @ R.T + t
    with torch.no_grad():
        near = (p[:, 2] > C.NEAR).nonzero().squeeze(1)  # positive-phrased: NaN fails
    index, p = index[near], p[near]
    f = {k: v[near] for k, v in f.items()}

    W, H = camera.width, camera.height
    lim_x = C.CLAMP * 0.5 * W / camera.fx
    lim_y = C.CLAMP * 0.5 * H / camera.fy
    x, y, z = p.unbind(-1)
    tx = z * (x / z).clamp(-lim_x, lim_x)
    ty = z * (y / z).clamp(-lim_y, lim_y)
    # T = J R_wc R(q) diag(s) (2x3), written out because J has only four non-zeros; cov2d = T T^T + DILATION I.
    M = torch.einsum("ij,njk->nik", R, quaternion_to_matrix(f["quats"])) * f["scales"][:, None, :]
    iz = 1.0 / z
    T0 = (camera.fx * iz)[:, None] * (M[:, 0] - (tx * iz)[:, None] * M[:, 2])
    T1 = (camera.fy * iz)[:, None] * (M[:, 1] - (ty * iz)[:, None] * M[:, 2])
    a0, b, c0 = (T0 * T0).sum(-1), (T0 * T1).sum(-1), (T1 * T1).sum(-1)
    a, c = a0 + C.DILATION, c0 + C.DILATION
    # det(cov2d) = |T0 x T1|^2 + DILATION (a0 + c0) + DILATION^2 (Cauchy-Binet). Equal to a c - b^2, but without
    # its catastrophic cancellation in float32 for needle Gaussians.
    cross = torch.linalg.cross(T0, T1, dim=-1)
    det = (cross * cross).sum(-1) + C.DILATION * (a0 + c0) + C.DILATION**2
    u = camera.fx * x / z + camera.cx
    v = camera.fy * y / z + camera.cy
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp_min(mid * mid - det, C.EIG_FLOOR))
        radius = torch.ceil(C.EXTENT_SIGMA * torch.sqrt(lam)).clamp(max=C.RADIUS_MAX)
        radius = torch.nan_to_num(radius, nan=0.0, posinf=C.RADIUS_MAX).to(torch.int64)
        on = (det > C.DET_MIN) & (u + radius > 0) & (u - radius < W) & (v + radius > 0) & (v - radius < H)
        keep = on.nonzero().squeeze(1)
    det = det[keep]
    conic = torch.stack([c[keep] / det, -b[keep] / det, a[keep] / det], -1)
    feats = f["colors"][keep]
    if "extras" in f:
        feats = torch.cat([feats, f["extras"][keep]], -1)
    with torch.no_grad():  # the ellipse d <= 9 lies within +-3 sqrt(cov_xx) in x (likewise y): a tight box
        ext = torch.stack([C.EXTENT_SIGMA * torch.sqrt(a[keep]), C.EXTENT_SIGMA * torch.sqrt(c[keep])], -1)
        ext = torch.minimum(torch.nan_to_num(ext, nan=0.0, posinf=C.RADIUS_MAX), radius[keep, None].to(ext.dtype))
    index = index[keep] if pre is None else pre[index[keep]]
    return Projected(
        index, torch.stack([u[keep], v[keep]], -1), conic, z[keep], radius[keep], ext, f["opacities"][keep], feats
    )


def depth_order(proj: Projected) -> torch.Tensor:
    """Sort key: camera depth ascending, ties by lower input index (the projected set is in input order)."""
    return torch.sort(proj.depth.detach(), stable=True).indices


@dataclass
class TileLists:
    tile_size: int
    tiles_x: int
    tiles_y: int
    offsets: torch.Tensor  # (tiles+1,) int64: tile k's Gaussians are ids[offsets[k]:offsets[k+1]]
    ids: torch.Tensor  # (pairs,) int64 rows of the Projected set, depth-sorted within each tile


def tile_intersect(proj: Projected, width: int, height: int, tile_size: int = C.TILE_SIZE) -> TileLists:
    """Per-tile, depth-sorted lists of the Gaussians whose support box (`extent`, within the square
    [u-r,u+r]x[v-r,v+r]) overlaps the tile."""
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    ntiles = tiles_x * tiles_y
    dev = proj.uv.device
    with torch.no_grad():
        order = depth_order(proj)
        uv, e = proj.uv.detach()[order], proj.extent[order]
        # Tiles that can hold a pixel centre inside the support's bounding box.
        x0 = torch.floor((uv[:, 0] - e[:, 0]) / tile_size).clamp(0, tiles_x - 1).to(torch.int64)
        x1 = torch.floor((uv[:, 0] + e[:, 0]) / tile_size).clamp(0, tiles_x - 1).to(torch.int64)
        y0 = torch.floor((uv[:, 1] - e[:, 1]) / tile_size).clamp(0, tiles_y - 1).to(torch.int64)
        y1 = torch.floor((uv[:, 1] + e[:, 1]) / tile_size).clamp(0, tiles_y - 1).to(torch.int64)
        nx, ny = x1 - x0 + 1, y1 - y0 + 1
        counts = nx * ny
        rank = torch.repeat_interleave(torch.arange(len(order), device=dev), counts)
        start = torch.cumsum(counts, 0) - counts
        local = torch.arange(int(counts.sum()), device=dev) - start[rank]
        tx = x0[rank] + local % nx[rank]
        ty = y0[rank] + local // nx[rank]
        tile = ty * tiles_x + tx
        key = tile * max(1, len(order)) + rank  # tile-major, depth rank within the tile
        key, perm = torch.sort(key)
        ids = order[rank[perm]]
        offsets = torch.zeros(ntiles + 1, dtype=torch.int64, device=dev)
        offsets[1:] = torch.cumsum(torch.bincount(tile, minlength=ntiles), 0)
    return TileLists(tile_size, tiles_x, tiles_y, offsets, ids)
