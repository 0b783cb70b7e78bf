"""Agents as objects: the per-frame dynamic Gaussians that fall in an agent's box become one canonical set in that
box's frame, posed per frame by the agent's track (`types.AgentObject`); the rest stay per-frame dynamics.

The scenario states every agent's box at every frame (`agent_tracks`). `ObjectBuilder.add(frames, dynamic)` takes a
window's per-frame dynamic sets (scene frame, as `aggregate.WindowAggregator` returns them), gives each Gaussian to
the box that contains it (with `AGENT_MARGIN_M`; the nearest box where margins overlap), moves it into that box's
frame and merges an agent's Gaussians of all the window's frames and cameras with the economy's merging
(`aggregate.economize`) in cells of the box frame. Like the static stream, an object grows window by window and is
append-only: a window emits only the cells no earlier window emitted (`aggregate.CellTable`), so what a window hands
over is final and an object's canonical set is the concatenation of its window parts. The cells' size is the pixel
footprint from the camera nearest to the place over the whole clip (`Economy.dynamic_cell_factor` footprints, the
per-frame sets' own): the tracks and the ego are known before any frame is, so every window puts an observation of
the same place in the same cell, and the agent seen from several sides and frames becomes one complete object.

Every agent in the clip is an object, parked and standing ones too: before the aggregation, the Gaussians in a
standing agent's box are made dynamic (`ObjectBuilder.claim`), so its static pixels become its object.
`source` (generate mode): a function (the agent's track, appearance seed) -> Gaussians in the box frame draws an agent's
canonical set instead; its in-box dynamic Gaussians are then absorbed. `add(..., observed=)` (reconstruct mode):
the agents are built from other Gaussians than the frames' (the observed pixels in the boxes, `lift_in_boxes`),
the frames' in-box Gaussians absorbed. `keep_unboxed=False` drops the dynamic Gaussians in no box (a learned mode's
spurious dynamics where the scenario states no agent). Box frame: x forward, y left, z up, metres,
origin at the box centre (the world's footprint centre lifted by half the height)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from worldsplat.core.camera import RigCamera, rigid_inverse
from worldsplat.gaussians.aggregate import (
    DYNAMIC_THRESHOLD,
    WINDOW_FINER,
    AggregateStats,
    CellTable,
    Economy,
    economize,
    sky_rows,
)
from worldsplat.gaussians.lift import lift
from worldsplat.gaussians.types import AgentObject, Gaussians, transform
from worldsplat_models.geometry import quaternion_to_matrix

# Gaussians this far outside a box still belong to it (lifted silhouette pixels, merged means); the agents'
# snapping in generate mode uses the same margin (pipeline.snaps.AGENT_BOX_MARGIN_M).
AGENT_MARGIN_M = 0.3
AGENT_MODES = ("objects", "per_frame")  # an agent as one posed object, or re-drawn per frame (the paper's dynamics)
# An object is drawn at every frame, also where the agent is nearer than when a place of it was seen: a Gaussian
# lifted from far is then a blurred blob over the near agent's silhouette (test:0, a car driving away: frame 0
# contrast 0.66 -> 0.09 of the exact one). So the finest observation of a place wins: a Gaussian is left out where
# at least FINER_COUNT Gaussians FINER_FACTOR or more times finer lie within FINER_REACH of its std.
FINER_FACTOR = math.sqrt(2)
FINER_COUNT = 2
FINER_REACH = 2.0
# A Gaussian on a camera's ray through a box is claimed up to this far behind where the ray leaves it (metres, or
# this share of that depth if more): a decoded depth is blurred over an agent's edge.
CLAIM_RAY_TOL_M = 1.0
CLAIM_RAY_TOL_SHARE = 0.1
OBJECT_CELL_FACTOR = 2.0  # merge cells of an object, in pixel footprints from the nearest camera of the clip
OBJECT_COVER = 0.0  # > 0: a merged Gaussian covers its members' patch (aggregate.merged_variance)
# An object is drawn at every frame, also from nearer than some of its places were seen: a Gaussian lifted from far
# or merged over a cell is wider than the agent's pixels when drawn near and bloats its silhouette. So an object's
# Gaussian is at most this many pixel footprints wide (std) from the camera nearest to it over the clip (the
# lifting's own is FOOTPRINT = 0.7). Oracle test:0-2 (frames 0, 3, 7): agents seen 22/26 -> 25/26, silhouette IoU
# 0.792 -> 0.82; 0.7 leaves holes in a near car (covered 0.99 -> 0.77), 2.0 gains half as much.
OBJECT_SCALE_CAP = 1.0
# A standing agent's pixels are static: Gaussians in its box (grown by CLAIM_MARGIN_M) are claimed for its object
# before the aggregation (`ObjectBuilder.claim`), all but the bottom CLAIM_FLOOR_M of the box, where the road under
# and around it lies. A moving agent's pixels are dynamic already; claiming around it too took the pole or parked
# car it passes into its object (oracle test:1, a pedestrian: silhouette IoU 0.39, its colour the surround's). A
# learned mode whose objects come from elsewhere claims every agent's box with AGENT_MARGIN_M: the model's blurred
# agent, spilling over its box, gives way to the object (dropped) instead of covering its edges.
CLAIM_MARGIN_M = 0.1
CLAIM_FLOOR_M = 0.08
# Observed pixels (`lift_in_boxes`) are an agent's where their depth lies on the ray's way through its box, up to
# this much nearer or farther (metres, or this share of the depth if more); a pixel whose depth is behind the box
# sees past the agent. An observed depth needs little; a decoded one is blurred over an agent's edge (1 m, 10 %).
OBSERVED_DEPTH_TOL_M = 0.1
OBSERVED_DEPTH_TOL_SHARE = 0.0


@dataclass
class AgentTrack:
    """An agent's box over the clip: `poses[t]` box_to_scene (box frame above; the scene's frame, which is the
    world in oracle/reconstruct and the first frame's ego in generate), `present[t]` where it has a pose."""

    agent_id: int  # the world's track id (conditions' boxes: track_id)
    cls: int
    size: np.ndarray  # (3,) length, width, height m
    poses: np.ndarray  # (T,4,4)
    present: np.ndarray  # (T,) bool
    name: str | None = None  # the scenario's agents[i].id for an explicit agent
    colour: np.ndarray | None = None  # (3,) RGB in [0, 1]: the world's body / clothing colour
    standing: bool = False  # a parked or standing agent (its pixels are static)


# (the agent's track: class, size, colour, poses; its appearance seed) -> its canonical Gaussians in the box frame
ObjectSource = Callable[[AgentTrack, int], Gaussians]


def box_to_world(x: float, y: float, yaw: float, height: float) -> np.ndarray:
    """The 4x4 box_to_world of a footprint centre (x, y) on the ground (z = 0) turned by yaw."""
    m = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = [x, y, height / 2]
    return m


def agent_tracks(world, ego_to_scene: np.ndarray, moving_only: bool = False) -> list[AgentTrack]:
    """The world's agents present in the clip as tracks in the scene's frame: box_to_scene[t] = ego_to_scene[t] @
    world_to_ego[t] @ box_to_world[t]. Parked and standing agents too (as static scenery they were blurred by the
    learned modes); `moving_only`: the moving agents alone (the ones whose pixels are dynamic)."""
    ego_to_scene = np.asarray(ego_to_scene, np.float64)
    scene_from_world = np.stack([e @ rigid_inverse(w) for e, w in zip(ego_to_scene, world.ego_to_world, strict=True)])
    out = []
    for a in world.agents:
        if moving_only and not a.moving:
            continue
        p = np.asarray(a.poses, np.float64)
        present = np.isfinite(p).all(1)
        if not present.any():
            continue
        poses = np.stack(
            [scene_from_world[t] @ box_to_world(*p[t], a.size[2]) if present[t] else np.eye(4) for t in range(len(p))]
        )
        out.append(AgentTrack(int(a.track_id), int(a.cls), np.asarray(a.size, np.float64), poses, present,
                              a.agent_id, np.asarray(a.color, np.float64), not a.moving))  # fmt: skip
    return out


def assign_to_boxes(means: np.ndarray, tracks: list[AgentTrack], t: int, margin: float = AGENT_MARGIN_M) -> np.ndarray:
    """Per point (scene frame, frame t): the index in `tracks` of the box that contains it (within `margin`), or -1.
    Where margins overlap, the box the point is deepest in (smallest box-relative distance) wins."""
    best = np.full(len(means), -1, np.int64)
    score = np.full(len(means), np.inf)
    for i, tr in enumerate(tracks):
        if not tr.present[t] or not len(means):
            continue
        inv = rigid_inverse(tr.poses[t])
        local = means @ inv[:3, :3].T + inv[:3, 3]
        half = tr.size / 2
        inside = (np.abs(local) <= half + margin).all(1)
        rel = (np.abs(local) / np.maximum(half, 1e-3)).max(1)
        take = inside & (rel < score)
        best[take], score[take] = i, rel[take]
    return best


def _box_local(means: np.ndarray, tr: AgentTrack, t: int) -> np.ndarray:
    inv = rigid_inverse(tr.poses[t])
    return means @ inv[:3, :3].T + inv[:3, 3]


def claim_in_boxes(
    g: Gaussians, tracks: list[AgentTrack], t: int, margin: float = CLAIM_MARGIN_M, floor: float = CLAIM_FLOOR_M
) -> Gaussians:
    """Frame t's Gaussians (scene frame, extras[:, 0] the dynamic probability) with those inside an agent's box
    (grown by `margin`, all but its bottom `floor`: the road) made dynamic, so the aggregation hands them to the
    objects."""
    if not len(g) or not tracks:
        return g
    means = g.means.detach().double().cpu().numpy()
    take = np.zeros(len(g), bool)
    for tr in tracks:
        if tr.present[t]:
            local = _box_local(means, tr, t)
            half = tr.size / 2
            take |= (np.abs(local) <= half + margin).all(1) & (local[:, 2] >= -half[2] + floor)
    if not take.any():
        return g
    extras = torch.zeros(len(g), 1, dtype=g.means.dtype) if g.extras is None else g.extras.clone()
    extras[torch.from_numpy(take), 0] = 1.0
    return Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors, extras)


def _box_pixels(camera, pose: np.ndarray, size: np.ndarray) -> tuple[slice, slice] | None:
    """The rows and columns of `camera`'s pixels whose rays can hit the box (`pose` box_to_scene, `size`), None
    where it lies wholly behind the camera (`_rects`)."""
    r = _rects(camera, pose[None], np.asarray(size, np.float64)[None])
    if not len(r):
        return None
    r0, r1, c0, c1 = (int(x) for x in r[0, :4])
    return slice(r0, r1), slice(c0, c1)


def _box_rects(camera, tracks: list[AgentTrack], t: int) -> np.ndarray:
    """`_rects` of the boxes present at frame t."""
    here = [tr for tr in tracks if tr.present[t]]
    if not here:
        return np.zeros((0, 6))
    return _rects(camera, np.stack([tr.poses[t] for tr in here]), np.stack([tr.size for tr in here]))


def _rects(camera, poses: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(n, 6) per box (`poses` (n,4,4) box_to_scene, `sizes` (n,3)) that `camera` can see: the pixel rect its rays
    can hit (row0, row1, col0, col1: the bounds of its corners' projections, as a box wholly before the camera
    projects inside their hull; the whole image where it reaches behind the camera) and its corners' nearest (at
    least 0) and farthest camera depth."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    m = camera.world_to_camera @ poses  # (n,4,4) box -> camera
    local = signs[None] * (sizes / 2)[:, None, :]  # (n,8,3)
    pc = np.einsum("nkj,nij->nki", local, m[:, :3, :3]) + m[:, None, :3, 3]
    z = pc[..., 2]
    seen = (z > 0).any(1)
    whole = (z <= 1e-6).any(1)  # reaches behind the camera: the whole image
    zs = np.where(z > 1e-6, z, 1.0)
    u = pc[..., 0] / zs * camera.fx + camera.cx
    v = pc[..., 1] / zs * camera.fy + camera.cy
    c0 = np.where(whole, 0, np.maximum(0, np.floor(u.min(1) - 0.5)))
    c1 = np.where(whole, camera.width, np.minimum(camera.width, np.ceil(u.max(1) - 0.5) + 1))
    r0 = np.where(whole, 0, np.maximum(0, np.floor(v.min(1) - 0.5)))
    r1 = np.where(whole, camera.height, np.minimum(camera.height, np.ceil(v.max(1) - 0.5) + 1))
    keep = seen & (r0 < r1) & (c0 < c1)
    return np.stack([r0, r1, c0, c1, np.maximum(z.min(1), 0.0), z.max(1)], 1)[keep]


def _near_rects(camera, p: np.ndarray, rects: np.ndarray, before_m: float, after_m, reach_m=None) -> bool:
    """Whether a point of `p` (N,3) projects (pixel floor) into one of `rects` (`_box_rects`), at a camera depth
    from the rect's nearest corner depth less `before_m` to its farthest plus `after_m` (metres, or a function of
    that depth); with `reach_m` (N,), a rect grown by each point's reach in pixels at its depth, plus one. A test
    that costs a projection, where what it guards costs rendering the boxes (`box_depths`)."""
    if not len(rects) or not len(p):
        return False
    w2c = camera.world_to_camera
    z = p @ w2c[2, :3] + w2c[2, 3]
    front = z > 1e-3
    if not front.any():
        return False
    p, z = p[front], z[front]
    pad = 0.0 if reach_m is None else np.asarray(reach_m)[front] * max(camera.fx, camera.fy) / z + 1.0
    u = np.floor((p @ w2c[0, :3] + w2c[0, 3]) / z * camera.fx + camera.cx)
    v = np.floor((p @ w2c[1, :3] + w2c[1, 3]) / z * camera.fy + camera.cy)
    for r0, r1, c0, c1, zmin, zmax in rects:
        hi = zmax + (after_m(zmax) if callable(after_m) else after_m)
        ok = (z < hi) & (z > zmin - before_m)
        ok &= (v >= r0 - pad) & (v < r1 + pad) & (u >= c0 - pad) & (u < c1 + pad)
        if ok.any():
            return True
    return False


def _passages(camera, tracks: list[AgentTrack], t: int):
    """Per box present at frame t whose corners project into `camera`: (its index, the pixel rect (`_box_pixels`),
    the camera depth where each of the rect's rays enters the box and where it leaves, both (h,w); a ray that misses
    it leaves before it enters)."""
    origin, dirs = camera.pixel_rays()
    for i, tr in enumerate(tracks):
        if not tr.present[t]:
            continue
        rect = _box_pixels(camera, tr.poses[t], tr.size)
        if rect is None:
            continue
        inv = rigid_inverse(tr.poses[t])
        d = dirs[rect]
        shape = d.shape[:2]
        o, d = inv[:3, :3] @ origin + inv[:3, 3], d.reshape(-1, 3) @ inv[:3, :3].T
        half = tr.size / 2
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (-half - o) / d, (half - o) / d
        lo = np.nan_to_num(np.minimum(a, b), nan=-np.inf).max(1)
        hi = np.nan_to_num(np.maximum(a, b), nan=np.inf).min(1)
        yield i, rect, lo.reshape(shape), hi.reshape(shape)


def box_depths(camera, tracks: list[AgentTrack], t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel of `camera` (scene frame): (the nearest box its ray enters at frame t, or -1; the camera depth where
    it enters; where it leaves) (H,W) each. Each box's rays are only those of the pixels its corners project to."""
    H, W = camera.height, camera.width
    owner = np.full((H, W), -1, np.int64)
    near, far = np.full((H, W), np.inf), np.full((H, W), np.inf)
    for i, rect, lo, hi in _passages(camera, tracks, t):
        sub_owner, sub_near, sub_far = owner[rect], near[rect], far[rect]  # views into the whole image
        hit = (lo < hi) & (hi > 0) & (np.maximum(lo, 0) < sub_near)
        sub_owner[hit] = i
        sub_near[hit] = np.maximum(lo[hit], 0)
        sub_far[hit] = hi[hit]
    return owner, near, far


def box_rays(cameras: list, tracks: list[AgentTrack], t: int, entering: bool = False) -> list[tuple]:
    """(camera, `box_depths` owner, leaving depth) of each camera that sees one of the boxes at frame t; `entering`:
    the depth where the ray enters the box instead."""
    out = []
    for camera in cameras:
        owner, near, far = box_depths(camera, tracks, t)
        if (owner >= 0).any():
            out.append((camera, owner, np.where(owner >= 0, near if entering else far, -np.inf)))
    return out


def _farthest_corner(point: np.ndarray, tracks: list[AgentTrack]) -> float:
    """The largest distance from `point` to a corner of the standing `tracks`' boxes (at their first pose)."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    best = 0.0
    for tr in tracks:
        pose = tr.poses[int(np.argmax(tr.present))]
        corners = (signs * tr.size / 2) @ pose[:3, :3].T + pose[:3, 3]
        best = max(best, float(np.linalg.norm(corners - point, axis=1).max()))
    return best


def claim_tolerance(depth, tol_m: float = CLAIM_RAY_TOL_M, tol_share: float = CLAIM_RAY_TOL_SHARE):
    """How far behind where a ray leaves a box (camera depth `depth`) `claim_along_rays` still claims. A pixel no box
    covers (depth -inf, `box_rays`) gets tol_m: it claims nothing either way, and 0 x inf would be NaN."""
    d = np.asarray(depth, np.float64)
    return np.maximum(tol_m, tol_share * np.where(np.isfinite(d), d, 0.0))


def claim_reach(
    camera, far_max: float, tol_m: float = CLAIM_RAY_TOL_M, tol_share: float = CLAIM_RAY_TOL_SHARE
) -> float:
    """The farthest a Gaussian claimed by `claim_along_rays` on this camera's rays can be from its centre, where a
    ray leaves a box at camera depth `far_max` at most: that depth plus its tolerance, times the largest ratio of
    distance to camera depth in the image."""
    zmax = far_max + float(claim_tolerance(far_max, tol_m, tol_share))
    tx = max(camera.cx, camera.width - camera.cx) / camera.fx
    ty = max(camera.cy, camera.height - camera.cy) / camera.fy
    return zmax * math.sqrt(1.0 + tx * tx + ty * ty)


# A camera's projection of a frame's Gaussians is computed only for those in cubes of PRUNE_CELL_M (metres) whose
# bounds can reach the region the camera's test looks at (`PointCells.rows`): a long clip's keyframe cameras see a
# frame's Gaussians mostly from afar or aside. The test itself is unchanged, on fewer points.
PRUNE_CELL_M = 6.0


class PointCells:
    """Points (N,3) grouped into cubes of `size` metres, each with its points' exact bounds, to find the points a
    camera's pixel rect and depth range can hold without projecting them all."""

    def __init__(self, p: np.ndarray, size: float = PRUNE_CELL_M):
        self.n = len(p)
        if not self.n:
            self.order, self.starts = np.zeros(0, np.int64), np.zeros(1, np.int64)
            self.centre, self.half = np.zeros((0, 3)), np.zeros((0, 3))
            return
        keys = np.floor(p / size).astype(np.int64)
        keys -= keys.min(0)
        span = keys.max(0) + 1
        flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
        self.order = np.argsort(flat, kind="stable")
        sorted_keys = flat[self.order]
        first = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
        self.starts = np.r_[first, self.n]
        ps = p[self.order]
        lo, hi = np.minimum.reduceat(ps, first, axis=0), np.maximum.reduceat(ps, first, axis=0)
        self.centre, self.half = (lo + hi) / 2, (hi - lo) / 2

    def pad(self, per_point: np.ndarray) -> np.ndarray:
        """Each cube's largest of `per_point` (N,)."""
        return np.maximum.reduceat(per_point[self.order], self.starts[:-1]) if self.n else np.zeros(0)

    @staticmethod
    def _tests(camera, rect: tuple, zmax: float, zmin: float) -> tuple | None:
        """`rows`' tests, each a linear function of world (x, y, z), >= 0 where a point may pass: (6,3) coefficients,
        (6,) constants, the camera's larger focal length; None where nothing can pass."""
        r0, r1, c0, c1 = (float(x) for x in rect)
        if r1 <= r0 or c1 <= c0 or zmax <= max(zmin, 0.0):
            return None
        fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
        a = np.array([
            [0.0, 0.0, 1.0],  # z > zmin (and before the camera)
            [fx, 0.0, cx - (c0 - 2.0)],  # u >= c0
            [-fx, 0.0, (c1 + 2.0) - cx],  # u < c1
            [0.0, fy, cy - (r0 - 2.0)],  # v >= r0
            [0.0, -fy, (r1 + 2.0) - cy],  # v < r1
            [0.0, 0.0, -1.0],  # z < zmax
        ])  # fmt: skip
        b = np.array([-max(zmin, 0.0) + 1e-3, 0.0, 0.0, 0.0, 0.0, zmax + 1e-3])
        if not math.isfinite(zmax):
            a[5], b[5] = 0.0, 1.0
        w2c = camera.world_to_camera
        return a @ w2c[:3, :3], a @ w2c[:3, 3] + b, max(fx, fy)

    def _tops(self, a: np.ndarray, b: np.ndarray, f: np.ndarray, pad: np.ndarray | None) -> np.ndarray:
        """(C,K,6): each cube's largest value of K cameras' tests (`_tests`: a (K,6,3), b (K,6), f (K,)): at the
        centre plus the extent times |a|; the pixel tests grown by the cube's `pad` footprint
        (u >= c0 - pad f / z: fx x + (cx - c0) z + pad f >= 0)."""
        top = np.einsum("cj,ktj->ckt", self.centre, a) + np.einsum("cj,ktj->ckt", self.half, np.abs(a)) + b[None]
        if pad is not None:
            top[:, :, 1:5] += pad[:, None, None] * f[None, :, None]
        return top

    def reachable(self, items: list[tuple], pad: np.ndarray | None = None) -> np.ndarray:
        """(K,) bool per (camera, rect, zmax, zmin) of `items`: whether `rows` can find a point (False: it finds
        none), for all at once."""
        out = np.zeros(len(items), bool)
        tests = [self._tests(*it) for it in items]
        live = [k for k, t in enumerate(tests) if t is not None]
        if not self.n or not live:
            return out
        for i in range(0, len(live), 64):
            ks = live[i : i + 64]
            a = np.stack([tests[k][0] for k in ks])
            b = np.stack([tests[k][1] for k in ks])
            f = np.array([tests[k][2] for k in ks])
            top = self._tops(a, b, f, pad)
            out[ks] = (top >= -1e-6 * (1.0 + np.abs(top))).all(2).any(0)
        return out

    def rows(
        self, camera, rect: tuple, zmax: float, zmin: float = -math.inf, pad: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Sorted indices of the points in the cubes that may hold a point with camera depth in (max(zmin, 0), zmax)
        projecting (pixel floor) into rect (row0, row1, col0, col1), with two pixels and a millimetre to spare (a
        superset: the caller's own test decides); None for all of them. Never a single one: numpy projects a single
        row by another path than a matrix's rows, a last bit apart (a subset of two or more rows projects as they
        do in the whole). `pad` (per cube, `pad`): the rect grown by that many metres' footprint at each depth
        (pad * max(fx, fy) / z pixels) for a cube's points."""
        tests = self._tests(camera, rect, zmax, zmin)
        if not self.n or tests is None:
            return np.zeros(0, np.int64)
        a, b, f = tests
        top = self._tops(a[None], b[None], np.array([f]), pad)[:, 0]
        keep = (top >= -1e-6 * (1.0 + np.abs(top))).all(1)
        if keep.all():
            return None
        cells = np.flatnonzero(keep)
        if not len(cells):
            return np.zeros(0, np.int64)
        begin, length = self.starts[cells], self.starts[cells + 1] - self.starts[cells]
        if int(length.sum()) == 1:
            return None
        at = np.repeat(begin - np.r_[0, np.cumsum(length)[:-1]], length) + np.arange(int(length.sum()))
        return np.sort(self.order[at])


def ray_bounds(camera, owner: np.ndarray, far: np.ndarray) -> tuple[tuple, float, np.ndarray]:
    """The pixel rect (row0, row1, col0, col1) holding a `box_rays` camera's box pixels, the farthest depth where
    one of their rays leaves a box, and the camera's centre."""
    hit = owner >= 0
    rows, cols = np.flatnonzero(hit.any(1)), np.flatnonzero(hit.any(0))
    if not len(rows):
        return (0, 0, 0, 0), float(far.max()), None if camera is None else camera.position
    return (rows[0], rows[-1] + 1, cols[0], cols[-1] + 1), float(far.max()), None if camera is None else camera.position


def within(tree: cKDTree, points: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(K,) bool: whether `tree` has a point within reach[k] of points[k], as `tree.query(points[k],
    distance_upper_bound=reach[k])` finds one, in one query for all (a distance within a hair of its reach asks
    that query)."""
    if not len(points):
        return np.zeros(0, bool)
    reach = np.asarray(reach, np.float64)
    d = tree.query(points, distance_upper_bound=float(reach.max()) * (1 + 1e-6) + 1e-6)[0]
    out = d < reach
    close = np.isfinite(d) & (np.abs(d - reach) <= 1e-9 * np.maximum(reach, 1.0))
    for k in np.flatnonzero(close):
        out[k] = np.isfinite(tree.query(points[k], distance_upper_bound=float(reach[k]))[0])
    return out


def claim_along_rays(
    g: Gaussians,
    rays: list[tuple],
    tol_m: float = CLAIM_RAY_TOL_M,
    tol_share: float = CLAIM_RAY_TOL_SHARE,
    tree: cKDTree | None = None,
    cells: PointCells | None = None,
) -> Gaussians:
    """A learned mode's Gaussians (scene frame) with those made dynamic that a camera of `rays` (`box_rays`) sees on
    a ray through an agent's box, before it or within tol_m (or tol_share of the depth, if more) behind where the
    ray leaves it. A decoded depth is blurred over an agent's edge and often far off on a small agent, so the
    model's agent lies before and behind its box (and, seen from another camera, before the box); left in the
    scene, it covers the object. Road before a box is never on a ray through it. `cells`: `PointCells` of the same
    means, whose cubes out of a camera's boxes' pixels or depth are not projected (each ray tuple may carry its
    `ray_bounds` fourth). Each Gaussian's test is the same either way."""
    if not len(g) or not rays:
        return g
    p = g.means.detach().double().cpu().numpy()
    take = np.zeros(len(p), bool)
    tree = cKDTree(p) if tree is None else tree  # `tree`: the caller's of the same means
    bounds = [r[3] if len(r) > 3 else ray_bounds(*r[:3]) for r in rays]
    # a camera with no Gaussian within its claim reach claims none (a long clip's far frames): skipped before
    # projecting every Gaussian
    reach = [claim_reach(r[0], b[1], tol_m, tol_share) for r, b in zip(rays, bounds, strict=True)]
    near = within(tree, np.array([b[2] for b in bounds]), np.array(reach))
    if cells is not None and near.any():  # and, all at once, those whose box pixels no cube of `cells` reaches
        ks = np.flatnonzero(near)
        items = [(rays[k][0], bounds[k][0], bounds[k][1] + float(claim_tolerance(bounds[k][1], tol_m, tol_share)),
                  -math.inf) for k in ks]  # fmt: skip
        near[ks] = cells.reachable(items)
    for (camera, owner, far, *_), (rect, far_max, _), ok in zip(rays, bounds, near, strict=True):
        if not ok:
            continue
        sub, q = None, p
        if cells is not None:
            sub = cells.rows(camera, rect, far_max + float(claim_tolerance(far_max, tol_m, tol_share)))
            if sub is not None and not len(sub):
                continue
            q = p if sub is None else p[sub]
        w2c = camera.world_to_camera
        pc = q @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        rows = np.flatnonzero(z > 1e-3)
        u = np.floor(pc[rows, 0] / z[rows] * camera.fx + camera.cx).astype(np.int64)
        v = np.floor(pc[rows, 1] / z[rows] * camera.fy + camera.cy).astype(np.int64)
        inside = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        rows, u, v = rows[inside], u[inside], v[inside]
        hi = far[v, u]
        rows = rows[z[rows] < hi + claim_tolerance(hi, tol_m, tol_share)]
        take[rows if sub is None else sub[rows]] = True
    if not take.any():
        return g
    extras = torch.zeros(len(g), 1, dtype=g.means.dtype) if g.extras is None else g.extras.clone()
    extras[torch.from_numpy(take), 0] = 1.0
    return Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors, extras)


# A learned mode's static Gaussian before a moving agent's box whose footprint (SPILL_SIGMAS std) reaches past the
# box's pixels' edge in a camera that draws the agent is narrowed to stop at that edge: decoded road 0.6-3 m before a
# pedestrian (std 0.15-0.35 m) spread over its legs (generate, urban: covered 0.30). The static scene is drawn at every
# frame and the agent moves, so every drawn frame's box as that frame's cameras see it (the road before the
# pedestrian at frame 0 was mostly decoded at other frames; frame t's cameras alone: covered 0.64).
# Only those less than SPILL_BEFORE_M before where the ray leaves the box: narrowing all before it thinned the near
# road in every frame (test:2: static PSNR -0.08 dB, a car's surround nearer its colour, contrast 0.67 -> 0.34).
SPILL_SIGMAS = 2.5
SPILL_BEFORE_M = 4.0
# A frame's cameras are tried only on Gaussians within SPILL_BEFORE_M + SPILL_SIDE_M of one of its boxes (past the
# box's half-diagonal): a spill SPILL_SIDE_M wide is SPILL_SIGMAS std of 1.2 m (the spilling road: 0.15-0.35 m). The
# long clip's first frame tried every keyframe's cameras: 3.24 s, was 2.53 s.
SPILL_SIDE_M = 3.0


def _rotations(quats: np.ndarray) -> np.ndarray:
    """(N,3,3) rotations of (N,4) wxyz quaternions (normalised here)."""
    q = quats / np.maximum(np.linalg.norm(quats, axis=1, keepdims=True), 1e-12)
    return quaternion_to_matrix(q)


def box_edges(owner: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of a `box_depths` owner image: its distance to the nearest pixel of a box (0 on one) and that
    pixel's (row, column) (2,H,W)."""
    return distance_transform_edt(owner < 0, return_indices=True)


def spill_bounds(owner: np.ndarray, far: np.ndarray) -> tuple[tuple, float, float]:
    """The pixel rect holding a `box_rays` camera's box pixels (`ray_bounds`), and the farthest and the nearest depth
    where one of their rays leaves a box."""
    hit = owner >= 0
    if not hit.any():
        return (0, 0, 0, 0), -math.inf, math.inf
    rect, far_max, _ = ray_bounds(None, owner, far)
    return rect, far_max, float(far[hit].min())


def narrow_before_boxes(
    g: Gaussians, rays: list[tuple], sigmas: float = SPILL_SIGMAS, cells: PointCells | None = None
) -> Gaussians:
    """A learned mode's Gaussians (scene frame) with each static one (extras[:, 0] <= DYNAMIC_THRESHOLD) that lies
    before a box (by less than SPILL_BEFORE_M) a camera of `rays` (`box_rays`, each optionally with its `box_edges`
    appended) sees, outside the box's pixels, and whose projected footprint reaches `sigmas` std into them, shrunk
    (all its scales alike) until that reach ends at their edge. Those on a box's pixels are `claim_along_rays`' to
    take or leave. `cells`: `PointCells` of the same means, whose cubes out of reach of a camera's box pixels or
    depths are not projected (each ray tuple may carry its `spill_bounds` after its edges); the same result."""
    if not len(g) or not rays:
        return g
    p = g.means.detach().double().cpu().numpy()
    scales = g.scales.detach().double().cpu().numpy()
    static = np.ones(len(p), bool) if g.extras is None else g.extras[:, 0].detach().cpu().numpy() <= DYNAMIC_THRESHOLD
    factor = np.ones(len(p))
    widest = scales.max(1)
    pad = None if cells is None else cells.pad(sigmas * widest)
    bounds = [r[4] if len(r) > 4 else spill_bounds(r[1], r[2]) for r in rays] if cells is not None else []
    live = np.ones(len(rays), bool)
    if cells is not None:  # all at once: a camera whose box pixels no cube of `cells` reaches narrows none
        live = cells.reachable([(r[0], b[0], b[1], b[2] - SPILL_BEFORE_M) for r, b in zip(rays, bounds)], pad)
    for k, (camera, owner, far, *extra) in enumerate(rays):
        if not live[k]:
            continue
        sub, q = None, p
        if cells is not None:
            rect, far_max, far_min = bounds[k]
            sub = cells.rows(camera, rect, far_max, far_min - SPILL_BEFORE_M, pad)
            if sub is not None and not len(sub):
                continue
            q = p if sub is None else p[sub]
        dist, (ir, ic) = extra[0] if extra else box_edges(owner)
        w2c = camera.world_to_camera
        pc = q @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        f = max(camera.fx, camera.fy)
        wq = widest if sub is None else widest[sub]
        reach = sigmas * wq * f / np.maximum(z, 1e-3)  # pixels, an upper bound of the footprint's reach
        rows = np.flatnonzero((static if sub is None else static[sub]) & (z > 1e-3) & (reach >= 1.0))
        u = pc[rows, 0] / z[rows] * camera.fx + camera.cx
        v = pc[rows, 1] / z[rows] * camera.fy + camera.cy
        ui, vi = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        inside = (ui >= 0) & (ui < camera.width) & (vi >= 0) & (vi < camera.height)
        rows, u, v, ui, vi = rows[inside], u[inside], v[inside], ui[inside], vi[inside]
        d = dist[vi, ui]
        near_r, near_c = ir[vi, ui], ic[vi, ui]
        # outside the box's pixels, before where the nearest box pixel's ray leaves it but not far before it, within
        # reach of it
        leave = far[near_r, near_c]
        cand = (d >= 1.0) & (z[rows] < leave) & (z[rows] > leave - SPILL_BEFORE_M) & (reach[rows] > d - 0.5)
        rows, u, v, d, near_r, near_c = rows[cand], u[cand], v[cand], d[cand], near_r[cand], near_c[cand]
        if not len(rows):
            continue
        # the footprint's std towards the nearest box pixel (its edge half a pixel nearer)
        zr, at = z[rows], rows if sub is None else sub[rows]
        jac = np.zeros((len(rows), 2, 3))
        jac[:, 0, 0], jac[:, 1, 1] = camera.fx / zr, camera.fy / zr
        jac[:, 0, 2], jac[:, 1, 2] = -pc[rows, 0] * camera.fx / zr**2, -pc[rows, 1] * camera.fy / zr**2
        rot = w2c[:3, :3] @ _rotations(g.quats.detach().double().cpu().numpy()[at])
        m = jac @ rot * scales[at][:, None, :]  # (n,2,3): J R S
        towards = np.stack([near_c + 0.5 - u, near_r + 0.5 - v], 1)
        towards /= np.maximum(np.linalg.norm(towards, axis=1, keepdims=True), 1e-9)
        std = np.linalg.norm(np.einsum("ni,nij->nj", towards, m), axis=1)
        edge = np.maximum(d - 0.5, 0.5)
        over = sigmas * std > edge
        np.minimum.at(factor, at[over], edge[over] / (sigmas * std[over]))
    if (factor >= 1.0).all():
        return g
    narrowed = g.scales * torch.from_numpy(factor).to(g.scales.dtype)[:, None]
    return Gaussians(g.means, g.quats, narrowed, g.opacities, g.colors, g.extras)


def lift_in_boxes(
    rgb: np.ndarray,
    depth: np.ndarray,
    camera,
    tracks: list[AgentTrack],
    t: int,
    tol_m: float = OBSERVED_DEPTH_TOL_M,
    tol_share: float = OBSERVED_DEPTH_TOL_SHARE,
) -> Gaussians:
    """An observed view's agent pixels lifted (`gaussians.lift`, dynamic): rgb (H,W,3) in [0,1], depth (H,W) camera
    z (sky +inf) at `camera`'s size, both the observation's. A pixel is an agent's where its ray passes through the
    agent's box and its depth lies on that passage (within tol_m, or tol_share of the depth if more); it is lifted at its depth clamped
    to the passage, so an observation blurred over an edge still lands on the box, not in the air before or behind."""
    z = np.asarray(depth, np.float64)
    H, W = z.shape
    near, far = np.full((H, W), np.inf), np.zeros((H, W))
    for _, rect, lo, hi in _passages(camera, tracks, t):
        # the nearest box whose passage holds the depth: a ray may pass through a nearer box where the agent in it
        # does not fill it (above a car's bonnet) and see the agent behind (reconstruct, urban_straight: a parked
        # car's side past a passing car's box was lifted by neither, and the road behind showed through it)
        lo = np.maximum(lo, 0)
        zr, sub_near, sub_far = z[rect], near[rect], far[rect]  # views into the whole image
        on = (lo < hi) & (hi > 0) & np.isfinite(zr) & (lo < sub_near)
        on &= (zr > lo - np.maximum(tol_m, tol_share * lo)) & (zr < hi + np.maximum(tol_m, tol_share * hi))
        sub_near[on], sub_far[on] = lo[on], hi[on]
    ok = np.isfinite(near)
    clamped = np.where(ok, np.clip(z, np.where(ok, near, 0.0), far), np.nan)
    return lift(rgb, clamped, np.ones(z.shape, bool), camera, sky=False)


# An observed pixel shows an occluder before an agent where its depth is this much before the agent's box (metres, or
# this share of the depth if more): a person's swinging arm or stride reaches out of the box (test:1, a pedestrian
# 10 m away: with 0.1 m its own pixels were taken for occluders and covered it), a barrier stands metres before.
OCCLUDER_TOL_M = 1.0
OCCLUDER_TOL_SHARE = 0.1


def occluder_pixels(
    depth: np.ndarray,
    camera,
    tracks: list[AgentTrack],
    t: int,
    tol_m: float = OCCLUDER_TOL_M,
    tol_share: float = OCCLUDER_TOL_SHARE,
) -> np.ndarray:
    """(H,W) bool: the pixels of an observed view (depth (H,W) camera z, sky +inf) whose ray enters an agent's box at
    frame t and whose depth lies before it by more than tol_m (or tol_share of the depth, if more): what stands
    between the camera and the agent (a barrier, a pole, another car; `lift_in_boxes` takes the rest of the ray's
    pixels). A Gaussian a model decoded from such a pixel is that occluder, not the agent blurred before its box:
    `ObjectBuilder.claim` leaves it (test:2, reconstruct: a barrier 3-6 m before two cars was claimed, and the cars
    showed through it: 4 of 6 agents seen, 6 of 6 with it left). Pixels on no box's ray are not shielded: a model's
    decoding of another frame blurs an agent onto them, and from this frame's cameras it lies before the box."""
    owner, near, _ = box_depths(camera, tracks, t)
    hit = owner >= 0
    z = np.asarray(depth, np.float64)
    near = np.where(hit, near, 0.0)
    return hit & (z < near - np.maximum(tol_m, tol_share * near))


def pixels_of(g: Gaussians, camera, mask: np.ndarray) -> np.ndarray:
    """(N,) bool: the Gaussians whose centre projects onto a True pixel of `mask` (H,W) in `camera`."""
    p = g.means.detach().double().cpu().numpy()
    w2c = camera.world_to_camera
    pc = p @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    ok = z > 1e-3
    zs = np.where(ok, z, 1.0)
    u = np.floor(pc[:, 0] / zs * camera.fx + camera.cx).astype(np.int64)
    v = np.floor(pc[:, 1] / zs * camera.fy + camera.cy).astype(np.int64)
    ok &= (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    out = np.zeros(len(p), bool)
    out[ok] = mask[v[ok], u[ok]]
    return out


def _voxel_keys(p: np.ndarray, size: float) -> np.ndarray:
    ijk = np.floor(p / size).astype(np.int64) & 0x1FFFFF
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def finest_observations(g: Gaussians, reference: list[Gaussians] = ()) -> np.ndarray:
    """Keep mask over `g` (box frame): False where at least FINER_COUNT Gaussians of `g` or of `reference` (an
    object's parts sent before) at least FINER_FACTOR times finer (geometric-mean std) lie in the Gaussian's voxel of
    FINER_REACH x its std. Scales in half-octave levels; a place seen only coarsely keeps its coarse Gaussians."""

    def log_std(x: Gaussians) -> np.ndarray:
        return np.log2(np.clip(x.scales.detach().double().cpu().numpy(), 1e-6, None)).mean(1)

    p = g.means.detach().double().cpu().numpy()
    level = np.floor(log_std(g) / math.log2(FINER_FACTOR)).astype(np.int64)
    ref = [r for r in reference if len(r)]
    all_p = np.concatenate([p] + [r.means.detach().double().cpu().numpy() for r in ref])
    all_level = np.concatenate([level] + [np.floor(log_std(r) / math.log2(FINER_FACTOR)).astype(np.int64) for r in ref])
    keep = np.ones(len(p), bool)
    for lv in np.unique(level):
        finer = all_level <= lv - 2  # at least one whole FINER_FACTOR below this level's range
        if not finer.any():
            continue
        size = FINER_REACH * FINER_FACTOR ** (lv + 1)
        keys, counts = np.unique(_voxel_keys(all_p[finer], size), return_counts=True)
        cand = np.flatnonzero(level == lv)
        k = _voxel_keys(p[cand], size)
        i = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
        keep[cand] = ~((keys[i] == k) & (counts[i] >= FINER_COUNT))
    return keep


@dataclass
class ObjectStats:
    agents: int = 0  # objects with Gaussians
    gaussians: int = 0  # canonical Gaussians over all objects
    absorbed: int = 0  # per-frame dynamic Gaussians that went into an object
    left_per_frame: int = 0  # per-frame dynamic Gaussians in no box, kept
    unboxed_dropped: int = 0  # per-frame dynamic Gaussians in no box, dropped (`keep_unboxed` False)
    coarse_dropped: int = 0  # observations left out where finer ones of the same place exist
    aggregate: AggregateStats = field(default_factory=AggregateStats)  # the objects' merging

    def as_dict(self) -> dict:
        return {"agents": self.agents, "gaussians": self.gaussians, "absorbed": self.absorbed,
                "left_per_frame": self.left_per_frame, "unboxed_dropped": self.unboxed_dropped, "coarse_dropped": self.coarse_dropped, "merged_away": self.aggregate.merged_away}  # fmt: skip


def _with_rows(g: Gaussians, rows: np.ndarray, part: Gaussians) -> Gaussians:
    """`g` with its `rows` (bool) replaced by `part` (as many Gaussians, same order; means unchanged), the row
    order kept."""
    idx = torch.from_numpy(np.flatnonzero(rows))
    out = []
    for whole, new in ((g.quats, part.quats), (g.scales, part.scales), (g.opacities, part.opacities),
                       (g.colors, part.colors)):  # fmt: skip
        whole = whole.clone()
        whole[idx] = new
        out.append(whole)
    extras = None
    if part.extras is not None:
        extras = torch.zeros(len(g), part.extras.shape[1], dtype=part.extras.dtype)
        if g.extras is not None:
            extras[:, : g.extras.shape[1]] = g.extras
        extras[idx] = part.extras
    return Gaussians(g.means, *out, extras)


class ObjectBuilder:
    """Agent objects built window by window (module docstring). `add` returns the window's per-frame leftovers and
    each agent's new canonical Gaussians; `objects()` the objects so far; `baked(frames, leftover)` the window's
    per-frame sets with the objects so far posed in (for writers without object records)."""

    def __init__(
        self,
        tracks: list[AgentTrack],
        rig: list[RigCamera],
        ego_to_scene: np.ndarray,
        *,
        economy: Economy | None = None,
        margin: float = AGENT_MARGIN_M,
        finer: float = WINDOW_FINER,
        source: ObjectSource | None = None,
        seed: int = 0,
        keep_unboxed: bool = True,
        claim_moving: bool = False,
        claim_margin: float = CLAIM_MARGIN_M,
        claim_rays: str | None = None,
        ray_frames: list[int] | None = None,
        narrow_spill: bool = False,
    ):
        self.tracks, self.economy, self.margin, self.source = list(tracks), economy or Economy(), margin, source
        self.keep_unboxed = keep_unboxed
        self.claimed = [tr for tr in self.tracks if tr.standing or claim_moving]
        self.claim_margin, self.claim_rays = claim_margin, claim_rays
        ego = np.asarray(ego_to_scene, np.float64)
        self.T = len(ego)
        # a standing agent's box is drawn from every frame's cameras: claimed along all their rays (`claim_along_rays`);
        # `ray_frames`: the frames whose cameras claim (None: all; a keyframed clip's keyframes, whose cameras the
        # frames between them are within a keyframe step of)
        self.ray_frames = list(range(self.T)) if ray_frames is None else sorted({int(f) for f in ray_frames})
        standing = [tr for tr in self.claimed if tr.standing]
        cams = [rc.at(ego[f]) for f in self.ray_frames for rc in rig]
        # their rays are computed per camera when first needed (`_standing_rays`): a long clip's first window then
        # waits only for the cameras that can reach its Gaussians
        self.standing = standing
        self.standing_cams = cams if claim_rays and standing else []
        self.standing_far = np.array([_farthest_corner(c.position, standing) for c in self.standing_cams])
        self._standing_cache: dict[int, tuple | None] = {}
        self._standing_pos: np.ndarray | None = None  # the cameras' centres and claim reaches, once
        self._standing_reach = np.zeros(0)
        self._standing_rects: dict[int, np.ndarray] = {}  # each camera's `_box_rects`, once
        # `narrow_spill`: static Gaussians before a moving box narrowed (`narrow_before_boxes`) as every drawn
        # frame's cameras see that frame's boxes; each camera's rays computed when first needed
        self.narrow_spill = narrow_spill
        self._spill_cams: tuple | None = None
        self._spill_cache: dict[int, tuple | None] = {}
        self._spill_pos: np.ndarray | None = None
        self._spill_rects: dict[int, np.ndarray] = {}
        self.rig, self.ego, self._rays, self._rays_key = list(rig), ego, [], None
        self._frame_rays: dict[
            tuple[int, bool], list[tuple]
        ] = {}  # `_moving_rays` per frame: the boxes and cameras are fixed
        for tr in self.tracks:
            if len(tr.poses) != self.T:
                raise ValueError(f"objects: agent {tr.agent_id} has {len(tr.poses)} poses, the clip {self.T} frames")
        self.focal = float(np.median([np.sqrt(rc.fx * rc.fy) for rc in rig])) if rig else 1.0
        centres = np.array([[rc.at(e).position for rc in rig] for e in ego]).reshape(self.T, -1, 3)
        # each agent's view of the cameras: every frame's camera centres in that frame's box frame
        self.centres = [self._box_centres(tr, centres) for tr in self.tracks]
        self.cells = [CellTable(finer) for _ in self.tracks]
        self.parts: list[list[Gaussians]] = [[] for _ in self.tracks]
        self.stats = ObjectStats()
        # agents drawn by `source`: their set is sent with the first window, their in-box Gaussians absorbed
        self.sourced: set[int] = set()
        if source is not None:
            for i, tr in enumerate(self.tracks):
                self.parts[i].append(source(tr, int(seed) * 1000 + tr.agent_id))
                self.sourced.add(i)
        self.unsent = set(self.sourced)

    def drops_claimed(self, observed: bool = False) -> bool:
        """Does a Gaussian the claims make dynamic leave the scene (`add`): no Gaussian in no box is kept, and every
        agent's object comes from elsewhere (the source; `observed`: the observed pixels)."""
        return not self.keep_unboxed and (observed or len(self.sourced) == len(self.tracks))

    @staticmethod
    def _box_centres(tr: AgentTrack, centres: np.ndarray) -> np.ndarray:
        present = np.flatnonzero(tr.present)
        if not len(present):
            return np.zeros((0, 3))
        rot, pos = tr.poses[present, :3, :3], tr.poses[present, :3, 3]
        # x_box = R^T (x - t), for every present frame's cameras at once
        return np.einsum("tvi,tij->tvj", centres[present] - pos[:, None, :], rot).reshape(-1, 3)

    def skeleton_objects(self) -> list[AgentObject]:
        """Every tracked agent with no Gaussians yet and all its poses (what a stream can announce up front)."""
        return [
            AgentObject(tr.agent_id, tr.cls, tr.size, Gaussians.empty(), tr.poses, tr.present) for tr in self.tracks
        ]

    def claim(self, t: int, g: Gaussians, shield: tuple | None = None) -> Gaussians:
        """Frame t's Gaussians before the aggregation, those in a standing agent's box (with `claim_moving`, any
        agent's) made dynamic (`claim_in_boxes`), so its static pixels go to its object, or, where the object comes
        from elsewhere (`source`, `observed`), give way to it; with `claim_rays`, those on the rays through a box,
        before it or near it, too (`claim_along_rays`): "frame", a moving agent's box at frame t as frame t's
        cameras see it; "clip", each agent's box at every frame as that frame's cameras see it, whatever frame the
        Gaussians were lifted at (the static scene is drawn at every frame); "frame_and_before", "frame" and, as every
        other drawn frame's cameras see the box, only what lies before it (no tolerance behind: what frame t sees
        beside the box stays). A standing agent's box always as every
        frame's cameras see it. `shield` (camera, (H,W) bool, `occluder_pixels`): the Gaussians lifted from those
        pixels of that camera are not claimed along the rays (what the observation shows stands before the agent)."""
        g = claim_in_boxes(g, self.claimed, t, self.claim_margin)
        if not self.claim_rays:
            return g
        # the sky shell is a backdrop, never before a box: left out, the far cameras of a long clip (whose reach
        # only the shell's points were in) are not tried
        sky = sky_rows(g)
        if sky.any():
            return _with_rows(g, ~sky, self._claim_rays_and_spill(t, g.subset(torch.from_numpy(~sky)), shield))
        return self._claim_rays_and_spill(t, g, shield)

    def _claim_rays_and_spill(self, t: int, g: Gaussians, shield: tuple | None) -> Gaussians:
        p = g.means.detach().double().cpu().numpy()
        tree, cells = (cKDTree(p), PointCells(p)) if len(g) else (None, None)
        claimed = self._claim_rays(t, g, tree, cells)
        if shield is not None and claimed is not g:
            keep = torch.from_numpy(pixels_of(g, *shield))
            if bool(keep.any()):
                extras = claimed.extras.clone()
                extras[keep] = g.extras[keep] if g.extras is not None else 0.0
                claimed = Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors, extras)
        if self.narrow_spill and tree is not None:  # the same means as `g`'s
            claimed = narrow_before_boxes(claimed, self._spill_rays(tree, claimed, cells), cells=cells)
        return claimed

    def _claim_rays(self, t: int, g: Gaussians, tree: cKDTree | None, cells: PointCells | None) -> Gaussians:
        key = -1 if self.claim_rays == "clip" else t
        if self._rays_key != key:  # the boxes as every frame's (or frame t's) cameras see them
            frames = self.ray_frames if key == -1 else [t]
            self._rays = self._moving_rays(frames)
            self._rays_key = key
        if tree is None:
            return g
        g = claim_along_rays(g, self._rays + self._standing_rays(tree, cells), tree=tree, cells=cells)
        if self.claim_rays == "frame_and_before":  # and before the boxes as the other drawn frames' cameras see them
            others = self._moving_rays([f for f in self.ray_frames if f != t], entering=True)
            g = claim_along_rays(g, others, tol_m=0.0, tol_share=0.0, tree=tree, cells=cells)
        return g

    def _moving_rays(self, frames: list[int], entering: bool = False) -> list[tuple]:
        """`box_rays` (with `ray_bounds`) of the moving claimed boxes at each of `frames` as its cameras see them,
        each frame's computed once ("frame_and_before" asks for every other frame's at each frame); `entering`: up to
        where the rays enter the boxes (what lies in another frame's box, the road under it, is frame t's to keep)."""
        moving = [tr for tr in self.claimed if not tr.standing]
        for f in frames:
            if (f, entering) not in self._frame_rays:
                cams = [rc.at(self.ego[f]) for rc in self.rig]
                rays = box_rays(cams, moving, f, entering=entering)
                self._frame_rays[(f, entering)] = [(*r, ray_bounds(*r)) for r in rays]
        return [r for f in frames for r in self._frame_rays[(f, entering)]]

    def _spill_rays(self, tree: cKDTree, g: Gaussians, cells: PointCells | None = None) -> list[tuple]:
        """The moving boxes' rays (`box_rays`, with `box_edges`) of every drawn frame's cameras that have a Gaussian
        of `tree` (`g`'s means) nearer than the farthest corner of that frame's boxes (a Gaussian narrowed lies
        before a box) and near one of those boxes (`_spill_cameras`)."""
        if self._spill_cams is None:
            self._spill_cams = self._spill_cameras()
        frames, cams, far, centres = self._spill_cams
        if not cams or not tree.n:
            return []
        if self._spill_pos is None:
            self._spill_pos = np.array([c.position for c in cams])
        nearest = tree.query(self._spill_pos)[0]
        near_box: dict[int, bool] = {}  # per frame, asked when first needed
        moving = [tr for tr in self.claimed if not tr.standing]
        static = np.ones(len(g), bool) if g.extras is None else (g.extras[:, 0] <= DYNAMIC_THRESHOLD).cpu().numpy()
        p = tree.data[static]
        widest = g.scales.detach().double().cpu().numpy().max(1, initial=0.0)
        reach = SPILL_SIGMAS * widest[static]
        out = []
        cand = []
        for i in np.flatnonzero(nearest < far):
            f = frames[i]
            if f not in near_box:
                c, r = centres[f]
                near_box[f] = bool((tree.query(c)[0] < r).any())
            if not near_box[f]:
                continue
            # a Gaussian `narrow_before_boxes` could narrow lies less than SPILL_BEFORE_M before a box, with its
            # footprint's reach (pixels) from the box's pixel rect
            if i not in self._spill_rects:
                self._spill_rects[i] = _box_rects(cams[i], moving, frames[i])
            cand.append(i)
        # the cameras not asked yet, all at once: one whose rects no cube of `cells` reaches finds no point
        ask = [i for i in cand if i not in self._spill_cache]
        hopeless = set()
        pad = None if cells is None else cells.pad(SPILL_SIGMAS * widest)
        if cells is not None and ask:
            bounds = [self._spill_bounds(cams[i], self._spill_rects[i]) for i in ask]
            hopeless = {i for i, ok in zip(ask, cells.reachable(bounds, pad), strict=True) if not ok}
        for i in cand:
            if i in hopeless:
                continue
            if i not in self._spill_cache:
                pi, ri = self._spill_points(cells, cams[i], self._spill_rects[i], static, p, reach, pad)
                if not _near_rects(cams[i], pi, self._spill_rects[i], SPILL_BEFORE_M, 0.0, ri):
                    continue
            if i not in self._spill_cache:
                r = box_rays([cams[i]], moving, frames[i])
                self._spill_cache[i] = (*r[0], box_edges(r[0][1]), spill_bounds(r[0][1], r[0][2])) if r else None
            if self._spill_cache[i] is not None:
                out.append(self._spill_cache[i])
        return out

    @staticmethod
    def _spill_points(cells, cam, rects, static, p, reach, pad) -> tuple[np.ndarray, np.ndarray]:
        """The static points `p` (`static` of the cells' points) and their reaches that `_near_rects(cam, p, rects,
        SPILL_BEFORE_M, 0.0, reach)` can find near a rect: those in the `cells` cubes that reach the rects' pixel
        bounds grown by their reach, between the rects' nearest depth less SPILL_BEFORE_M and their farthest (all
        without `cells`, or where one point alone would be left)."""
        if cells is None or not len(rects):
            return p, reach
        rows = cells.rows(*ObjectBuilder._spill_bounds(cam, rects), pad)
        if rows is None:
            return p, reach
        at = np.cumsum(static) - 1  # each static point's row in `p`
        rows = at[rows[static[rows]]]
        if len(rows) == 1:
            return p, reach
        return p[rows], reach[rows]

    @staticmethod
    def _spill_bounds(cam, rects: np.ndarray) -> tuple:
        """(cam, the rects' pixel bounds, their farthest depth, their nearest less SPILL_BEFORE_M): `PointCells.rows`'
        arguments for `_spill_points`; nothing where there are no rects (`_near_rects` finds nothing)."""
        if not len(rects):
            return cam, (0, 0, 0, 0), -math.inf, -math.inf
        rect = (rects[:, 0].min(), rects[:, 1].max(), rects[:, 2].min(), rects[:, 3].max())
        return cam, rect, float(rects[:, 5].max()), float(rects[:, 4].min()) - SPILL_BEFORE_M

    def _spill_cameras(self) -> tuple[list[int], list, np.ndarray, dict]:
        """Every drawn frame's cameras where a moving box is present: (their frames, the cameras, each one's
        distance to the farthest corner of that frame's boxes, {frame: (its boxes' centres, the distance within
        which a Gaussian narrowed against them lies: SPILL_BEFORE_M + SPILL_SIDE_M past the half-diagonal)})."""
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
        moving = [tr for tr in self.claimed if not tr.standing]
        frames, cams, reach, centres = [], [], [], {}
        for f in self.ray_frames:
            here = [tr for tr in moving if tr.present[f]]
            if not here:
                continue
            boxes = [(signs * tr.size / 2) @ tr.poses[f][:3, :3].T + tr.poses[f][:3, 3] for tr in here]
            radius = [float(np.linalg.norm(tr.size)) / 2 + SPILL_BEFORE_M + SPILL_SIDE_M for tr in here]
            centres[f] = (np.array([tr.poses[f][:3, 3] for tr in here]), np.array(radius))
            corners = np.concatenate(boxes)
            for rc in self.rig:
                cam = rc.at(self.ego[f])
                frames.append(f)
                cams.append(cam)
                reach.append(float(np.linalg.norm(corners - cam.position, axis=1).max()))
        return frames, cams, np.array(reach), centres

    @staticmethod
    def _near_points(tree: cKDTree, cells: PointCells | None, cam, rects: np.ndarray) -> np.ndarray:
        """The points of `tree` that `_near_rects(cam, ..., rects, math.inf, claim_tolerance)` can find near a rect:
        those in the `cells` cubes that reach the rects' pixel bounds before their farthest depth plus its
        tolerance (all without `cells`)."""
        if cells is None or not len(rects):
            return tree.data
        rows = cells.rows(*ObjectBuilder._near_bounds(cam, rects))
        return tree.data if rows is None else tree.data[rows]

    @staticmethod
    def _near_bounds(cam, rects: np.ndarray) -> tuple:
        """(cam, the rects' pixel bounds, their farthest depth plus its tolerance, -inf): `PointCells.rows`'
        arguments for `_near_points`; the whole image where there are no rects (`_near_rects` finds nothing)."""
        if not len(rects):
            return cam, (0, 0, 0, 0), -math.inf, -math.inf
        zmax = float((rects[:, 5] + claim_tolerance(rects[:, 5])).max())
        return cam, (rects[:, 0].min(), rects[:, 1].max(), rects[:, 2].min(), rects[:, 3].max()), zmax, -math.inf

    def _standing_rays(self, tree: cKDTree, cells: PointCells | None = None) -> list[tuple]:
        """The standing boxes' rays (`box_rays`) of the cameras that may claim one of the Gaussians in `tree`: those
        with a Gaussian within `claim_reach` of the boxes' farthest corner (a ray leaves a box before it), each
        camera's rays computed once."""
        out = []
        if self._standing_pos is None:
            self._standing_pos = np.array([c.position for c in self.standing_cams]).reshape(-1, 3)
            self._standing_reach = np.array([claim_reach(c, f) for c, f in zip(self.standing_cams, self.standing_far)])
        near = np.flatnonzero(within(tree, self._standing_pos, self._standing_reach))
        for i in near:
            if i not in self._standing_rects:
                self._standing_rects[i] = _box_rects(self.standing_cams[i], self.standing, 0)
        # the cameras not asked yet, all at once: one whose rects no cube of `cells` reaches finds no point
        ask = [i for i in near if i not in self._standing_cache]
        hopeless = set()
        if cells is not None and ask:
            bounds = [self._near_bounds(self.standing_cams[i], self._standing_rects[i]) for i in ask]
            hopeless = {i for i, ok in zip(ask, cells.reachable(bounds), strict=True) if not ok}
        for i in near:
            cam = self.standing_cams[i]
            # a Gaussian `claim_along_rays` could take lies in a box's pixel rect, before its far side's tolerance
            if i in hopeless:
                continue
            if i not in self._standing_cache and not _near_rects(
                cam,
                self._near_points(tree, cells, cam, self._standing_rects[i]),
                self._standing_rects[i],
                math.inf,
                claim_tolerance,
            ):
                continue
            if i not in self._standing_cache:
                r = box_rays([cam], self.standing, 0)
                self._standing_cache[i] = (*r[0], ray_bounds(*r[0])) if r else None
            if self._standing_cache[i] is not None:
                out.append(self._standing_cache[i])
        return out

    def add(
        self, frames: list[int], dynamic: dict[int, Gaussians], observed: dict[int, Gaussians] | None = None
    ) -> tuple[dict[int, Gaussians], dict[int, Gaussians]]:
        """A window's per-frame dynamic sets -> (the per-frame Gaussians in no box, {agent_id: the canonical
        Gaussians this window adds, box frame}); both final. `observed` (per frame, scene frame): where the
        agents' Gaussians come from instead of the dynamic sets (whose in-box Gaussians are then absorbed), e.g.
        the observed pixels `lift_in_boxes` lifts. Without `keep_unboxed` the Gaussians in no box are dropped."""
        mine: list[list[Gaussians]] = [[] for _ in self.tracks]
        leftover = {}
        for t in frames:
            d = dynamic[t]
            owner = assign_to_boxes(d.means.detach().double().cpu().numpy(), self.tracks, t, self.margin)
            src, src_owner = d, owner
            if observed is not None:
                src = observed[t]
                src_owner = assign_to_boxes(src.means.detach().double().cpu().numpy(), self.tracks, t, self.margin)
            for i in np.unique(src_owner[src_owner >= 0]):
                if i not in self.sourced:
                    part = src.subset(torch.from_numpy(src_owner == i))
                    mine[i].append(transform(part, rigid_inverse(self.tracks[i].poses[t])))
            unboxed = owner < 0 if self.keep_unboxed else np.zeros(len(owner), bool)
            leftover[t] = d.subset(torch.from_numpy(unboxed))
            self.stats.absorbed += int((owner >= 0).sum())
            self.stats.left_per_frame += len(leftover[t])
            self.stats.unboxed_dropped += int((owner < 0).sum()) - len(leftover[t])
        added = {}
        for i, tr in enumerate(self.tracks):
            if i in self.unsent:  # the source's Gaussians go out with the first window
                new = self.parts[i][0]
                self.unsent.discard(i)
            elif mine[i]:
                new = self._merge(i, Gaussians.cat(mine[i]))
                if len(new):
                    self.parts[i].append(new)
            else:
                continue
            if len(new):
                added[tr.agent_id] = new
        return leftover, added

    def _merge(self, i: int, g: Gaussians) -> Gaussians:
        eco = self.economy
        if not eco.enabled:
            return g.detach()
        keep = finest_observations(g, self.parts[i])
        self.stats.coarse_dropped += int((~keep).sum())
        g = g.subset(torch.from_numpy(keep))
        out = economize(g, eco, self.centres[i], self.focal, self.stats.aggregate, cell_factor=OBJECT_CELL_FACTOR,
                        cover=OBJECT_COVER, emitted=self.cells[i])  # fmt: skip
        if len(out) and len(self.centres[i]):  # no Gaussian wider than OBJECT_SCALE_CAP footprints (above)
            p = out.means.detach().double().cpu().numpy()
            near = np.min(np.linalg.norm(p[:, None, :] - self.centres[i][None, :, :], axis=-1), axis=1)
            cap = torch.as_tensor(OBJECT_SCALE_CAP * near / self.focal, dtype=out.scales.dtype)[:, None]
            out.scales = torch.minimum(out.scales, cap)
        return out

    def objects(self) -> list[AgentObject]:
        """The objects so far: agents with at least one canonical Gaussian, in track order."""
        out = []
        for tr, parts in zip(self.tracks, self.parts, strict=True):
            g = Gaussians.cat(parts) if len(parts) > 1 else (parts[0] if parts else None)
            if g is not None and len(g):
                out.append(AgentObject(tr.agent_id, tr.cls, tr.size, g, tr.poses, tr.present))
        self.stats.agents, self.stats.gaussians = len(out), sum(len(o.gaussians) for o in out)
        return out

    def baked(self, frames: list[int], leftover: dict[int, Gaussians]) -> dict[int, Gaussians]:
        """The window's frames with the objects so far posed in (what a per-frame writer sends for them)."""
        objs = self.objects()
        return {t: Gaussians.cat([leftover[t]] + [o.at_frame(t) for o in objs]) for t in frames}

    def names(self) -> dict[str, str]:
        """{track id: the scenario's agent id} of the explicit agents among the tracks (for the scene's meta)."""
        return {str(tr.agent_id): tr.name for tr in self.tracks if tr.name}
