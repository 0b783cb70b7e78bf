"""Conditions the models consume (paper §3.2, MagicDrive-style), computed from the layout, for any shifted track:

- `bev` (T,C,Hb,Wb) float32: ego-centric raster, 0.5 m/px, 200x200 (100 m square, ego in the centre, ego +x up,
  ego +y left); channels `BEV_CHANNELS`.
- `sketch` (T,V,H,W,3) float32 in {0,1}: lane lines and road edges (ch 0), vehicle box edges (ch 1), pedestrian and
  cyclist box edges (ch 2), projected into each (shifted) camera: the paper's reprojected S' and B'.
- `boxes`: per frame a list of {corners (8,3) world metres, cls, cls_name, track_id, moving, and for an explicit
  scenario agent its `agent_id`}.
- `ego_traj` (T,4,4): poses of the (shifted) ego relative to its first frame.
- `caption`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from worldsplat.core.camera import Camera, rigid_inverse, shifted_ego
from worldsplat.world.agents import ego_travel
from worldsplat.world.classes import CLASS_NAMES, CYCLIST, PEDESTRIAN, VEHICLE_CLASSES
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, layout_maps
from worldsplat.world.render import single_threaded_blas
from worldsplat.world.road import bev_layers

if TYPE_CHECKING:  # the World's own `conditions()` calls world_conditions; only the annotations name it
    from worldsplat.world.layout import World

BEV_CHANNELS = ("drivable", "lane_divider", "crosswalk", "sidewalk", "vehicle", "vulnerable")
SKETCH_CHANNELS = ("lane_lines", "vehicle_boxes", "vulnerable_boxes")
BEV_SIZE, BEV_RES = 200, 0.5
BOX_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]])
SKETCH_RANGE = 90.0  # metres: farther lines are not drawn


def bev_grid(size: int = BEV_SIZE, res: float = BEV_RES) -> tuple[np.ndarray, np.ndarray]:
    """Ego-frame x (forward, up the image) and y (left, left in the image) of BEV pixel centres, (size,size)."""
    c = (np.arange(size) + 0.5 - size / 2) * res
    xe = -c[:, None] + 0 * c[None, :]
    ye = -c[None, :] + 0 * c[:, None]
    return xe, ye


def draw_segments(img: np.ndarray, cam: Camera, a: np.ndarray, b: np.ndarray, near: float = 0.1) -> None:
    """Draw 3D segments a->b (N,3 world) into `img` (H,W) float32 as 1-pixel lines (near-plane clipped)."""
    if len(a) == 0:
        return
    m = cam.world_to_camera
    pa = a @ m[:3, :3].T + m[:3, 3]
    pb = b @ m[:3, :3].T + m[:3, 3]
    za, zb = pa[:, 2], pb[:, 2]
    keep = (za > near) | (zb > near)
    pa, pb, za, zb = pa[keep], pb[keep], za[keep], zb[keep]
    # Clip to the near plane (both ends computed from the unclipped segment).
    with np.errstate(divide="ignore", invalid="ignore"):
        fa = np.clip((near - za) / (zb - za), 0, 1)
        fb = np.clip((near - zb) / (za - zb), 0, 1)
    pa, pb = (
        np.where((za < near)[:, None], pa + fa[:, None] * (pb - pa), pa),
        np.where((zb < near)[:, None], pb + fb[:, None] * (pa - pb), pb),
    )
    ua = np.stack([cam.fx * pa[:, 0] / pa[:, 2] + cam.cx, cam.fy * pa[:, 1] / pa[:, 2] + cam.cy], -1)
    ub = np.stack([cam.fx * pb[:, 0] / pb[:, 2] + cam.cx, cam.fy * pb[:, 1] / pb[:, 2] + cam.cy], -1)
    h, w = img.shape
    # Liang-Barsky clip to the image rectangle.
    t0, t1 = np.zeros(len(ua)), np.ones(len(ua))
    delta = ub - ua
    for p, q in (
        (-delta[:, 0], ua[:, 0]),
        (delta[:, 0], w - ua[:, 0]),
        (-delta[:, 1], ua[:, 1]),
        (delta[:, 1], h - ua[:, 1]),
    ):
        with np.errstate(divide="ignore", invalid="ignore"):
            r = q / p
        t0 = np.where(p < 0, np.maximum(t0, r), t0)
        t1 = np.where(p > 0, np.minimum(t1, r), t1)
        bad = (p == 0) & (q < 0)
        t0 = np.where(bad, 2.0, t0)
    ok = t0 <= t1
    ua, ub, t0, t1, delta = ua[ok], ub[ok], t0[ok], t1[ok], delta[ok]
    s = ua + t0[:, None] * delta
    e = ua + t1[:, None] * delta
    n = np.ceil(np.abs(e - s).max(axis=1)).astype(np.int64) + 1
    if len(n) == 0:
        return
    seg = np.repeat(np.arange(len(n)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    frac = k / np.maximum(n[seg] - 1, 1)
    pts = s[seg] + frac[:, None] * (e[seg] - s[seg])
    i = np.clip(np.floor(pts[:, 0]).astype(np.int64), 0, w - 1)
    j = np.clip(np.floor(pts[:, 1]).astype(np.int64), 0, h - 1)
    img[j, i] = 1.0


def lane_segments(world: World) -> tuple[np.ndarray, np.ndarray]:
    """World-space segments (a, b) of every lane line, centre line, edge line and kerb."""
    travel = ego_travel(world.scenario, world.frame_times)
    polys = world.road.line_polylines(-70.0, travel + 110.0, 2.0)
    a = np.concatenate([p[:-1] for p, _ in polys]) if polys else np.zeros((0, 3))
    b = np.concatenate([p[1:] for p, _ in polys]) if polys else np.zeros((0, 3))
    return a, b


def boxes_at(world: World, t: int) -> list[dict]:
    out = []
    for a in world.agents:
        out.append(
            {
                "corners": a.box_corners(t),
                "cls": int(a.cls),
                "cls_name": CLASS_NAMES[a.cls],
                "track_id": int(a.track_id),
                "moving": bool(a.moving),
                **({"agent_id": a.agent_id} if a.agent_id is not None else {}),
            }
        )
    return out


def bev_raster(
    world: World, t: int, ego_pose: np.ndarray, seg: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    xe, ye = bev_grid()
    x = ego_pose[0, 0] * xe + ego_pose[0, 1] * ye + ego_pose[0, 3]
    y = ego_pose[1, 0] * xe + ego_pose[1, 1] * ye + ego_pose[1, 3]
    layers = bev_layers(world.road, x, y)
    out = np.zeros((len(BEV_CHANNELS), BEV_SIZE, BEV_SIZE), np.float32)
    out[0] = layers["drivable"]
    out[2] = layers["crosswalk"]
    out[3] = layers["sidewalk"]
    # Lane lines: the same segments as the sketch, drawn top-down.
    a, b = seg if seg is not None else lane_segments(world)
    inv = rigid_inverse(ego_pose)
    pa, pb = _to_bev_px(inv, a), _to_bev_px(inv, b)
    _draw_2d(out[1], pa, pb)
    for ag in world.agents:
        ch = 4 if ag.cls in VEHICLE_CLASSES else 5
        px, py, yaw = ag.poses[t]
        c, s = np.cos(yaw), np.sin(yaw)
        dx, dy = x - px, y - py
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        inside = (np.abs(lx) <= ag.size[0] / 2 + BEV_RES / 2) & (np.abs(ly) <= ag.size[1] / 2 + BEV_RES / 2)
        out[ch][inside] = 1.0
    return out


def _to_bev_px(inv: np.ndarray, p: np.ndarray) -> np.ndarray:
    pe = p @ inv[:3, :3].T + inv[:3, 3]
    col = BEV_SIZE / 2 - pe[:, 1] / BEV_RES
    row = BEV_SIZE / 2 - pe[:, 0] / BEV_RES
    return np.stack([col, row], -1)


def _draw_2d(img: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    h, w = img.shape
    inside = ((a[:, 0] > -w) & (a[:, 0] < 2 * w) & (a[:, 1] > -h) & (a[:, 1] < 2 * h)) | (
        (b[:, 0] > -w) & (b[:, 0] < 2 * w) & (b[:, 1] > -h) & (b[:, 1] < 2 * h)
    )
    a, b = a[inside], b[inside]
    if len(a) == 0:
        return
    n = np.ceil(np.abs(b - a).max(axis=1)).astype(np.int64) + 1
    seg = np.repeat(np.arange(len(n)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    frac = k / np.maximum(n[seg] - 1, 1)
    pts = a[seg] + frac[:, None] * (b[seg] - a[seg])
    ok = (pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)
    img[pts[ok, 1].astype(np.int64), pts[ok, 0].astype(np.int64)] = 1.0


def sketch(world: World, t: int, cams: list[Camera], seg: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(V,H,W,3) float32 perspective sketch for frame t."""
    a, b = seg
    out = []
    boxes = [(ag, ag.box_corners(t)) for ag in world.agents]
    for cam in cams:
        img = np.zeros((cam.height, cam.width, 3), np.float32)
        pos = cam.position
        near = np.linalg.norm(a[:, :2] - pos[:2], axis=1) < SKETCH_RANGE
        draw_segments(img[..., 0], cam, a[near], b[near])
        for ch, classes in ((1, VEHICLE_CLASSES), (2, (PEDESTRIAN, CYCLIST))):
            cs = [c for ag, c in boxes if ag.cls in classes and np.linalg.norm(c[0, :2] - pos[:2]) < SKETCH_RANGE]
            if cs:
                corners = np.stack(cs)
                draw_segments(
                    img[..., ch],
                    cam,
                    corners[:, BOX_EDGES[:, 0]].reshape(-1, 3),
                    corners[:, BOX_EDGES[:, 1]].reshape(-1, 3),
                )
        out.append(img)
    return np.stack(out)


def world_conditions(
    world: World,
    shift_m: float = 0.0,
    cameras: list[str] | None = None,
    layout_size: tuple[int, int] | None = None,
    frames: list[int] | None = None,
    behind: bool = False,
) -> dict:
    """The models' conditions; with layout_size = (W, H) also the per-camera layout maps at that size
    (`layout`, (T,V,H,W,C), see world.layout_maps), which the DiT reads as its layout control, and with `behind` the
    same maps without the agents' boxes (`layout_behind`: what stands behind them, generate's backdrop). `frames`:
    only these frames (every per-frame entry in their order; `ego_traj` still relative to frame 0), None every
    frame."""
    frames = list(range(world.num_frames)) if frames is None else [int(t) for t in frames]
    with single_threaded_blas():
        out = _world_conditions(world, shift_m, cameras, frames)
        if layout_size is not None:
            out["layout"] = layout_maps(world, shift_m, cameras, size=tuple(layout_size), frames=frames)
            out["layout_channels"] = LAYOUT_CHANNELS
            if behind:
                out["layout_behind"] = layout_maps(
                    world, shift_m, cameras, size=tuple(layout_size), frames=frames, agents=False
                )
        return out


def ego_trajectory(world: World, shift_m: float = 0.0) -> np.ndarray:
    """(T,4,4) each frame's (shifted) ego pose in the first frame's ego frame: the conditions' `ego_traj`."""
    poses = shifted_ego(world.ego_to_world, shift_m)
    inv0 = rigid_inverse(poses[0])
    return np.stack([inv0 @ p for p in poses])


def _world_conditions(world: World, shift_m: float, cameras: list[str] | None, frames: list[int]) -> dict:
    rig = world.rig if cameras is None else [world.rig_camera(n) for n in cameras]
    poses = shifted_ego(world.ego_to_world, shift_m)
    seg = lane_segments(world)
    bev = np.stack([bev_raster(world, t, poses[t], seg) for t in frames])
    sk = np.stack([sketch(world, t, [rc.at(world.ego_to_world[t], shift_m) for rc in rig], seg) for t in frames])
    return {
        "bev": bev,
        "bev_channels": BEV_CHANNELS,
        "bev_resolution_m": BEV_RES,
        "sketch": sk,
        "sketch_channels": SKETCH_CHANNELS,
        "cameras": [c.name for c in rig],
        "boxes": [boxes_at(world, t) for t in frames],
        "ego_traj": ego_trajectory(world, shift_m)[frames],
        "caption": world.caption,
        "shift_m": float(shift_m),
    }
