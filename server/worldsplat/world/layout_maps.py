"""Per-camera layout maps: what the conditions alone say each pixel should show (the DiT's layout control).

Rendered by ray casting a *layout world* that holds only what a scenario states: the road plane with its drivable
area, painted markings and sidewalks, and one solid box per agent (its 3D box, not its detailed parts). Textures,
colours and lighting are absent: they are the model's to generate. Channels (`LAYOUT_CHANNELS`), float32:

    drivable    1 on road surface (lanes + shoulder), incl. junction areas
    markings    1 on painted lane lines and crosswalk stripes (exact, as the world paints them)
    sidewalk    1 on sidewalks / kerb side of urban roads
    vehicle     1 where a car / bus / truck box is the nearest surface (filled, not a wireframe)
    vulnerable  1 where a pedestrian / cyclist box is the nearest surface
    heading     on box pixels: position of the hit along the agent's heading, 0 at its rear, 1 at its front
                (so the direction of travel is visible in a single image); 0 elsewhere
    depth       layout depth (camera z of the road plane or box hit), log-normalised to [-1, 1] over
                [near, far] as the models normalise depth; +1 where the ray meets neither (sky, far)

Then the *map layer* (appended after them, so that a model trained on the first 7 channels reads them unchanged): the
scenario's static structure as a city map states it (building footprints with their heights, trees, poles / signs /
barriers), each as its solid volume without texture or colour, as CityDreamer's building-instance and height maps
condition a city generator. The street's buildings and trees are a deterministic function of the scenario (its road
kind and seed), so a generator that is not told where they stand can only draw an average facade at an average
distance (without the map layer, all-pixel depth AbsRel stayed at 0.22 while the road reached 0.03; CHANGELOG.md).

    building    1 where a building volume is nearer than the road / agent surface above
    vegetation  1 where a tree (trunk or crown) is
    furniture   1 where a pole, sign, traffic light or barrier is
    map_depth   like `depth`, with the map layer's surfaces in front (what the whole scene's geometry is)

The maps are exact for any rig camera and shifted track, like the world's ground truth, and cost one ray cast
with a handful of boxes per camera.
"""

from __future__ import annotations

import math

import numpy as np

from worldsplat.core.camera import Camera
from worldsplat.world.classes import (
    BARRIER,
    BUILDING,
    CROSSWALK,
    CYCLIST,
    LANE_MARKING,
    PEDESTRIAN,
    POLE,
    SIGN,
    VEGETATION,
    VEHICLE_CLASSES,
)
from worldsplat.world.prims import BOX, Prims
from worldsplat.world.render import PID_GROUND, trace
from worldsplat.world.road import bev_layers

LAYOUT_CHANNELS = (
    "drivable",
    "markings",
    "sidewalk",
    "vehicle",
    "vulnerable",
    "heading",
    "depth",
    "building",
    "vegetation",
    "furniture",
    "map_depth",
)
ROAD_AGENT_CHANNELS = 7  # the first 7: the road and the agents alone (what a road-only model reads)
MAP_CLASSES = {"building": (BUILDING,), "vegetation": (VEGETATION,), "furniture": (POLE, SIGN, BARRIER)}
LAYOUT_RANGE = 90.0  # metres: the road plane beyond this is left out (as the sketch's lines are)
LAYOUT_NEAR, LAYOUT_FAR = 0.5, 80.0  # metres: the depth channel's normalisation range


def agent_boxes(world, t: int) -> Prims:
    """One solid box per agent at frame t (its annotated 3D box), agent index in `agent`."""
    n = len(world.agents)
    center = np.zeros((n, 3))
    half = np.zeros((n, 3))
    yaw = np.zeros(n)
    cls = np.zeros(n, np.uint8)
    for i, a in enumerate(world.agents):
        x, y, th = a.poses[t]
        length, width, height = a.size
        center[i] = (x, y, height / 2)
        half[i] = (length / 2, width / 2, height / 2)
        yaw[i] = th
        cls[i] = a.cls
    return Prims(
        center,
        yaw,
        half,
        np.full(n, BOX, np.int8),
        cls,
        np.zeros((n, 3), np.float32),
        np.zeros(n, np.int8),
        np.zeros(n, np.float32),
        np.arange(n, dtype=np.int32),
    )


def map_layer(world) -> Prims:
    """The static structure a city map states: buildings, trees, poles / signs / barriers (not road paint)."""
    keep = np.isin(world.static.cls, [c for cs in MAP_CLASSES.values() for c in cs])
    return world.static.take(np.flatnonzero(keep))


def take_layout(control, channels: int):
    """The first `channels` layout channels of (..., C, H, W) maps: what a model trained on that many reads (the
    channel list only grows at its end). Refuses maps with fewer channels than the model needs."""
    have = control.shape[-3]
    if have < channels:
        raise ValueError(f"layout maps have {have} channels, the model reads {channels} ({LAYOUT_CHANNELS[:channels]})")
    return control if have == channels else control[..., :channels, :, :]


# `layout_regions`: a depth channel at or above this is open sky (+1 is the far range, 80 m; a resampled map's edge
# reads a little under it).
SKY_DEPTH = 0.99


def layout_regions(control) -> dict[str, object]:
    """Where torch layout maps (..., C, H, W) state the open road, the open sky and the agents: each (..., 1, H, W)
    float, 1 or 0. road: drivable, marking or sidewalk with no agent box in front; sky: no road, box or (where the
    maps carry the map layer) map surface within the maps' far range; agents: a vehicle or vulnerable-road-user box."""
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS[: control.shape[-3]])}

    def layer(*names):
        return control[..., [ch[n] for n in names], :, :].amax(-3, keepdim=True).clamp(0, 1)

    agents = layer("vehicle", "vulnerable")
    sky = control[..., ch["depth"] : ch["depth"] + 1, :, :] >= SKY_DEPTH
    if "map_depth" in ch:
        sky &= control[..., ch["map_depth"] : ch["map_depth"] + 1, :, :] >= SKY_DEPTH
    return {"road": layer("drivable", "markings", "sidewalk") * (1 - agents), "sky": sky.float(), "agents": agents}


def normalize_log_depth(z: np.ndarray, near: float, far: float) -> np.ndarray:
    d = np.clip(np.nan_to_num(z, nan=far, posinf=far), near, far)
    return np.clip(2.0 * (np.log(d) - math.log(near)) / (math.log(far) - math.log(near)) - 1.0, -1.0, 1.0)


def layout_depth_m(x, near: float = LAYOUT_NEAR, far: float = LAYOUT_FAR):
    """The depth channel back in metres (numpy or torch; `normalize_log_depth` inverted, far where nothing was hit)."""
    return near * (far / near) ** ((x + 1.0) / 2.0)


def layout_map(
    world,
    t: int,
    cam,
    near: float = LAYOUT_NEAR,
    far: float = LAYOUT_FAR,
    structure: Prims | None = None,
    agents: bool = True,
) -> np.ndarray:
    """(H, W, 11) float32 layout map of frame t seen by `cam` (any pose, shifted tracks included); `structure`:
    the world's `map_layer` (computed once per world by `layout_maps`). `agents` False: the map without the agents'
    boxes (what stands behind them: generate's backdrop, `pipeline.backdrop`)."""
    boxes = agent_boxes(world, t)
    if not agents:
        boxes = boxes.take(np.zeros(0, np.int64))
    hits, o, d = trace(cam, boxes, far=LAYOUT_RANGE)
    h, w = hits.t.shape
    out = np.zeros((h, w, len(LAYOUT_CHANNELS)), np.float32)
    finite = np.isfinite(hits.t)
    p = o + hits.t[..., None] * d  # world hit points (camera-z depth times unit-z rays)
    ground = (hits.pid == PID_GROUND) & finite
    if ground.any():
        gx, gy = p[ground, 0], p[ground, 1]
        layers = bev_layers(world.road, gx, gy)
        cls, _, _ = world.road.ground(gx, gy)
        out[ground, 0] = layers["drivable"]
        out[ground, 1] = (cls == LANE_MARKING) | (cls == CROSSWALK)
        out[ground, 2] = layers["sidewalk"]
    on_box = (hits.pid >= 0) & finite
    if on_box.any():
        k = hits.pid[on_box]
        bcls = boxes.cls[k]
        out[on_box, 3] = np.isin(bcls, list(VEHICLE_CLASSES))
        out[on_box, 4] = np.isin(bcls, [PEDESTRIAN, CYCLIST])
        c, s = np.cos(boxes.yaw[k]), np.sin(boxes.yaw[k])
        rel = p[on_box, :2] - boxes.center[k, :2]
        along = c * rel[:, 0] + s * rel[:, 1]
        out[on_box, 5] = np.clip(0.5 + along / (2 * boxes.half[k, 0]), 0.0, 1.0)
    out[..., 6] = normalize_log_depth(np.where(finite, hits.t, np.inf), near, far)
    structure = map_layer(world) if structure is None else structure
    depth = np.where(finite, hits.t, np.inf)
    if len(structure):
        shits, _, _ = trace(cam, structure, far=LAYOUT_RANGE)
        front = (shits.pid >= 0) & np.isfinite(shits.t) & (shits.t < depth)
        if front.any():
            scls = structure.cls[shits.pid[front]]
            for i, name in enumerate(MAP_CLASSES, start=ROAD_AGENT_CHANNELS):
                out[front, i] = np.isin(scls, MAP_CLASSES[name])
            depth = np.where(front, shits.t, depth)
    out[..., 10] = normalize_log_depth(depth, near, far)
    return out


def resized(cam, size: tuple[int, int] | None):
    """The same camera with its image scaled to size = (width, height) (intrinsics scaled with it)."""
    if size is None or (cam.width, cam.height) == tuple(size):
        return cam
    w, h = size
    sx, sy = w / cam.width, h / cam.height
    return Camera(w, h, cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy, cam.world_to_camera)


def layout_maps(
    world,
    shift_m: float = 0.0,
    cameras=None,
    near: float = LAYOUT_NEAR,
    far: float = LAYOUT_FAR,
    size=None,
    frames=None,
    agents: bool = True,
) -> np.ndarray:
    """(T, V, H, W, 11) layout maps of every frame (or of `frames`, in their order) and rig camera, at the rig's
    resolution or at size = (W, H) (the models' own, so the cast costs what the model reads); `agents` False:
    without the agents' boxes (`layout_map`)."""
    rig = world.rig if cameras is None else [world.rig_camera(n) for n in cameras]
    structure = map_layer(world)
    return np.stack(
        [
            np.stack(
                [
                    layout_map(
                        world, t, resized(rc.at(world.ego_to_world[t], shift_m), size), near, far, structure, agents
                    )
                    for rc in rig
                ]
            )
            for t in (range(world.num_frames) if frames is None else frames)
        ]
    )
