"""An agent's appearance as Gaussians: its canonical Gaussians from its class, size, an appearance code and an optional
colour, in its box frame (x forward, y left, z up; origin at the box centre), made once and posed per frame.

A parametric, part-based generator fitted to the world's agents: the parts are the world's own
(`world.agents.agent_parts`: a car's body and cabin, a truck's cab and box, a bus, a person's body and head, a
cyclist's bike, torso and helmet, sized from the agent's box), every visible face covered by a grid of flat Gaussians
(surfels), each coloured by the world's own surface textures at its centre (`world.surfaces`: darker glazing, dark
wheels and sills, a grille, head and tail lamps; a person's clothing above the hips and dark trousers below). The
appearance code (seed) draws what the world draws per agent: the paint or clothing from the class palette (unless a
colour is asked) and the texture key. "Model only what a scene needs": a car is about 3,000 Gaussians, once, not per
frame. How close it comes to the world's agent (silhouette IoU, colour error, an asked colour) is measured by
`worldsplat.evaluation.agent_appearance` (web/docs/world.md#agent-colour).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from worldsplat.gaussians.types import Gaussians
from worldsplat.world.agents import CLASS_IDS, Agent, agent_parts
from worldsplat.world.classes import BUS, CAR, CYCLIST, PEDESTRIAN, TRUCK
from worldsplat.world.colours import BUS_COLOURS, CLOTHES, TRUCK_COLOURS, VEHICLE_COLOURS, colour_word, hex_rgb
from worldsplat.world.lighting import Lighting, make_lighting
from worldsplat.world.prims import BOX, Prims
from worldsplat.world.render import artificial_light
from worldsplat.world.surfaces import prim_hits, shade_prims
from worldsplat_models.geometry import matrix_to_quaternion

# About how many Gaussians an object of each class gets (the grid spacing follows from its surface area).
GAUSSIANS_PER_CLASS = {CAR: 3000, BUS: 6000, TRUCK: 6000, PEDESTRIAN: 1200, CYCLIST: 1500}
SPACING_RANGE = (0.03, 0.25)  # m between surfel centres
SURFEL_SPREAD = 0.45  # a surfel's std as a share of its grid cell: neighbours overlap (no holes), edges stay sharp
SURFEL_THICKNESS = 0.01  # m, std across the face
OPACITY = 0.98
_PALETTES = {CAR: VEHICLE_COLOURS, BUS: BUS_COLOURS, TRUCK: TRUCK_COLOURS}
_HEADINGS = 16  # sun headings averaged over when lighting an object that turns
# The light albedo textures are made under (only the glazing's sky reflection reads it; lamps are off by day).
DAYLIGHT = make_lighting("day", "clear", np.random.Generator(np.random.PCG64(0)))
# (points, normals) (n,3) in the agent's footprint frame -> the light (n,3) they get beside the sky and the sun
Lamps = Callable[[np.ndarray, np.ndarray], np.ndarray]
# Frames of the clip an object is lit at (its headings, the street lights and headlights on it), evenly spaced
LIGHT_FRAMES = 8


def agent_gaussians(
    cls: int | str,
    size,
    seed: int,
    colour: str | tuple[float, float, float] | None = None,
    *,
    lighting: Lighting | None = None,
    lamps: Lamps | None = None,
    headings: np.ndarray | None = None,
) -> Gaussians:
    """The agent's canonical Gaussians in its box frame.

    cls       world class id (`worldsplat.world.classes`, as `AgentObject.cls`) or scenario class name ("car")
    size      (length, width, height) in m
    seed      the appearance code (>= 0): the same seed gives the same object (bit for bit)
    colour    "#rrggbb" or RGB in [0, 1]: the body colour of a vehicle, the clothing of a person or cyclist (the
              paint's albedo, as `agents[i].colour`); None: drawn from the class palette by the seed
    lighting  None: colours are albedo (plus lamp emission); a scene's `Lighting`: lit by its sky and by its sun
              averaged over headings (the object turns with its track), and lamps glowing at dusk and night, as the
              world shades a surface (no shadows, no fog: those depend on where the object is)
    lamps     with `lighting`: the street lights and headlights where the object is (`clip_lamps`); at night
              they are most of an agent's light (test:1, a truck 19 m ahead: exact 0.54 grey, unlit 0.03)
    headings  with `lighting`: the agent's yaws in the world over the clip (`clip_headings`): the sun lights the
              faces it lights there, averaged over them; None: averaged over every heading"""
    prims = object_parts(cls, size, seed, colour)
    height = float(size[2])
    cls_id = CLASS_IDS[cls] if isinstance(cls, str) else int(cls)
    area = _surface_area(prims)
    spacing = float(np.clip(math.sqrt(area / GAUSSIANS_PER_CLASS[cls_id]), *SPACING_RANGE))
    pts, frames, cell, k = _surfels(prims, spacing)
    ph = prim_hits(prims, k, pts)
    shade_prims(ph, prims, pts, lighting or DAYLIGHT)
    light = 1.0 if lighting is None else _light(lighting, ph.normal, headings)
    if lighting is not None and lamps is not None:
        light = light + lamps(pts, ph.normal)
    rgb = ph.col * light + ph.em
    means = pts - [0.0, 0.0, height / 2]  # footprint frame (z = 0 on the ground) -> box frame
    scales = np.concatenate([SURFEL_SPREAD * cell, np.full((len(pts), 1), SURFEL_THICKNESS)], 1)
    return Gaussians.from_numpy(
        means, matrix_to_quaternion(frames), scales, np.full(len(pts), OPACITY), np.clip(rgb, 0.0, 1.0)
    )


def object_parts(cls: int | str, size, seed: int, colour: str | tuple[float, float, float] | None = None) -> Prims:
    """The world's parts of an agent of this class and size, in its footprint frame (z = 0 on the ground), with the
    appearance the seed draws: the palette colour (draw kept when a colour is asked, so the key is the same) and the
    texture key."""
    cls_id = CLASS_IDS[cls] if isinstance(cls, str) else int(cls)
    if cls_id not in GAUSSIANS_PER_CLASS:
        raise ValueError(f"agent_gaussians: class {cls!r} is not an agent class (car, bus, truck, pedestrian, cyclist)")
    if len(size) != 3 or not all(math.isfinite(float(v)) and float(v) > 0 for v in size):
        raise ValueError(f"agent_gaussians: size must be (length, width, height) > 0 in m, got {tuple(size)}")
    rng = np.random.Generator(np.random.PCG64([int(seed), cls_id]))
    if cls_id in _PALETTES:
        name, drawn = _PALETTES[cls_id][int(rng.integers(len(_PALETTES[cls_id])))]
    else:
        name, drawn = "", CLOTHES[int(rng.integers(len(CLOTHES)))]
    key = float(rng.random())
    if colour is not None:
        drawn = hex_rgb(colour) if isinstance(colour, str) else tuple(float(c) for c in colour)
        name = colour_word(drawn)
    dims = tuple(float(v) for v in size)
    agent = Agent(0, cls_id, dims, drawn, name, False, np.zeros((1, 3)), ("lane", "main", 1, 0))
    return agent_parts(agent, 0, key)


# (axis, sign) of the box faces a camera can see: all but the bottom (cameras are above the ground).
_FACES = tuple((a, s) for a in range(3) for s in (1, -1) if (a, s) != (2, -1))


def _surface_area(prims: Prims) -> float:
    total = 0.0
    for k in range(len(prims)):
        h = prims.half[k]
        if prims.shape[k] == BOX:
            total += sum(4 * h[(a + 1) % 3] * h[(a + 2) % 3] for a, _ in _FACES)
        else:
            total += 4 * math.pi * h[0] ** 2
    return total


def _surfels(prims: Prims, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Surfel centres (n,3), frames (n,3,3) (columns: the two in-face axes, the normal), cell sizes (n,2) and
    primitive index (n,) covering every visible face, without those inside another part (hidden anyway)."""
    pts, frames, cells, ks = [], [], [], []
    for k in range(len(prims)):
        p, f, c = _box_grid(prims, k, spacing) if prims.shape[k] == BOX else _sphere_grid(prims, k, spacing)
        keep = ~_inside_other(prims, k, p)
        pts.append(p[keep])
        frames.append(f[keep])
        cells.append(c[keep])
        ks.append(np.full(int(keep.sum()), k))
    return np.concatenate(pts), np.concatenate(frames), np.concatenate(cells), np.concatenate(ks)


def _box_grid(prims: Prims, k: int, spacing: float):
    c, s = math.cos(prims.yaw[k]), math.sin(prims.yaw[k])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    h = prims.half[k]
    pts, frames, cells = [], [], []
    for a, sign in _FACES:
        b, d = (a + 1) % 3, (a + 2) % 3
        nb, nd = max(1, math.ceil(2 * h[b] / spacing)), max(1, math.ceil(2 * h[d] / spacing))
        ub = (np.arange(nb) + 0.5) / nb * 2 * h[b] - h[b]
        ud = (np.arange(nd) + 0.5) / nd * 2 * h[d] - h[d]
        gb, gd = np.meshgrid(ub, ud, indexing="ij")
        local = np.zeros((gb.size, 3))
        local[:, a], local[:, b], local[:, d] = sign * h[a], gb.ravel(), gd.ravel()
        axes = np.eye(3)
        # Columns: in-face axes b and d, then the outward normal; det +1 (b, d, a are a cyclic order).
        frame = rot @ np.stack([axes[b], axes[d] * sign, axes[a] * sign], 1)
        pts.append(local @ rot.T + prims.center[k])
        frames.append(np.broadcast_to(frame, (len(local), 3, 3)))
        cells.append(np.broadcast_to([2 * h[b] / nb, 2 * h[d] / nd], (len(local), 2)))
    return np.concatenate(pts), np.concatenate(frames), np.concatenate(cells)


def _sphere_grid(prims: Prims, k: int, spacing: float):
    """A Fibonacci sphere: about equal areas per point."""
    r = float(prims.half[k, 0])
    n = max(8, math.ceil(4 * math.pi * r * r / spacing**2))
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + math.sqrt(5)) * i
    nrm = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], -1)
    helper = np.where(np.abs(nrm[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t1 = np.cross(helper, nrm)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nrm, t1)
    cell = math.sqrt(4 * math.pi * r * r / n)
    return prims.center[k] + r * nrm, np.stack([t1, t2, nrm], -1), np.full((n, 2), cell)


def _inside_other(prims: Prims, k: int, p: np.ndarray) -> np.ndarray:
    """Points inside (or on) a primitive other than k."""
    out = np.zeros(len(p), bool)
    for j in range(len(prims)):
        if j == k:
            continue
        rel = p - prims.center[j]
        if prims.shape[j] == BOX:
            c, s = math.cos(prims.yaw[j]), math.sin(prims.yaw[j])
            loc = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]], -1)
            out |= np.all(np.abs(loc) <= prims.half[j] + 1e-6, axis=1)
        else:
            out |= np.linalg.norm(rel, axis=1) <= prims.half[j, 0] + 1e-6
    return out


def _light(L: Lighting, normal: np.ndarray, headings: np.ndarray | None = None) -> np.ndarray:
    """The world's surface light (`world.render`: sky ambient by the normal's tilt plus Lambert sun) with the sun
    averaged over the object's `headings` (yaws in the world; None: _HEADINGS evenly spaced); street lights and
    headlights come from `lamps`, shadows are left out (they depend on where the object is)."""
    sun = L.sun_dir
    if headings is None:  # the sun at _HEADINGS azimuths evenly spaced
        az = 2 * math.pi * np.arange(_HEADINGS) / _HEADINGS
        horiz = math.hypot(sun[0], sun[1])
        suns = np.stack([horiz * np.cos(az), horiz * np.sin(az), np.full(_HEADINGS, sun[2])], -1)
    else:  # the sun in the box frame of an object turned by yaw: the world's sun turned by -yaw
        yaw = np.asarray(headings, np.float64)
        c, s = np.cos(yaw), np.sin(yaw)
        suns = np.stack([c * sun[0] + s * sun[1], -s * sun[0] + c * sun[1], np.full(len(yaw), sun[2])], -1)
    lambert = np.clip(normal @ suns.T, 0.0, None).mean(1)
    return L.ambient[None] * (0.75 + 0.25 * normal[:, 2:3]) + lambert[:, None] * L.sun_color[None]


def clip_frames(poses: np.ndarray, frames: int = LIGHT_FRAMES) -> np.ndarray:
    """Up to `frames` of the frames where an agent (poses (T,3) x, y, yaw in the world, nan where absent) is
    present, evenly spaced: the frames its one canonical object is lit at (it is drawn at every frame)."""
    p = np.asarray(poses, np.float64)
    present = np.flatnonzero(np.isfinite(p).all(1))
    if not len(present):
        return present
    return present[np.unique(np.round(np.linspace(0, len(present) - 1, min(frames, len(present)))).astype(int))]


def clip_headings(poses: np.ndarray) -> np.ndarray | None:
    """The agent's yaws in the world at its `clip_frames` (None where it is never present)."""
    pick = clip_frames(poses)
    return np.asarray(poses, np.float64)[pick, 2] if len(pick) else None


def clip_lamps(world, poses: np.ndarray) -> Lamps | None:
    """The world's street lights and the ego's headlights (`world.render.artificial_light`) on an agent whose
    footprint is at `poses` (T,3) x, y, yaw in the world (nan where absent), averaged over its `clip_frames`: one
    canonical object is drawn at every frame, so it gets the clip's mean light. None where the world's lights are
    off."""
    pick = clip_frames(poses)
    if not world.lighting.lights_on or not len(pick):
        return None
    p = np.asarray(poses, np.float64)

    def lamps(pts: np.ndarray, normals: np.ndarray) -> np.ndarray:
        out = np.zeros((len(pts), 3))
        for t in pick:
            x, y, yaw = p[t]
            c, s = math.cos(yaw), math.sin(yaw)
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            out += artificial_light(world, pts @ rot.T + [x, y, 0.0], normals @ rot.T, world.ego_to_world[t])
        return out / len(pick)

    return lamps
