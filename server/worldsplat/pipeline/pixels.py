"""Pixel-aligned Gaussians of decoded latents: the VAE's decoding of L (colour, depth and dynamic mask at the image
the VAE ran at: the model image, or reconstruct's clip image) up-sampled to the rig's image where smaller and
lifted one opaque Gaussian per pixel by the oracle's lifting (`gaussians.lift`, the sky on its far shell, colours
fitted to the decoded image, the near side of depth edges narrowed), so a learned scene holds as many Gaussians per
served pixel as the oracle's and its footprints tile the surface at any display size (the latent decoder's
2x2-model-pixel grid of translucent Gaussians shows as a cell grid; web/docs/models.md, "Served Gaussians per
mode"). `lift_observed` is the oracle's own lifting of an observed view, the same steps on exact colour and depth.

    rgb, depth, dynamic = served_maps(guide, (H, W), near, far)   # guide: inference.pixel_guide, (N, 5, h, w)
    depth = snap_to_ground(depth, dynamic, cameras)               # the road where the frames' decodings agree
    views = lift_views(rgb, depth, dynamic, cameras)              # one Gaussians per map, H * W each
    control = upsample_layout(control, (H, W))                    # the layout maps at the same grid, for the snaps

Depth is up-sampled edge-aware (`upsample_depth`): inverse depth bilinearly (exact on a plane) where the four
model pixels around a served pixel agree, the nearest of them across a depth edge, so no served pixel is lifted
between a facade and the sky behind it.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.core.camera import Camera
from worldsplat.gaussians.lift import EDGE_FOOTPRINT, FIT_ITERS, MAX_DEPTH, SKY_CHANNEL, lift
from worldsplat.gaussians.types import Gaussians
from worldsplat.world.classes import AGENT_CLASSES
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, LAYOUT_FAR, LAYOUT_NEAR, layout_depth_m

# A decoded depth at or beyond this many metres is sky (lifted onto the sky shell). The VAE decodes the sky, whose
# normalised depth is +1 (80 m), a little nearer: on the default and highway presets 96-98 % of its pixels decode
# beyond 62 m, while 2-3 % of the other pixels do (mostly surfaces beyond 60 m, which the shell barely moves).
SKY_DEPTH_M = 62.0
# Four model pixels around a served pixel whose depths differ by more than this ratio straddle a depth edge: the
# served pixel takes the nearest one's depth instead of their blend (a blend is a point in mid-air).
EDGE_DEPTH_RATIO = 1.25


def _taps(x: torch.Tensor, size: tuple[int, int], reduce) -> torch.Tensor:
    """(N,C,h,w) -> (N,C,H,W): `reduce` (torch.amax / amin) over the 2x2 model pixels a bilinear up-sampling to
    `size` reads at each output pixel (align_corners=False; the border replicated)."""
    h, w = x.shape[-2:]
    H, W = size
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    win = reduce(torch.stack([p[..., :-1, :-1], p[..., :-1, 1:], p[..., 1:, :-1], p[..., 1:, 1:]]), 0)
    iy = (torch.floor((torch.arange(H, dtype=torch.float64) + 0.5) * h / H - 0.5).long() + 1).clamp(0, h)
    ix = (torch.floor((torch.arange(W, dtype=torch.float64) + 0.5) * w / W - 0.5).long() + 1).clamp(0, w)
    return win[..., iy[:, None], ix[None, :]]


# A model pixel on a depth edge that the VAE decodes as a blend of the two sides (a point in mid-air between a tree
# crown and the facade behind it) takes the nearer side's or the farther side's depth, whichever it is closer to (in
# log depth). Edge pixels: where inverse depth bends by more than EDGE_BEND of itself within a 3x3 neighbourhood (a
# plane seen by a camera is linear in inverse depth, so ground and facades stay as decoded) and the neighbourhood's
# depths span more than EDGE_DEPTH_RATIO.
EDGE_BEND = 0.15


def sharpen_depth_edges(depth: torch.Tensor, bend: float | None = None) -> torch.Tensor:
    """Depth (N,1,h,w) in metres -> the same with each edge pixel's depth moved to the nearer or the farther end of
    its 5x5 neighbourhood (see EDGE_BEND), so lifting puts no point between two surfaces."""
    bend = EDGE_BEND if bend is None else bend
    q = 1.0 / depth
    p = F.pad(q, (1, 1, 1, 1), mode="replicate")
    d2x = (p[..., 1:-1, :-2] + p[..., 1:-1, 2:] - 2 * q).abs()
    d2y = (p[..., :-2, 1:-1] + p[..., 2:, 1:-1] - 2 * q).abs()
    zone = F.max_pool2d(torch.maximum(d2x, d2y) / q, 3, stride=1, padding=1) > bend
    # the sides' depths from a 5x5 neighbourhood: a blend two model pixels wide sees both sides, not its partner
    lo = -F.max_pool2d(-F.pad(depth, (2, 2, 2, 2), mode="replicate"), 5, stride=1)
    hi = F.max_pool2d(F.pad(depth, (2, 2, 2, 2), mode="replicate"), 5, stride=1)
    edge = zone & (hi > EDGE_DEPTH_RATIO * lo)
    nearer = torch.log(depth / lo) < torch.log(hi / depth)
    return torch.where(edge, torch.where(nearer, lo, hi), depth)


def upsample_depth(depth: torch.Tensor, size: tuple[int, int], edge_ratio: float | None = None) -> torch.Tensor:
    """Depth (N,1,h,w) in metres (> 0, finite) -> (N,1,H,W): inverse depth bilinear where the four model pixels
    around a served pixel agree within `edge_ratio` (None: EDGE_DEPTH_RATIO), the nearest model pixel's depth where
    they do not."""
    if tuple(depth.shape[-2:]) == tuple(size):
        return depth
    edge_ratio = EDGE_DEPTH_RATIO if edge_ratio is None else edge_ratio
    inv = 1.0 / depth
    smooth = 1.0 / F.interpolate(inv, size=size, mode="bilinear", align_corners=False)
    nearest = F.interpolate(depth, size=size, mode="nearest-exact")
    edge = _taps(depth, size, torch.amax) > edge_ratio * _taps(depth, size, torch.amin)
    return torch.where(edge, nearest, smooth)


def served_maps(
    guide: torch.Tensor, size: tuple[int, int], near: float, far: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The VAE's decoding (N,5,h,w): rgb in [-1,1], normalised depth, mask probability (`inference.pixel_guide`) ->
    at the served grid `size` (H,W): rgb (N,H,W,3) float32 in [0,1], depth (N,H,W) camera z in metres with the sky
    (beyond SKY_DEPTH_M) +inf, dynamic (N,H,W) bool."""
    guide = torch.nan_to_num(guide.float())
    rgb = F.interpolate(guide[:, :3], size=size, mode="bilinear", align_corners=False)
    rgb = ((rgb + 1.0) * 0.5).clamp(0.0, 1.0)
    n = guide[:, 3:4].clamp(-1.0, 1.0)
    depth = torch.exp(math.log(near) + (n + 1.0) * 0.5 * (math.log(far) - math.log(near)))
    dyn = F.interpolate(guide[:, 4:5], size=size, mode="bilinear", align_corners=False)[:, 0] > 0.5
    return rgb.permute(0, 2, 3, 1).numpy(), depth_map(depth, size), dyn.numpy()


def depth_map(depth: torch.Tensor, size: tuple[int, int]) -> np.ndarray:
    """Decoded depth (N,1,h,w) in metres -> (N,H,W) at the served grid `size`: blended edge pixels sharpened
    (`sharpen_depth_edges`), up-sampled edge-aware (`upsample_depth`), the sky (beyond SKY_DEPTH_M) +inf."""
    depth = upsample_depth(sharpen_depth_edges(depth.float()), size)[:, 0]
    return torch.where(depth >= SKY_DEPTH_M, torch.full_like(depth, math.inf), depth).numpy()


# The worlds' ground (road, markings, kerbs, sidewalks, terrain) is the plane z = 0 of the scene frame. A decoded depth
# within this log ratio of the plane's along its ray is ground and takes the plane's depth: each frame's decoding puts
# the road a few per cent off, differently, and the frames' copies of it then leave seams where they meet (the finest
# rule keeps each where it is finest). A vertical surface's pixels within it are its bottom 0.14 m (camera 1.5 m up).
GROUND_LOG_TOL = 0.1


def ground_depth(camera: Camera) -> np.ndarray:
    """(H, W) camera z at which each pixel's ray meets the plane z = 0 (+inf where it never does)."""
    origin, dirs = camera.pixel_rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        z = -origin[2] / dirs[..., 2]
    return np.where(np.isfinite(z) & (z > 0), z, np.inf)


def snap_to_ground(depth: np.ndarray, dynamic: np.ndarray, cameras: list[Camera], tol: float = GROUND_LOG_TOL):
    """Depth maps (N, H, W) of N views -> the same with each static pixel within exp(+-tol) of the ground plane's
    depth (`ground_depth`) on the plane."""
    out = depth.copy()
    for i, cam in enumerate(cameras):
        g = ground_depth(cam)
        with np.errstate(divide="ignore", invalid="ignore"):
            on = np.isfinite(g) & np.isfinite(depth[i]) & (np.abs(np.log(depth[i] / g)) < tol) & ~dynamic[i]
        out[i] = np.where(on, g, depth[i])
    return out


def lift_views(
    rgb: np.ndarray,
    depth: np.ndarray,
    dynamic: np.ndarray,
    cameras: list[Camera],
    agents: np.ndarray | None = None,
    fit_iters: int | None = None,
) -> list[Gaussians]:
    """`served_maps` of N views and their N world cameras (at the maps' size) -> one Gaussians per view, one per
    pixel in row-major order (the oracle's lifting: extras[:, 0] dynamic, extras[:, 1] sky; its colours fitted so
    that each view renders its decoded image back, `lift(fit_iters=)`, FIT_ITERS steps unless `fit_iters` says; the near side of depth edges
    EDGE_FOOTPRINT wide except on `agents`, (N, H, W) bool: the observed agents' pixels, or None)."""
    return [
        lift(
            rgb[i],
            depth[i],
            dynamic[i],
            cam,
            fit_iters=FIT_ITERS if fit_iters is None else fit_iters,
            edge_footprint=EDGE_FOOTPRINT,
            agents=None if agents is None else agents[i],
        )
        for i, cam in enumerate(cameras)
    ]


def observed_agents(clip) -> np.ndarray | None:
    """(T, V, H, W) bool: the pixels a clip's segmentation (`semantic`; the paper's SegFormer) calls an agent; None
    for a clip without one."""
    semantic = getattr(clip, "semantic", None)
    return None if semantic is None else np.isin(np.asarray(semantic), AGENT_CLASSES)


def lift_observed(clip, t: int, v: int) -> Gaussians:
    """The oracle's lifting of an observed view (`world.simulate.Clip`, frame t, view v: exact colour and depth):
    `lift_views` of it, the agents' pixels from its segmentation."""
    agents = observed_agents(clip)
    one = None if agents is None else agents[t, v][None]
    (g,) = lift_views(clip.rgb[t, v][None], clip.depth[t, v][None], clip.dynamic[t, v][None], [clip.camera(t, v)], one)
    return g


def settle_sky(g: Gaussians, camera: Camera) -> Gaussians:
    """Clear the sky flag of lifted Gaussians a snap moved off the sky shell (nearer than MAX_DEPTH to the camera:
    a box or facade the layout states where the decoding saw sky), so the economy merges them as surfaces."""
    if g.extras is None or g.extras.shape[1] <= SKY_CHANNEL:
        return g
    origin = torch.as_tensor(np.linalg.inv(camera.world_to_camera)[:3, 3], dtype=g.means.dtype)
    near = (g.means - origin).norm(dim=-1) < MAX_DEPTH
    extras = g.extras.clone()
    extras[:, SKY_CHANNEL] = torch.where(near, torch.zeros_like(extras[:, SKY_CHANNEL]), extras[:, SKY_CHANNEL])
    return Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors, extras)


_LAYOUT_DEPTHS = tuple(i for i, k in enumerate(LAYOUT_CHANNELS) if k in ("depth", "map_depth"))


def upsample_layout(control: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Layout maps (N,C,h,w) (`world.layout_maps`) -> (N,C,H,W): the masks bilinear (a cover per served pixel, which
    the snaps threshold at 0.5), the depth channels edge-aware (`upsample_depth`, in metres and back)."""
    if tuple(control.shape[-2:]) == tuple(size):
        return control
    c = control.float()
    out = F.interpolate(c, size=size, mode="bilinear", align_corners=False)
    span = math.log(LAYOUT_FAR / LAYOUT_NEAR)
    for i in _LAYOUT_DEPTHS:
        if i < c.shape[1]:
            z = upsample_depth(layout_depth_m(c[:, i : i + 1].clamp(-1.0, 1.0)), size)
            out[:, i : i + 1] = (2.0 * torch.log(z / LAYOUT_NEAR) / span - 1.0).clamp(-1.0, 1.0)
    return out
