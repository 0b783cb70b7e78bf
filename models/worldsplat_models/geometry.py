"""Rotation and ray math, written once: quaternions (w, x, y, z; Hamilton product), rotation matrices, camera rays and
their Plücker coordinates.

Both packages use this module: the networks (the Gaussian decoder's rays and rotations) and the server (the
rasterizer, oracle lifting, 4D aggregation, the .wsplat encoder's canonical rotations, file formats). It lives in
`worldsplat_models` because the networks may import nothing of `worldsplat` (pyproject.toml, import-linter), while
`worldsplat` may import the networks. The quaternion functions take torch tensors or numpy arrays (leading batch
axes, the four components on the last axis) and return the same kind; the ray functions are the network's (torch).
"""

from __future__ import annotations

import numpy as np
import torch

IDENTITY = (1.0, 0.0, 0.0, 0.0)


def _components(q):
    """The four components of (..., 4) quaternions, each (...)."""
    return q.unbind(-1) if isinstance(q, torch.Tensor) else np.moveaxis(q, -1, 0)


def _stack(parts, like):
    return torch.stack(parts, -1) if isinstance(like, torch.Tensor) else np.stack(parts, -1)


def quaternion_multiply(a, b):
    """Hamilton product a * b of (..., 4) quaternions: the rotation b, then a (R(a b) = R(a) R(b))."""
    aw, ax, ay, az = _components(a)
    bw, bx, by, bz = _components(b)
    return _stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        a,
    )


def quaternion_to_matrix(q):
    """Unit quaternions (..., 4) -> rotation matrices (..., 3, 3) (local -> world)."""
    w, x, y, z = _components(q)
    m = _stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        q,
    )
    return m.reshape(tuple(q.shape[:-1]) + (3, 3))


def matrix_to_quaternion(R):
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) with w >= 0. Torch input is computed in float32
    (the decoder network's precision and its ONNX graph's), numpy input in float64.

    Branch-free, so it exports to ONNX: each component's magnitude from the diagonal, its sign relative to the
    largest component from the off-diagonal terms that are largest there (differences against w, sums between x, y,
    z), so rotations by about 180 degrees, where w ~ 0 and the differences are only rounding, keep their axis. A
    component near zero carries about sqrt(eps) (1e-8 in float64, 1e-4 in float32) from its square root."""
    if isinstance(R, torch.Tensor):
        m, sqrt, where = R.float(), torch.sqrt, torch.where
        positive = lambda v: v.clamp_min(0)  # noqa: E731
    else:
        m, sqrt, where = np.asarray(R, dtype=np.float64), np.sqrt, np.where
        positive = lambda v: np.maximum(v, 0)  # noqa: E731
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    w = sqrt(positive(1 + m00 + m11 + m22)) / 2
    x = sqrt(positive(1 + m00 - m11 - m22)) / 2
    y = sqrt(positive(1 - m00 + m11 - m22)) / 2
    z = sqrt(positive(1 - m00 - m11 + m22)) / 2
    # negative (4 w x, 4 w y, 4 w z) and (4 x y, 4 x z, 4 y z): the signs of products of two components
    nwx, nwy, nwz = m[..., 2, 1] - m[..., 1, 2] < 0, m[..., 0, 2] - m[..., 2, 0] < 0, m[..., 1, 0] - m[..., 0, 1] < 0
    nxy, nxz, nyz = m[..., 0, 1] + m[..., 1, 0] < 0, m[..., 0, 2] + m[..., 2, 0] < 0, m[..., 1, 2] + m[..., 2, 1] < 0
    w_big = (w >= x) & (w >= y) & (w >= z)
    x_big = ~w_big & (x >= y) & (x >= z)
    y_big = ~w_big & ~x_big & (y >= z)
    z_big = ~w_big & ~x_big & ~y_big
    # each component negative relative to the largest one (which is taken positive) ...
    flip_w = (x_big & nwx) | (y_big & nwy) | (z_big & nwz)
    flip_x = (w_big & nwx) | (y_big & nxy) | (z_big & nxz)
    flip_y = (w_big & nwy) | (x_big & nxy) | (z_big & nyz)
    flip_z = (w_big & nwz) | (x_big & nxz) | (y_big & nyz)
    # ... then all of them turned so that w >= 0
    x = where(flip_x ^ flip_w, -x, x)
    y = where(flip_y ^ flip_w, -y, y)
    z = where(flip_z ^ flip_w, -z, z)
    q = _stack([w, x, y, z], w)
    if isinstance(q, torch.Tensor):
        return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-8)


def normalize_quaternion(q, eps: float):
    """Quaternions (..., 4) -> unit quaternions; those shorter than `eps` become the identity. The norm is clamped
    before the division, so the gradient stays finite at q = 0."""
    if isinstance(q, torch.Tensor):
        sq = (q * q).sum(-1, keepdim=True)
        ident = torch.tensor(IDENTITY, dtype=q.dtype, device=q.device)
        return torch.where(sq >= eps**2, q / torch.sqrt(sq.clamp_min(eps**2)), ident)
    sq = (q * q).sum(-1, keepdims=True)
    return np.where(sq >= eps**2, q / np.sqrt(np.maximum(sq, eps**2)), IDENTITY)


def pixel_rays(
    intrinsics: torch.Tensor, cam_to_world: torch.Tensor, image_hw: tuple[int, int], grid_hw: tuple[int, int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray origins (..., 3) and directions (..., gh, gw, 3) with unit camera-z component, for the centres of a
    gh x gw grid covering an image of image_hw pixels. intrinsics (..., 4) = fx, fy, cx, cy in image pixels."""
    with torch.autocast(device_type=intrinsics.device.type, enabled=False):  # geometry stays float32
        return _pixel_rays(intrinsics.float(), cam_to_world.float(), image_hw, grid_hw)


def _pixel_rays(intrinsics, cam_to_world, image_hw, grid_hw):
    H, W = image_hw
    gh, gw = grid_hw
    dev = intrinsics.device
    u = (torch.arange(gw, dtype=torch.float32, device=dev) + 0.5) * (W / gw)
    v = (torch.arange(gh, dtype=torch.float32, device=dev) + 0.5) * (H / gh)
    fx, fy, cx, cy = [intrinsics[..., i, None, None].float() for i in range(4)]
    x = (u[None, :] - cx) / fx
    y = (v[:, None] - cy) / fy
    x, y = torch.broadcast_tensors(x, y)
    d_cam = torch.stack([x, y, torch.ones_like(x)], dim=-1)
    R = cam_to_world[..., :3, :3].float()
    dirs = torch.einsum("...ij,...hwj->...hwi", R, d_cam)
    return cam_to_world[..., :3, 3].float(), dirs


def plucker(origins: torch.Tensor, dirs: torch.Tensor, ray_scale: float) -> torch.Tensor:
    """(..., 3), (..., h, w, 3) -> (..., 6, h, w): [o x d, d] with d normalised and o in units of ray_scale."""
    dirs, origins = dirs.float(), origins.float()
    d = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    o = (origins / ray_scale)[..., None, None, :].expand_as(d)
    out = torch.cat([torch.cross(o, d, dim=-1), d], dim=-1)
    n = out.dim()
    return out.permute(*range(n - 3), n - 1, n - 3, n - 2)  # explicit perm (ONNX rejects negative ones)
