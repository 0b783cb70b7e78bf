"""Oracle lifting: pixel-aligned Gaussians from ground-truth RGB + depth + camera (the training-free baseline).

Each pixel becomes one isotropic Gaussian on its ray, coloured by the pixel, with a standard deviation of FOOTPRINT
pixels at its depth (`scale = FOOTPRINT * z / f`), so neighbouring splats overlap into a closed surface:
- a surface pixel (finite depth < `max_depth`) sits at `origin + depth * dir` (dir has unit camera-z component, so
  `depth` is camera z);
- a sky pixel (depth +inf, or beyond `max_depth`) sits where its ray meets the sky shell, a sphere of SKY_DISTANCE
  metres around the point of a SKY_GRID_M grid nearest the camera (`sky_centre`: one centre for every frame, view,
  window and mode on a stretch of track, so their sky lands on one surface and the economy merges it instead of
  layering a shell per camera), and is flagged in extras[:, SKY_CHANNEL]: the sky is a static backdrop rendered
  by the same rasterizer (at 300 m a +-4 m track shift moves it by ~1 % of the focal length in pixels, which is
  what "at infinity" looks like).

With `fit_iters` > 0 the static pixels' colours are fitted at the lifting camera (`fit_colours`, on the render's
weights computed on the lifted view's pixel stencil by `raster.aligned_weights`): each splat
spreads over its neighbours (0.7 px std and the rasterizer's 0.3 px^2 dilation: 0.89 px at its own view) and the
nearer neighbours lie in front of it, so a pixel's own splat carries only about a quarter to a half of its rendered
colour, the rest is its neighbours' (a road pixel: the rows below it). Rendered back with the pixels' own colours
the image is smoothed: thin lane markings and curbs lose half their contrast, and the segmentation judge
(`evaluation.downstream`) reads the oracle scene at 0.67 of the world's own images at the rig. With fitted colours
the render at the lifting camera comes back towards the image, held near the pixels' own colours by FIT_RIDGE (an
exact fit is a deconvolution of the 1x image that rings when drawn larger); the oracle and reconstruct serve it
(`pipeline.scene`, `pipeline.pixels`, FIT_ITERS; `evaluation.oracle_gap` and web/docs/gaussians.md measure it).

`lift_surfels` is the same lifting with each surface splat flattened onto its surface (anisotropic, like a 3DGS
capture's Gaussians): the world scene the .wsplat v2 / SOG size comparison is measured on (`worldsplat.bench.sog`).
"""

from __future__ import annotations

import warnings

import numpy as np
import torch

from worldsplat.core.camera import Camera
from worldsplat.gaussians import constants as C
from worldsplat.gaussians.raster import aligned_weights
from worldsplat.gaussians.types import Gaussians
from worldsplat_models.geometry import matrix_to_quaternion

FOOTPRINT = 0.7  # px: splat std relative to the pixel pitch (tuned on the presets, see gaussians.md)
# A static surface pixel on the near side of a depth edge (a 4-neighbour farther by more than EDGE_DEPTH_RATIO, or
# sky) is lifted EDGE_FOOTPRINT wide where its caller asks (`lift(edge_footprint=)`): a full-width splat there spills
# over what lies behind the edge (a barrier's white top over the car behind it) where the world's image has a hard
# edge. An agent's own outline keeps the full width (narrowed, a small agent's object covered 0.53 of its pixels).
EDGE_DEPTH_RATIO = 1.25
EDGE_FOOTPRINT = 0.35
OPACITY = 0.98
# m: farther pixels join the sky shell. The economy keeps no surface farther than this from the track
# (`Economy.max_range`), so a farther pixel lifted as a surface left a hole in front of the shell (the oracle's
# highway horizon showed the shell's sky colour where the world's far grass is: web/docs/gaussians.md "Sky shell").
MAX_DEPTH = 150.0
SKY_DISTANCE = 300.0  # m: the sky shell's radius around its centre
# The shell's centre is the nearest point of this grid to the camera, a function of the position alone, so every
# caller agrees without being told the track: a camera is at most sqrt(3) * 50 m from it (a sky point at least
# ~213 m away, beyond MAX_DEPTH), and a track within 50 m of a grid point (a scene's first ego pose is its origin)
# has one shell.
SKY_GRID_M = 100.0
DYNAMIC_CHANNEL = 0  # extras[:, 0]: 1.0 for moving-agent pixels
SKY_CHANNEL = 1  # extras[:, 1]: 1.0 for sky-shell pixels (the economy keeps them beyond its range cut)
# lift_surfels (anisotropic lifting, the bench's world PLY): the std across the surface relative to the isotropic
# splat's, and the longest pixel step (in isotropic pixel pitches) a splat is stretched along
SURFEL_THICKNESS = 0.2
SURFEL_MAX_STEP = 8.0
# fit_colours: preconditioned projected-gradient (FISTA) steps of the fit (10: the render at the lifting camera within
# 0.5 dB of 40 steps, closer than 20 steps at the global Lipschitz step), and the weight of the pull towards each
# Gaussian's own pixel colour (a ridge: an exact fit at the lifting camera is a deconvolution of the 1x image whose
# pixel-scale contrast rings when drawn larger or from a neighbouring frame; 0.3 against 0: on frame 0's views of test
# clips 0-2 and urban_straight, the render at the lifting camera 28.8 -> 26.0 dB and at 2x its size 22.6 -> 23.6, the
# plain lifting's 21.9 / 22.6)
FIT_ITERS = 10
FIT_RIDGE = 0.3


def lift(
    rgb: np.ndarray,
    depth: np.ndarray,
    dynamic: np.ndarray | None,
    camera: Camera,
    *,
    footprint: float = FOOTPRINT,
    opacity: float = OPACITY,
    max_depth: float = MAX_DEPTH,
    sky: bool = True,
    sky_distance: float = SKY_DISTANCE,
    thickness: float | None = None,
    fit_iters: int = 0,
    edge_footprint: float | None = None,
    agents: np.ndarray | None = None,
) -> Gaussians:
    """rgb (H,W,3) uint8 or float in [0,1], depth (H,W) camera z (sky = +inf), dynamic (H,W) bool or None.
    Returns Gaussians in world coordinates with extras[:, 0] = dynamic mask, extras[:, 1] = sky flag.
    `sky=False` drops sky pixels instead of lifting them onto the shell. `thickness`: flatten each surface splat
    onto its surface, this thin across it (`_flatten`); None keeps every splat isotropic. `fit_iters` > 0: the
    colours fitted so that the render at `camera` reproduces `rgb` (`fit_colours`, that many steps).
    `edge_footprint`: the std (px) of surface pixels on the near side of a depth edge (`near_edge`), except the
    `dynamic` and `agents` (H,W bool: an agent's pixels) ones; None: every pixel `footprint` wide."""
    H, W = camera.height, camera.width
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != (H, W) or np.asarray(rgb).shape[:2] != (H, W):
        raise ValueError(f"lift: rgb {np.asarray(rgb).shape} / depth {depth.shape} do not match camera {W}x{H}")
    if not (np.isfinite(sky_distance) and sky_distance > 0):
        raise ValueError(f"lift: sky_distance must be a finite number > 0, got {sky_distance}")
    col = np.asarray(rgb)
    col = col.astype(np.float64) / 255.0 if col.dtype == np.uint8 else col.astype(np.float64)
    surface = np.isfinite(depth) & (depth > 0) & (depth < max_depth)
    # +inf or beyond max_depth is sky; NaN, zero and negative depths are invalid and dropped.
    is_sky = (np.isposinf(depth) | (np.isfinite(depth) & (depth >= max_depth))) if sky else np.zeros_like(surface)
    keep = surface | is_sky
    origin, dirs = camera.pixel_rays()
    d = np.where(surface, depth, _shell_depth(origin, dirs, sky_distance))[keep]
    means = origin + d[:, None] * dirs[keep]
    f = np.sqrt(camera.fx * camera.fy)
    width = np.full((H, W), footprint)
    if edge_footprint is not None:
        narrow = near_edge(np.where(surface, depth, np.inf))
        for own in (dynamic, agents):
            if own is not None:
                narrow &= ~np.asarray(own, dtype=bool)
        width[narrow] = edge_footprint
    scale = width[keep] * d / f
    n = len(d)
    dyn = np.zeros(n) if dynamic is None else np.asarray(dynamic, dtype=bool)[keep].astype(np.float64)
    dyn = np.where(is_sky[keep], 0.0, dyn)  # the sky never moves
    extras = np.stack([dyn, is_sky[keep].astype(np.float64)], 1)
    g = Gaussians.from_numpy(
        means,
        np.tile([1.0, 0, 0, 0], (n, 1)),
        np.repeat(scale[:, None], 3, 1),
        np.full(n, opacity),
        col[keep],
        extras=extras,
    )
    if thickness is not None:
        g = _flatten(g, depth, surface, keep, origin, dirs, depth / f, thickness)
    if fit_iters <= 0:
        return g
    # fitted: pairs (pixel, Gaussian) where both the Gaussian and the pixel's own Gaussian are static (not
    # dynamic). A moving agent's pixels keep their colours and their bleed over the static pixels is left as it
    # renders: its Gaussians become an object posed per frame, so compensating it (static pixels brightened around a
    # dark pedestrian) showed as a halo through the agent (a pedestrian's contrast 0.17 -> 0.04 on test:1).
    own = np.full(H * W, -1, np.int64)
    own[np.flatnonzero(keep.ravel())] = np.arange(n)
    static = np.append(dyn == 0, False)  # index -1 (a pixel without a Gaussian): never fitted

    def fitted(pix: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return static[rows] & static[own[pix]]

    return fit_colours(g, camera, col, fit_iters, fitted, ridge=FIT_RIDGE)


def sky_centre(position: np.ndarray) -> np.ndarray:
    """The sky shell's centre (3,) for a camera at `position` (3,) world: the nearest point of the SKY_GRID_M grid."""
    return np.round(np.asarray(position, dtype=np.float64).reshape(3) / SKY_GRID_M) * SKY_GRID_M


def _shell_depth(origin: np.ndarray, dirs: np.ndarray, radius: float) -> np.ndarray:
    """Camera z (H,W) where each pixel's ray (`dirs`, unit camera-z) from `origin` meets the sky shell: the sphere
    of `radius` around `sky_centre(origin)`."""
    o = np.asarray(origin, dtype=np.float64) - sky_centre(origin)
    if not np.linalg.norm(o) < radius:
        raise ValueError(
            f"lift: sky_distance {radius} m does not enclose the camera ({np.linalg.norm(o):.1f} m from its centre)"
        )
    norm = np.linalg.norm(dirs, axis=-1)
    u = dirs / norm[..., None]
    ou = u @ o
    return (-ou + np.sqrt(ou * ou - o @ o + radius * radius)) / norm


def near_edge(depth: np.ndarray, ratio: float = EDGE_DEPTH_RATIO) -> np.ndarray:
    """(H, W) camera z (+inf: sky or nothing) -> (H, W) bool: finite pixels with a 4-neighbour more than `ratio`
    times farther (the image border counts as no neighbour)."""
    p = np.pad(depth, 1, mode="edge")
    farthest = np.maximum.reduce([p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]])
    return np.isfinite(depth) & (farthest > ratio * depth)


def fit_colours(
    g: Gaussians,
    camera: Camera,
    target: np.ndarray,
    iters: int = FIT_ITERS,
    fitted=None,
    weights=aligned_weights,
    ridge: float = FIT_RIDGE,
) -> Gaussians:
    """`g` with colours in [0, 1] whose render at `camera` (`raster.render_view`, linear in the colours with the
    weights `raster.pair_weights`, here `weights(g, camera)`: `raster.aligned_weights`, the same weights on a stencil
    for a lifted view at its own camera) is nearest `target` (H, W, 3 in [0, 1]) in squared error plus `ridge` x the
    squared distance to g's own colours: `iters` projected gradient steps (FISTA, per-Gaussian step
    1 / ((W^T W 1)_i + ridge), a diagonal majorizer of the objective's curvature) from g's own colours.
    Gaussians that reach no pixel keep their colour. `fitted(pixels, rows)` -> bool per weight: with it only those
    weights are fitted, each pixel's share of them to its colour (sum of fitted w c = target x sum of fitted w); the other
    weights' colour (another surface's bleed) is left as it renders."""
    pix, rows, w = (t.cpu().numpy() for t in weights(g, camera))
    n, P = len(g), camera.width * camera.height
    if fitted is not None:
        keep = fitted(pix, rows)
        pix, rows, w = pix[keep], rows[keep], w[keep]
    if iters <= 0 or len(w) == 0:
        return g
    W = weights_matrix(pix, rows, w, P, n)
    target = np.asarray(target, np.float64).reshape(-1, 3)
    if fitted is not None:
        target = target * np.bincount(pix, w, minlength=len(target))[:, None]
    c0 = g.colors.detach().cpu().numpy().astype(np.float64)
    x, _ = solve_colours(W, target, c0, iters, ridge)
    colours = torch.as_tensor(x, dtype=g.colors.dtype, device=g.colors.device)
    return Gaussians(g.means, g.quats, g.scales, g.opacities, colours, g.extras)


def weights_matrix(pix: np.ndarray, rows: np.ndarray, w: np.ndarray, P: int, n: int):
    """The (P pixels x n Gaussians) scipy CSR matrix of the render's weight triples (each (pixel, row) once, as
    `raster.pair_weights` gives them); triples already in pixel order (one batch of pairs, `aligned_weights`) are
    its CSR arrays as they are, without the sort."""
    from scipy.sparse import csr_matrix  # noqa: PLC0415 - heavy, needed by the fits only

    if np.all(pix[1:] >= pix[:-1]):
        indptr = np.zeros(P + 1, np.int64)
        np.cumsum(np.bincount(pix, minlength=P), out=indptr[1:])
        return csr_matrix((w, rows, indptr), shape=(P, n))
    return csr_matrix((w, (pix, rows)), shape=(P, n))


def solve_colours(
    W, target: np.ndarray, c0: np.ndarray, iters: int, ridge: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """The colour fit's solver: colours x (n, 3) in [0, 1] minimising |W x - target|^2 + ridge |x - c0|^2 for a
    sparse non-negative W (pixels x Gaussians, the render's weights), `iters` FISTA steps from c0. Returns x and
    `reached` (n,) bool: the Gaussians with a weight (the others keep c0)."""
    # the steps' sparse products on torch's CSR kernels (both cores; scipy's run on one): W and its transpose
    # (scipy's CSC arrays of W are the CSR arrays of W^T)
    W = W.tocsr()
    Wc = W.tocsc()
    Wt = _torch_csr(W.indptr, W.indices, W.data, W.shape)
    WTt = _torch_csr(Wc.indptr, Wc.indices, Wc.data, W.shape[::-1])
    # per-Gaussian step 1 / (D_i + ridge), D = W^T W 1: with W >= 0, diag(D) - W^T W is diagonally dominant, so D
    # majorizes the fit's curvature (a Gaussian that reaches few pixels takes long steps)
    D = (WTt @ (Wt @ torch.ones(W.shape[1], 1, dtype=torch.float64)))[:, 0]
    reached = D > 0
    step = torch.where(reached, 1.0 / (torch.where(reached, D, 1.0) + ridge), 0.0)[:, None]
    c = torch.as_tensor(np.asarray(c0, np.float64))
    b = torch.as_tensor(np.asarray(target, np.float64))
    x, y, tk = c, c, 1.0
    for _ in range(iters):
        xn = torch.clamp(y - step * (WTt @ (Wt @ y - b) + ridge * (y - c)), 0.0, 1.0)
        tn = (1 + (1 + 4 * tk * tk) ** 0.5) / 2
        y = xn + ((tk - 1) / tn) * (xn - x)
        x, tk = xn, tn
    reached = reached.numpy()
    return np.where(reached[:, None], x.numpy(), c0), reached


def _torch_csr(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, shape) -> torch.Tensor:
    """A float64 torch CSR matrix on scipy's CSR arrays (its sparse x dense product is threaded; with int32 indices,
    where they fit, about twice as fast as with int64)."""
    it = np.int32 if max(len(data), *shape) < 2**31 else np.int64
    with warnings.catch_warnings():  # "sparse CSR support is in beta": the product used here is stable
        warnings.simplefilter("ignore", UserWarning)
        return torch.sparse_csr_tensor(torch.as_tensor(indptr.astype(it)), torch.as_tensor(indices.astype(it)),
                                       torch.as_tensor(np.asarray(data, np.float64)), size=tuple(shape),
                                       check_invariants=False)  # fmt: skip


def lift_surfels(rgb: np.ndarray, depth: np.ndarray, dynamic: np.ndarray | None, camera: Camera) -> Gaussians:
    """`lift` with surface splats SURFEL_THICKNESS thin across their surface (the bench's world PLY)."""
    return lift(rgb, depth, dynamic, camera, thickness=SURFEL_THICKNESS)


def _flatten(
    g: Gaussians,
    depth: np.ndarray,
    surface: np.ndarray,
    keep: np.ndarray,
    origin: np.ndarray,
    dirs: np.ndarray,
    pitch: np.ndarray,
    thickness: float,
) -> Gaussians:
    """`lift`'s Gaussians `g` with each surface pixel's flattened onto the surface it lies on (anisotropic, as a
    3DGS capture's are): covariance `FOOTPRINT^2 (du du^T + dv dv^T) + (thickness * iso)^2 n n^T`, where du / dv are
    the world steps to the next pixel along the row / column (the one-sided difference of the smaller step, so a
    depth edge does not stretch a splat across it) and n their normal; seen from its own camera it covers the same
    pixels as the isotropic splat. Pixels whose steps exceed SURFEL_MAX_STEP x the isotropic pitch (`pitch`: the
    pixel pitch at the pixel's depth; grazing surfaces, silhouettes) and the sky keep the isotropic Gaussian. Same
    Gaussians, order and extras as `g`; `surface`, `keep`, `origin`, `dirs` are `lift`'s (H, W) masks and rays."""
    p = origin + np.where(surface, depth, np.nan)[..., None] * dirs

    def step(axis: int) -> tuple[np.ndarray, np.ndarray]:
        d = np.diff(p, axis=axis)
        pad = [(0, 0)] * 3
        pad[axis] = (1, 0)
        back = np.pad(d, pad, constant_values=np.nan)
        pad[axis] = (0, 1)
        fwd = np.pad(d, pad, constant_values=np.nan)
        nb, nf = (np.nan_to_num(np.linalg.norm(x, axis=-1), nan=np.inf) for x in (back, fwd))
        return np.where((nb <= nf)[..., None], back, fwd), np.minimum(nb, nf)

    du, lu = step(1)
    dv, lv = step(0)
    with np.errstate(invalid="ignore"):
        normal = np.cross(du, dv)
        nn = np.linalg.norm(normal, axis=-1)
        ok = surface & (lu < SURFEL_MAX_STEP * pitch) & (lv < SURFEL_MAX_STEP * pitch) & (nn > 0)
    ok_k = ok[keep]
    if not ok_k.any():
        return g
    du, dv, n = du[ok], dv[ok], normal[ok] / nn[ok][:, None]
    t = thickness * FOOTPRINT * pitch[ok]
    cov = FOOTPRINT**2 * (du[:, :, None] * du[:, None, :] + dv[:, :, None] * dv[:, None, :])
    cov += (t * t)[:, None, None] * n[:, :, None] * n[:, None, :]
    ev, vec = np.linalg.eigh(cov)
    vec = vec * np.where(np.linalg.det(vec) < 0, -1.0, 1.0)[:, None, None]  # a rotation (det +1)
    quats, scales = g.quats.clone(), g.scales.clone()
    quats[torch.as_tensor(ok_k)] = matrix_to_quaternion(torch.as_tensor(vec)).to(quats.dtype)
    scales[torch.as_tensor(ok_k)] = torch.as_tensor(np.sqrt(np.maximum(ev, 0.0)), dtype=scales.dtype)
    return Gaussians(g.means, quats, scales.clamp_min(C.SCALE_MIN), g.opacities, g.colors, g.extras)
