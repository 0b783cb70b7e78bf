"""Generated Gaussians onto the layout the scenario states (generate mode, `inference.decode_generated`): the road onto
its plane (`snap_to_layout`), facades, trees and poles onto the map layer (`snap_to_map`), agents onto their boxes and
moving with them (`snap_agents_to_layout`). Each works on a DecodedFrames whose views are grids on the layout maps'
pixels: the latent decoder's (one Gaussian per 1 or 2x2 model pixels, against the maps at the model image) or the
lifted pixels' (one per pixel, against the maps up-sampled to the rig's image, `pipeline.pixels.upsample_layout`).
Measured in web/docs/models.md ("What the pipeline does after decoding").
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.world.layout_maps import LAYOUT_CHANNELS, layout_depth_m

if TYPE_CHECKING:
    from worldsplat.pipeline.inference import DecodedFrames


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
    out = torch.zeros(points.shape[0], dtype=torch.bool)
    if corners.shape[0] == 0:
        return out
    o = corners[:, 0]  # (K,3) rear-right bottom
    axes = torch.stack([corners[:, 1] - o, corners[:, 3] - o, corners[:, 4] - o], 1)  # (K,3,3) length, width, height
    size = axes.norm(dim=-1).clamp_min(1e-6)  # (K,3)
    points = points.to(corners.dtype)
    # only the points within a box's axis-aligned bounds (grown by the margin) are tested against it exactly
    lo, hi = corners.amin(1) - margin, corners.amax(1) + margin
    for k in range(corners.shape[0]):
        near = torch.nonzero(((points >= lo[k]) & (points <= hi[k])).all(-1)).reshape(-1)
        if len(near):
            local = (points[near] - o[k]) @ (axes[k] / size[k][:, None]).T  # (n,3) metres along the box's axes
            out[near] |= ((local > -margin) & (local < size[k] + margin)).all(-1)
    return out


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


# The decoder's grid refined (`inference.DECODER_REFINE`) widens every Gaussian to a scale floor of most of its
# cell (`inference.REFINED_SCALE_FLOOR_MODEL_PX`) at the same opacity, four per coarse cell: where a surface stands
# before an agent, their tails stack into a haze over the agent's pixels beside the edge (test:2's van behind a wall:
# covered 0.64, the coarse grid 0.92; its Gaussians there 5-9 m before the van, 0.2-0.8 m up, std 0.1-0.2 m, opacity
# ~0.5, five times the coarse grid's count). A static Gaussian within AGENT_EDGE_REACH grid cells of a cell the layout
# calls agent, nearer than that box's depth by more than AGENT_EDGE_RATIO, keeps only AGENT_EDGE_FLOOR_MODEL_PX of
# floor. Generate, decoder2x, test:0-2 + the default preset: the van seen (agents 35 -> 36 of 38), static PSNR and
# SSIM unchanged to 0.005 dB (the layout's ground excluded, the van stayed covered 0.80: the wall stands on it).
AGENT_EDGE_REACH = 2
AGENT_EDGE_RATIO = 1.25
AGENT_EDGE_FLOOR_MODEL_PX = 0.3


@torch.no_grad()
def narrow_before_agent_edges(
    dec: DecodedFrames,
    control: torch.Tensor,
    floor_px: float,
    model_hw: tuple[int, int],
    edge_floor_px: float = AGENT_EDGE_FLOOR_MODEL_PX,
    reach: int = AGENT_EDGE_REACH,
    ratio: float = AGENT_EDGE_RATIO,
) -> float:
    """Gaussians of a grid of one per layout pixel (f = 1) whose scales carry a floor of `floor_px` model pixels
    (`inference.scale_floor`, model image `model_hw`), beside an agent's cells (`_agent_cells`'s rule: box cover
    > 0.5) and nearer than the box's layout depth by more than `ratio`, re-floored at `edge_floor_px` (their own
    scale kept: s' = sqrt(s^2 - floor^2 + edge_floor^2)). In place; returns the fraction changed."""
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}
    changed = total = 0
    k = 2 * reach + 1
    for t, v, g, f, c in _views(dec, control, "narrow_before_agent_edges"):
        total += len(g)
        if f != 1:
            continue
        box = (c[ch["vehicle"]] + c[ch["vulnerable"]]).clamp(0, 1) > 0.5
        if not bool(box.any()):
            continue
        z_box = torch.where(box, layout_depth_m(c[ch["depth"]]), torch.zeros_like(box, dtype=torch.float32))
        far = F.max_pool2d(z_box[None, None], k, stride=1, padding=reach)[0, 0].reshape(-1)
        _, z = _camera_ray_depth(dec, t, v, g.means)
        ok = ~box.reshape(-1) & (far > ratio * z) & (z > 1e-3)
        if g.extras is not None:
            ok &= g.extras[:, 0] <= 0.5
        if not bool(ok.any()):
            continue
        cam = dec.rig[v]
        fx_model = cam.fx * model_hw[1] / cam.width
        big, small = (floor_px * z / fx_model) ** 2, (edge_floor_px * z / fx_model) ** 2
        s2 = (g.scales**2 - big[:, None]).clamp_min(0) + small[:, None]
        g.scales = torch.where(ok[:, None], s2.sqrt().to(g.scales.dtype), g.scales)
        changed += int(ok.sum())
    return changed / max(total, 1)
