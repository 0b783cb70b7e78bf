"""Pixel-aligned Gaussians flattened onto the surface they sample: the covariance of a pixel's footprint on the
surface (its neighbours' 3D offsets), so that copies of one surface seen from several frames lie in one plane and
project foreshortened, as 2DGS-style surfels do."""

import numpy as np
import torch

from worldsplat.gaussians import Gaussians
from worldsplat_models.gs_decoder import matrix_to_quaternion


def _short_diff(P, axis):
    f = np.diff(P, axis=axis)
    pad = [(0, 0)] * 3
    pad[axis] = (0, 1)
    fwd = np.pad(f, pad, mode="edge")
    pad[axis] = (1, 0)
    bwd = np.pad(f, pad, mode="edge")
    return np.where(
        np.linalg.norm(fwd, axis=-1, keepdims=True) <= np.linalg.norm(bwd, axis=-1, keepdims=True), fwd, bwd
    )


def surfel_gaussians(P, fp, col, dyn, k=0.3, thin=0.02, stretch=4.0):
    """P (H,W,3) world points, fp (H,W) footprint (m per px at the depth), col (H,W,3), dyn (H,W)."""
    a = _short_diff(P, 1)
    b = _short_diff(P, 0)
    # cap each tangent at `stretch` footprints (grazing angles, depth edges)
    for t in (a, b):
        n = np.linalg.norm(t, axis=-1, keepdims=True)
        cap = stretch * fp[..., None]
        t *= np.minimum(1.0, cap / np.maximum(n, 1e-9))
    nrm = np.cross(a, b)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-9)
    S = k * k * (a[..., :, None] * a[..., None, :] + b[..., :, None] * b[..., None, :])
    S += ((thin * fp) ** 2)[..., None, None] * nrm[..., :, None] * nrm[..., None, :]
    S += ((1e-3 * fp) ** 2)[..., None, None] * np.eye(3)
    w, R = np.linalg.eigh(S.reshape(-1, 3, 3))
    R[np.linalg.det(R) < 0, :, 0] *= -1
    q = matrix_to_quaternion(torch.as_tensor(R, dtype=torch.float32))
    sc = torch.as_tensor(np.sqrt(np.maximum(w, 1e-12)), dtype=torch.float32)
    n = len(sc)
    return Gaussians(
        torch.as_tensor(P.reshape(-1, 3), dtype=torch.float32),
        q,
        sc,
        torch.ones(n),
        torch.as_tensor(col.reshape(-1, 3), dtype=torch.float32),
        torch.as_tensor(dyn.reshape(-1, 1), dtype=torch.float32),
    )
